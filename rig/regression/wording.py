"""How a criterion's standing against its baseline reads, in one line (the terminal, the
report, JUnit messages): its class, the band, how far out in band half-widths and how
likely such a move is by chance, and what the confirmation at fresh seeds found."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rig.regression.baseline import EXCURSION, FAILING, FLAGGED


def percent(p: float | None) -> str:
    """A probability as a reader takes it in: 3 %, 0.2 %, 1e-05."""
    if p is None:
        return "?"
    if p >= 0.01:
        return f"{100 * p:.0f} %"
    if p >= 1e-4:
        return f"{100 * p:.2g} %"
    return f"{p:.1e}"


def distance(b: Mapping[str, Any]) -> str:
    d = b.get("distance")
    if d is None and "distance" in b:
        return "beyond any band (no number)"
    if d is None:
        return ""
    return f"{d:+.2f} band half-widths (chance {percent(b.get('chance'))})"


def confirmation(b: Mapping[str, Any]) -> str:
    conf = b.get("confirmation") or {}
    if not conf:
        return ""
    seeds = conf.get("seeds") or []
    span = f"seeds {seeds[0]}-{seeds[-1]}" if seeds else "fresh seeds"
    if conf.get("interrupted"):
        return f"confirmation at {span} interrupted"
    verdict = "confirmed" if conf.get("confirmed") else "not confirmed"
    return f"{verdict} at {span} (p = {conf.get('p', float('nan')):.2g}, " \
           f"level {conf.get('alpha', float('nan')):g})"


def against_baseline(c: Mapping[str, Any]) -> str:
    """One line for a criterion (result.json's), or '' when it is unchanged."""
    from rig.results import shown as values_shown  # enum values by their DBC names

    b = c.get("baseline")
    if not b or b.get("class") in (None, "unchanged"):
        return ""
    cls = str(b["class"])
    shown = cls.upper() if cls in FAILING else cls
    if "lo" not in b or b.get("value") is None:
        return f"{shown}: {values_shown.baseline_band(c)}"
    parts = [values_shown.baseline_band(c)]
    if cls in (*FLAGGED, EXCURSION, "improved"):
        d = distance(b)
        if d:
            parts.append(d)
    if b.get("where"):
        parts.append(str(b["where"]))
    c = confirmation(b)
    if c:
        parts.append(c)
    return f"{shown}: " + "; ".join(parts)
