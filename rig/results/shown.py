"""A criterion's numbers as a person reads them, the same in the report, on the terminal, in
JUnit messages and in the figures' titles: a value with its unit, an enumerated value by its
DBC name with the number beside it (``fw_state_end = FAULT (4)``, ``firmware.fault_code =
ADC_LOSS (6)``: ``rig.data.metrics.ENUMERATED``, ``rig.protocols.named_value``).

``value(metric, v)`` is what ``rig compare`` can call for its own tables."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from rig import protocols
from rig.data import metrics


def value(metric: str, v: Any, digits: int = 4) -> str:
    """One value of ``metric`` (a metric, counter or capture column): ``n/a`` when there is
    none, the DBC's name and number for an enumerated one, else the number to ``digits``
    significant digits."""
    if v is None:
        return "n/a"
    if isinstance(v, bool) or not isinstance(v, int | float):
        return str(v)
    if math.isnan(v):
        return "n/a"
    enum = metrics.enumerated(metric)
    if enum is not None and protocols.value_name(*enum, v) is not None:
        return protocols.named_value(*enum, v)
    return f"{v:.{digits}g}"


def with_unit(metric: str, v: Any, unit: str | None, digits: int = 4) -> str:
    text = value(metric, v, digits)
    return f"{text} {unit}" if unit and text != "n/a" else text


def bound(c: Mapping[str, Any], digits: int = 4) -> str:
    """A criterion's limit: ``<= 9.5 A``, ``== RUN (3)``, or ``reported``."""
    if c.get("limit") is None:
        return "reported"
    return (f"{c.get('comparison', '<=')} "
            f"{with_unit(str(c.get('metric')), c['limit'], c.get('unit'), digits)}")


def measured(c: Mapping[str, Any], digits: int = 4) -> str:
    """``metric = value unit``."""
    return (f"{c.get('metric')} = "
            f"{with_unit(str(c.get('metric')), c.get('value'), c.get('unit'), digits)}")


def baseline_band(c: Mapping[str, Any], digits: int = 4) -> str:
    """A criterion's baseline as text: its value and band over its seeds, or its note."""
    b = c.get("baseline") or {}
    metric, unit = str(c.get("metric")), c.get("unit")
    if "lo" not in b:
        return str(b.get("note", ""))
    if b.get("value") is None:
        return "the baseline has no value"
    return (f"baseline {with_unit(metric, b['value'], unit, digits)} within "
            f"{value(metric, b['lo'], digits)} .. {with_unit(metric, b['hi'], unit, digits)} "
            f"over {b.get('seeds')} seeds")
