"""The two sides of ``rig compare``, read and checked: a run folder, a suite folder, the
folder ``rig baseline record`` leaves (``seed-N/`` per seed: the mean over the seeds and
their spread), or a baseline (a file, or ``baseline:SUITE``).

A side is input a user hands over: a ``result.json`` that is not what the rig writes (a
list, criteria that are not a list of tables, a value that is not a number, seed values as
strings) is a :class:`CompareError` naming the file and the field, never a traceback.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.regression import baseline

Key = tuple[str, str]  # (scenario run "<name>@<profile>", criterion)


class CompareError(ValueError):
    """A side that cannot be read, or two sides that cannot be compared."""


@dataclass(frozen=True)
class Value:
    value: float | None
    unit: str
    metric: str
    better: str
    outcome: str
    band: baseline.Band | None = None  # a baseline's band, or the seeds' of a multi-seed side
    n: int = 1
    values: tuple[float | None, ...] | None = None  # per seed, where the side has them


@dataclass(frozen=True)
class Side:
    label: str
    values: dict[Key, Value]
    is_baseline: bool = False
    scenarios: frozenset[str] = field(default_factory=frozenset)  # the scenario runs it holds

    @property
    def evaluated(self) -> bool:
        """Whether anything on this side has a number (an interrupted run has none)."""
        return any(v.value is not None or v.outcome not in ("", "not_evaluated")
                   for v in self.values.values())


def _number(v: Any, where: str) -> float | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise CompareError(f"{where}: not a number: {str(v)[:40]!r}")
    x = float(v)
    return x if math.isfinite(x) else None


def _criteria(name: Any, profile: Any, criteria: Any, where: str,
              out: dict[Key, Value]) -> str:
    if not isinstance(name, str) or not isinstance(profile, str):
        raise CompareError(f"{where}: scenario and profile must be strings")
    if criteria is None:
        criteria = []
    if not isinstance(criteria, list):
        raise CompareError(f"{where}: criteria must be a list")
    key0 = baseline.entry_key(name, profile)
    for i, c in enumerate(criteria):
        at = f"{where}: criteria[{i}]"
        if not isinstance(c, dict):
            raise CompareError(f"{at}: must be a table")
        unit = str(c.get("unit") or "")
        v = _number(c.get("value"), f"{at}.value")
        band, n, per = None, 1, None
        seeds = c.get("seeds")
        if seeds:  # decided over its own seeds: the mean of them (rig.regression.baseline)
            if not isinstance(seeds, list) or not all(isinstance(x, dict) for x in seeds):
                raise CompareError(f"{at}.seeds: must be a list of tables")
            per = tuple(_number(x.get("value"), f"{at}.seeds[{k}].value")
                        for k, x in enumerate(seeds))
            band, n = baseline.Band.of(list(per), unit, of_mean=True), len(per)
            v = None if any(x is None for x in per) else band.value
        out[(key0, str(c.get("name")))] = Value(
            v, unit, str(c.get("metric")), baseline.better_side(c),
            str(c.get("outcome", "")), band, n, per)
    return key0


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise CompareError(f"{path}: not a readable result.json ({exc})") from exc


def run_folder(d: Path) -> tuple[dict[Key, Value], set[str]] | None:
    """A run's or a suite's result.json (None: the folder has none)."""
    path = d / "result.json"
    data = _read_json(path)
    if data is None:
        return None
    if not isinstance(data, dict):
        raise CompareError(f"{path}: must be a JSON object, not {type(data).__name__}")
    out: dict[Key, Value] = {}
    keys: set[str] = set()
    if data.get("schema") == "hil-suite/1":
        scenarios = data.get("scenarios") or []
        if not isinstance(scenarios, list):
            raise CompareError(f"{path}: scenarios must be a list")
        for i, e in enumerate(scenarios):
            if not isinstance(e, dict):
                raise CompareError(f"{path}: scenarios[{i}] must be a table")
            keys.add(_criteria(e.get("name"), e.get("profile"), e.get("criteria"),
                               f"{path}: scenarios[{i}]", out))
    elif data.get("schema") == "hil-result/1":
        keys.add(_criteria(data.get("scenario"), data.get("profile"), data.get("criteria"),
                           str(path), out))
    else:
        raise CompareError(f"{path}: schema {str(data.get('schema'))[:40]!r} is not a run's "
                           "or a suite's")
    return out, keys


def seed_folders(d: Path) -> tuple[dict[Key, Value], set[str]] | None:
    """A ``rig baseline record`` folder: each criterion's mean over its seeds, with their
    band and values."""
    seeds = sorted(p for p in d.glob("seed-*") if p.is_dir())
    if not seeds:
        return None
    per: dict[Key, list[Value]] = {}
    keys: set[str] = set()
    for s in seeds:
        for run in sorted(p for p in s.iterdir() if p.is_dir()):
            got = run_folder(run)
            if got is None:
                continue
            for k, v in got[0].items():
                per.setdefault(k, []).append(v)
            keys |= got[1]
    out: dict[Key, Value] = {}
    for k, vs in per.items():
        nums = [v.value for v in vs]
        band = baseline.Band.of(nums, vs[0].unit)
        outcomes = sorted({v.outcome for v in vs})
        out[k] = Value(band.value, vs[0].unit, vs[0].metric, vs[0].better, "/".join(outcomes),
                       band, len(vs), tuple(nums))
    return out, keys


def baseline_values(b: baseline.Baseline) -> dict[Key, Value]:
    out: dict[Key, Value] = {}
    for key, e in b.entries.items():
        for name, r in e.records.items():
            out[(key, name)] = Value(r.band.value, r.unit, r.metric, r.better, r.outcome,
                                     r.band, r.band.n or len(b.seeds), r.band.values)
    return out


def of_baseline(label: str, b: baseline.Baseline) -> Side:
    return Side(label, baseline_values(b), True, frozenset(b.entries))


def load_side(spec: str) -> Side:
    """A side from its command-line spelling."""
    if spec.startswith("baseline:"):
        path = baseline.path_of(spec.split(":", 1)[1])
        return of_baseline(spec, _load_baseline(path))
    p = Path(spec)
    if p.is_file() and p.suffix == ".toml":
        return of_baseline(spec, _load_baseline(p))
    if p.is_dir():
        got = run_folder(p)
        if got is None:
            got = seed_folders(p)
        if got is not None:
            return Side(spec, got[0], False, frozenset(got[1]))
    raise CompareError(f"{spec}: not a run or suite folder (result.json), a baseline record "
                       "folder (seed-N/), a baseline file or baseline:SUITE")


def _load_baseline(path: Path) -> baseline.Baseline:
    try:
        return baseline.Baseline.load(path)
    except baseline.BaselineError as exc:
        raise CompareError(str(exc)) from exc
