"""Two sets of results side by side (``rig compare A B``): per scenario run and criterion
the values, the difference (absolute, in %, in band widths) and how likely a difference that
large is by chance, sorted by that; and whether it is beyond the spread the plant's noise
seeds give.

The sides (``rig.regression.sides``) must be comparable: each must have evaluated something,
and they must share a scenario run (a baseline side is narrowed to the other side's
scenarios: a baseline of a whole suite against a run of one scenario compares that one).
Otherwise :class:`CompareError` says why ("not comparable").

The spread a difference is judged against is, in this order: the band of a baseline on
either side, the committed baseline of that scenario run (``rig/baselines``), the seed
spread of multi-seed sides (the same band rule as a baseline's). A difference without any
of these is ``unknown``, never ``unchanged``. Its chance: against a side with per-seed
values, the probability that one more seed (or, both sides having values, a sample like the
other) lies that far in that direction (rig.regression.baseline ``Band.chance``; the rank
test of rig.regression.stats); two single values against the committed band: that two
seeds' values differ that much (t distribution of the difference, sd sqrt(2)).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.regression import baseline, stats
from rig.regression.sides import (
    CompareError,
    Key,
    Side,
    Value,
    load_side,
    of_baseline,
)

__all__ = ["CompareError", "Key", "Row", "Side", "Value", "compare", "load_side"]


@dataclass(frozen=True)
class Row:
    key: Key
    a: Value | None
    b: Value | None
    diff: float | None
    half_band: float | None  # the spread the difference is judged against
    cls: str  # unchanged | improved | regressed | changed | unknown | added | removed
    chance: float | None = None  # how likely a difference this large is by chance

    @property
    def pct(self) -> float | None:
        va = _num(self.a)
        if self.diff is None or va is None or va == 0:
            return None
        return 100.0 * self.diff / abs(va)

    @property
    def widths(self) -> float | None:
        """The difference in band half-widths."""
        if self.diff is None or not self.half_band:
            return None
        return self.diff / self.half_band


# --------------------------------------------------------------------------------------
# The table


def _half(band: baseline.Band | None) -> float | None:
    if band is None or band.value is None or not math.isfinite(band.lo):
        return None
    return (band.hi - band.lo) / 2.0


def _committed(key: Key) -> baseline.Record | None:
    try:
        b = baseline.index().for_key(key[0])
    except baseline.BaselineError:
        return None
    return b.entries[key[0]].records.get(key[1]) if b is not None else None


def _num(v: Value | None) -> float | None:
    if v is None or v.value is None or not math.isfinite(v.value):
        return None
    return v.value


def _direction(diff: float, better: str) -> str:
    """Which side a move goes to on the criterion's scale: lower is better means up is worse."""
    if better == baseline.HIGHER:
        return baseline.LOWER if diff > 0 else baseline.HIGHER
    return baseline.LOWER if diff >= 0 else baseline.HIGHER


def _chance(a: Value, b: Value, diff: float, committed: baseline.Record | None) -> float | None:
    """The probability of a difference at least this large in this direction by chance."""
    # the side of "worse" the move is on, as Band.chance takes it
    side = baseline.LOWER if diff > 0 else baseline.HIGHER
    if a.values and b.values and len(a.values) > 1 and len(b.values) > 1:
        base = [math.inf if v is None else v for v in a.values]
        new = [math.inf if v is None else v for v in b.values]
        if side == baseline.HIGHER:
            base, new = [-x for x in base], [-x for x in new]
        return stats.shift_p(base, new)
    if a.band is not None and b.band is None and b.value is not None:
        return a.band.chance(b.value, side, n=a.n)
    if b.band is not None and a.band is None and a.value is not None:
        return b.band.chance(a.value, baseline.HIGHER if side == baseline.LOWER
                             else baseline.LOWER, n=b.n)
    if committed is not None and committed.band.n > 1 and committed.band.sd > 0:
        n = committed.band.n
        z = abs(diff) / (committed.band.sd * math.sqrt(2.0))
        return stats.t_sf(z, n - 1)
    return None


def row(key: Key, a: Value | None, b: Value | None) -> Row:
    if a is None or b is None:
        return Row(key, a, b, None, None, "added" if a is None else "removed")
    va, vb = _num(a), _num(b)
    better = b.better or a.better
    if va is None or vb is None:
        if va is None and vb is None:
            return Row(key, a, b, None, None, "unchanged", 1.0)
        worse_b = vb is None  # no number is the worst of its side
        cls = "changed" if better == baseline.EITHER else (
            "regressed" if worse_b else "improved")
        return Row(key, a, b, None, None, cls, 0.0)
    diff = vb - va
    committed = None
    # the spread: a band on one side (a baseline, or seeds), the larger of two, else the
    # committed baseline's
    if a.band is not None and b.band is None:
        half = _half(a.band)
    elif b.band is not None and a.band is None:
        half = _half(b.band)
    elif a.band is not None and b.band is not None:
        ha, hb = _half(a.band), _half(b.band)
        half = None if ha is None or hb is None else max(ha, hb)
    else:
        committed = _committed(key)
        half = _half(committed.band) if committed is not None else None
    chance = _chance(a, b, diff, committed) if diff != 0 else 1.0
    if half is None:
        return Row(key, a, b, diff, None, "unknown" if diff != 0 else "unchanged", chance)
    if abs(diff) <= half:
        return Row(key, a, b, diff, half, "unchanged", chance)
    if better == baseline.EITHER:
        return Row(key, a, b, diff, half, "changed", chance)
    worse = diff > 0 if better == baseline.LOWER else diff < 0
    return Row(key, a, b, diff, half, "regressed" if worse else "improved", chance)


def comparable(a: Side, b: Side) -> tuple[Side, Side]:
    """The sides narrowed to what can be compared, or CompareError: a side that evaluated
    nothing, or no scenario run in common. A baseline side keeps only the scenario runs of a
    run side (it is not "removed" from a run of one scenario)."""
    for s in (a, b):
        if not s.evaluated:
            raise CompareError(f"not comparable: {s.label} evaluated nothing (an interrupted "
                               "run, or no criteria)")
    if a.is_baseline and not b.is_baseline:
        a = Side(a.label, {k: v for k, v in a.values.items() if k[0] in b.scenarios}, True,
                 a.scenarios & b.scenarios)
    elif b.is_baseline and not a.is_baseline:
        b = Side(b.label, {k: v for k, v in b.values.items() if k[0] in a.scenarios}, True,
                 b.scenarios & a.scenarios)
    if not a.scenarios & b.scenarios:
        def names(s: Side) -> str:
            got = sorted(s.scenarios)
            return ", ".join(got[:5]) + (f" and {len(got) - 5} more" if len(got) > 5 else "")

        raise CompareError(f"not comparable: no scenario run in common ({a.label}: "
                           f"{names(a) or 'none'}; {b.label}: {names(b) or 'none'})")
    return a, b


def compare(a: Side, b: Side) -> list[Row]:
    """Every criterion of both sides, most significant first (CompareError when the sides
    are not comparable)."""
    a, b = comparable(a, b)
    keys = list(dict.fromkeys([*a.values, *b.values]))
    return sort([row(k, a.values.get(k), b.values.get(k)) for k in keys])


def baselines(old: baseline.Baseline, new: baseline.Baseline) -> list[Row]:
    a, b = of_baseline("old", old), of_baseline("new", new)
    keys = list(dict.fromkeys([*a.values, *b.values]))
    return sort([row(k, a.values.get(k), b.values.get(k)) for k in keys])


MOVED = ("regressed", "changed", "improved", "added", "removed", "unknown")
_ORDER = {k: i for i, k in enumerate(("regressed", "changed", "unknown", "improved", "added",
                                      "removed", "unchanged"))}


def sort(rows: list[Row]) -> list[Row]:
    """Regressions first, then by how unlikely the difference is by chance, then by size."""
    def key(r: Row) -> tuple[int, float, float, Key]:
        return (_ORDER.get(r.cls, 99), 1.0 if r.chance is None else r.chance,
                -abs(r.widths or 0.0), r.key)

    return sorted(rows, key=key)


def counts(rows: list[Row]) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in rows:
        out[r.cls] = out.get(r.cls, 0) + 1
    return out


def identical(r: Row) -> bool:
    """Both sides hold the criterion with the same value (every seed's too) and outcome."""
    return (r.a is not None and r.b is not None and r.a.value == r.b.value
            and r.a.outcome == r.b.outcome and r.a.values == r.b.values)


def not_identical_in_b(rows: list[Row]) -> list[Row]:
    """The criteria of side B that side A does not hold to the bit (``--exact``: B is the
    same computation as A on a part of A's runs, e.g. the bus against the gate in process)."""
    return [r for r in rows if r.b is not None and not identical(r)]


def summary_line(rows: list[Row], what: str = "") -> str:
    c = counts(rows)
    parts = ", ".join(f"{c[k]} {k}" for k in ("regressed", "changed", "improved", "unknown",
                                               "added", "removed", "unchanged") if c.get(k))
    same = sum(1 for r in rows if identical(r))
    return (f"{len(rows)} criteria{' ' + what if what else ''}: {parts or 'none'}"
            f"; {same} identical")


def _fmt(v: float | None) -> str:
    return "—" if v is None else f"{v:.4g}"


def _pct(p: float | None) -> str:
    if p is None:
        return "—"
    return f"{p:+.1f} %"


def _chance_text(p: float | None) -> str:
    from rig.regression.wording import percent

    return "—" if p is None else percent(p)


SHOWN_UNCHANGED = 15  # the most significant unchanged rows shown beside the moved ones


def markdown(rows: list[Row], only_changed: bool = True, a_label: str = "A",
             b_label: str = "B") -> str:
    """The table, most significant first: every row that moved, then (unless ``--all``) the
    ``SHOWN_UNCHANGED`` most significant unchanged ones; a closing line says how many more."""
    shown = sort(rows)
    hidden = 0
    if only_changed:
        moved = [r for r in shown if r.cls in MOVED]
        still = [r for r in shown if r.cls not in MOVED and r.diff not in (None, 0.0)]
        hidden = len(shown) - len(moved) - min(len(still), SHOWN_UNCHANGED)
        shown = moved + still[:SHOWN_UNCHANGED]
    lines = [f"| scenario | criterion | metric | {a_label} | {b_label} | B - A | change | "
             "band widths | chance | |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in shown:
        v = r.a or r.b
        assert v is not None
        unit = f" {v.unit}" if v.unit else ""
        widths = "—" if r.widths is None else f"{r.widths:+.2f}"
        lines.append(
            f"| {r.key[0]} | {r.key[1]} | `{v.metric}` | {_fmt(_num(r.a))}{unit} | "
            f"{_fmt(_num(r.b))}{unit} | {_fmt(r.diff)} | {_pct(r.pct)} | {widths} | "
            f"{_chance_text(r.chance)} | "
            f"{r.cls.upper() if r.cls in ('regressed', 'changed') else r.cls} |")
    if len(lines) == 2:
        lines.append("| (no criterion moved) | | | | | | | | | |")
    if hidden > 0:
        lines.append(f"\n({hidden} more criteria unchanged or identical: --all lists them)")
    return "\n".join(lines)


def plots(rows: list[Row], folder: Path, a_label: str, b_label: str) -> list[Path]:
    """One PNG per metric with a moved criterion: each moved scenario run's A and B values
    and the band a difference is judged against."""
    moved = [r for r in rows if r.cls in ("regressed", "changed", "improved", "unknown")
             and _num(r.a) is not None and _num(r.b) is not None]
    if not moved:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_metric: dict[str, list[Row]] = {}
    for r in moved:
        v = r.a or r.b
        assert v is not None
        by_metric.setdefault(v.metric, []).append(r)
    folder.mkdir(parents=True, exist_ok=True)
    out: list[Path] = []
    for metric, rs in sorted(by_metric.items()):
        rs = rs[:40]
        fig, ax = plt.subplots(figsize=(8.0, 1.0 + 0.35 * len(rs)))
        ys = list(range(len(rs)))
        for y, r in zip(ys, rs, strict=True):
            va, vb = _num(r.a), _num(r.b)
            assert va is not None and vb is not None
            if r.half_band is not None:
                ax.plot([va - r.half_band, va + r.half_band], [y, y], color="0.8", lw=6,
                        solid_capstyle="butt", zorder=1)
            color = {"regressed": "tab:red", "changed": "tab:orange",
                     "improved": "tab:green"}.get(r.cls, "tab:gray")
            ax.annotate("", xy=(vb, y), xytext=(va, y),
                        arrowprops={"arrowstyle": "->", "color": color}, zorder=2)
            ax.plot([va], [y], "o", color="k", ms=4, zorder=3)
            ax.plot([vb], [y], "D", color=color, ms=5, zorder=3)
        ax.set_yticks(ys, [f"{r.key[0]}: {r.key[1]}" for r in rs], fontsize=7)
        ax.invert_yaxis()
        unit = (rs[0].a or rs[0].b).unit if (rs[0].a or rs[0].b) else ""
        ax.set_xlabel(f"{metric}" + (f" ({unit})" if unit else ""))
        ax.set_title(f"{metric}: {a_label} (dot) → {b_label} (diamond); grey: seed spread",
                     fontsize=8)
        fig.tight_layout()
        path = folder / f"compare-{metric.replace('.', '_')}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        out.append(path)
    return out


def to_json(rows: list[Row]) -> list[Mapping[str, Any]]:
    return [{"scenario": r.key[0], "criterion": r.key[1],
             "metric": (r.a or r.b).metric if (r.a or r.b) else "",
             "a": _num(r.a), "b": _num(r.b), "diff": r.diff, "change_pct": r.pct,
             "band_widths": r.widths, "chance": r.chance, "spread": r.half_band,
             "class": r.cls} for r in rows]
