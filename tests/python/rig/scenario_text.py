"""Scenario files for the rig's tests, written from a few parameters: the speed profile, the
criteria and any other tables, as the TOML the rig reads (rig/scenario/schema.py)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

Fields = Mapping[str, Any]


def value(v: Any) -> str:
    """One TOML value: a string (quoted), a number as Python writes it (5 stays an integer,
    300.0 a float), a list, or an inline table."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, Sequence):
        return "[" + ", ".join(value(x) for x in v) + "]"
    return repr(v)


def tables(name: str, rows: Sequence[Fields]) -> str:
    """An array of tables: ``[[name]]`` and its fields, for each row."""
    return "".join(f"[[{name}]]\n" + "".join(f"{k} = {value(x)}\n" for k, x in row.items())
                   for row in rows)


def ramp(to: float, duration: float) -> Fields:
    return {"kind": "ramp", "to": to, "duration": duration}


def hold(duration: float) -> Fields:
    return {"kind": "hold", "duration": duration}


def criterion(name: str, metric: str, window: Sequence[float | str] | None = None,
              limit: float | None = None, comparison: str | None = None,
              **more: Any) -> Fields:
    """One ``[[criteria]]`` row; ``more`` are its other fields (``xfail``, ``params``)."""
    fields: dict[str, Any] = {"name": name, "metric": metric}
    for key, v in (("window", window), ("limit", limit), ("comparison", comparison)):
        if v is not None:
            fields[key] = v
    return fields | more


def scenario(description: str, *, profile: str, duration: float,
             speed: Sequence[Fields], criteria: Sequence[Fields], load: Sequence[Fields] = (),
             other: str = "") -> str:
    """A scenario: its description, profile and duration, its speed and load profile, the
    ``other`` tables as written (``[run]``, ``[[faults]]``), then its criteria."""
    parts = [f"description = {value(description)}\nprofile = {value(profile)}\n"
             f"duration = {duration}\n", tables("speed", speed), tables("load", load), other,
             tables("criteria", criteria)]
    return "\n".join(p for p in parts if p)
