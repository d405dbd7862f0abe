"""Two sets of results side by side (``rig compare A B``): per scenario run and criterion
the values, the difference and whether it is beyond the spread the plant's noise seeds give.

A side is a run folder (one scenario), a suite folder, the folder ``rig baseline record``
leaves (``seed-N/`` per seed: the mean over the seeds and their spread), or a baseline (a
file, or ``baseline:SUITE``). The spread a difference is judged against is, in this order:
the band of a baseline on either side, the committed baseline of that scenario run
(``rig/baselines``), the seed spread of multi-seed sides (the same band rule as a
baseline's). A difference without any of these is ``unknown``, never ``unchanged``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.regression import baseline

Key = tuple[str, str]  # (scenario run "<name>@<profile>", criterion)


@dataclass(frozen=True)
class Value:
    value: float | None
    unit: str
    metric: str
    better: str
    outcome: str
    band: baseline.Band | None = None  # a baseline's band, or the seeds' of a multi-seed side
    n: int = 1


@dataclass(frozen=True)
class Side:
    label: str
    values: dict[Key, Value]
    is_baseline: bool = False


@dataclass(frozen=True)
class Row:
    key: Key
    a: Value | None
    b: Value | None
    diff: float | None
    half_band: float | None  # the spread the difference is judged against
    cls: str  # unchanged | improved | regressed | changed | unknown | added | removed


class CompareError(ValueError):
    pass


# --------------------------------------------------------------------------------------
# Sides


def _from_criteria(name: str, profile: str, criteria: Any, out: dict[Key, Value]) -> None:
    key0 = baseline.entry_key(name, profile)
    for c in criteria or []:
        v = c.get("value")
        unit = str(c.get("unit") or "")
        band, n = None, 1
        if c.get("seeds"):  # decided over its own seeds: the mean of them (rig.regression.baseline)
            per = [x.get("value") for x in c["seeds"]]
            band, n = baseline.Band.of(per, unit, of_mean=True), len(per)
            v = None if any(x is None for x in per) else band.value
        out[(key0, str(c.get("name")))] = Value(
            None if v is None else float(v), unit, str(c.get("metric")),
            baseline.better_side(c), str(c.get("outcome", "")), band, n)


def _run_folder(d: Path) -> dict[Key, Value] | None:
    try:
        data = json.loads((d / "result.json").read_text())
    except (OSError, ValueError):
        return None
    out: dict[Key, Value] = {}
    if data.get("schema") == "hil-suite/1":
        for e in data.get("scenarios") or []:
            _from_criteria(str(e.get("name")), str(e.get("profile")), e.get("criteria"), out)
    elif data.get("schema") == "hil-result/1":
        _from_criteria(str(data.get("scenario")), str(data.get("profile")),
                       data.get("criteria"), out)
    else:
        return None
    return out


def _seed_folders(d: Path) -> dict[Key, Value] | None:
    seeds = sorted(p for p in d.glob("seed-*") if p.is_dir())
    if not seeds:
        return None
    per: dict[Key, list[Value]] = {}
    for s in seeds:
        for run in sorted(p for p in s.iterdir() if p.is_dir()):
            got = _run_folder(run)
            for k, v in (got or {}).items():
                per.setdefault(k, []).append(v)
    out: dict[Key, Value] = {}
    for k, vs in per.items():
        band = baseline.Band.of([v.value for v in vs], vs[0].unit)
        outcomes = sorted({v.outcome for v in vs})
        out[k] = Value(band.value, vs[0].unit, vs[0].metric, vs[0].better, "/".join(outcomes),
                       band, len(vs))
    return out


def _baseline_values(b: baseline.Baseline) -> dict[Key, Value]:
    out: dict[Key, Value] = {}
    for key, e in b.entries.items():
        for name, r in e.records.items():
            out[(key, name)] = Value(r.band.value, r.unit, r.metric, r.better, r.outcome,
                                     r.band, len(b.seeds))
    return out


def load_side(spec: str) -> Side:
    """A side from its command-line spelling."""
    if spec.startswith("baseline:"):
        path = baseline.path_of(spec.split(":", 1)[1])
        return Side(spec, _baseline_values(_load_baseline(path)), True)
    p = Path(spec)
    if p.is_file() and p.suffix == ".toml":
        return Side(spec, _baseline_values(_load_baseline(p)), True)
    if p.is_dir():
        got = _run_folder(p)
        if got is None:
            got = _seed_folders(p)
        if got is not None:
            return Side(spec, got)
    raise CompareError(f"{spec}: not a run or suite folder (result.json), a baseline record "
                       "folder (seed-N/), a baseline file or baseline:SUITE")


def _load_baseline(path: Path) -> baseline.Baseline:
    try:
        return baseline.Baseline.load(path)
    except baseline.BaselineError as exc:
        raise CompareError(str(exc)) from exc


# --------------------------------------------------------------------------------------
# The table


def _half(band: baseline.Band | None) -> float | None:
    if band is None or band.value is None or not math.isfinite(band.lo):
        return None
    return (band.hi - band.lo) / 2.0


def _committed_half(key: Key) -> float | None:
    try:
        b = baseline.index().for_key(key[0])
    except baseline.BaselineError:
        return None
    rec = b.entries[key[0]].records.get(key[1]) if b is not None else None
    return _half(rec.band) if rec is not None else None


def _num(v: Value | None) -> float | None:
    if v is None or v.value is None or not math.isfinite(v.value):
        return None
    return v.value


def row(key: Key, a: Value | None, b: Value | None) -> Row:
    if a is None or b is None:
        return Row(key, a, b, None, None, "added" if a is None else "removed")
    va, vb = _num(a), _num(b)
    better = b.better or a.better
    if va is None or vb is None:
        if va is None and vb is None:
            return Row(key, a, b, None, None, "unchanged")
        worse_b = vb is None  # no number is the worst of its side
        cls = "changed" if better == baseline.EITHER else (
            "regressed" if worse_b else "improved")
        return Row(key, a, b, None, None, cls)
    diff = vb - va
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
        half = _committed_half(key)
    if half is None:
        return Row(key, a, b, diff, None, "unknown" if diff != 0 else "unchanged")
    if abs(diff) <= half:
        return Row(key, a, b, diff, half, "unchanged")
    if better == baseline.EITHER:
        return Row(key, a, b, diff, half, "changed")
    worse = diff > 0 if better == baseline.LOWER else diff < 0
    return Row(key, a, b, diff, half, "regressed" if worse else "improved")


def compare(a: Side, b: Side) -> list[Row]:
    keys = list(dict.fromkeys([*a.values, *b.values]))
    return [row(k, a.values.get(k), b.values.get(k)) for k in keys]


def baselines(old: baseline.Baseline, new: baseline.Baseline) -> list[Row]:
    return compare(Side("old", _baseline_values(old), True),
                   Side("new", _baseline_values(new), True))


MOVED = ("regressed", "changed", "improved", "added", "removed", "unknown")


def counts(rows: list[Row]) -> dict[str, int]:
    out: dict[str, int] = {}
    for r in rows:
        out[r.cls] = out.get(r.cls, 0) + 1
    return out


def summary_line(rows: list[Row], what: str = "") -> str:
    c = counts(rows)
    parts = ", ".join(f"{c[k]} {k}" for k in ("regressed", "changed", "improved", "unknown",
                                               "added", "removed", "unchanged") if c.get(k))
    return f"{len(rows)} criteria{' ' + what if what else ''}: {parts or 'none'}"


def _fmt(v: float | None) -> str:
    return "—" if v is None else f"{v:.4g}"


def markdown(rows: list[Row], only_changed: bool = True, a_label: str = "A",
             b_label: str = "B") -> str:
    shown = [r for r in rows if not only_changed or r.cls in MOVED]
    order = {k: i for i, k in enumerate((*MOVED, "unchanged"))}
    shown.sort(key=lambda r: (order.get(r.cls, 99), r.key))
    lines = [f"| scenario | criterion | metric | {a_label} | {b_label} | B - A | seed spread "
             "(±) | |", "|---|---|---|---|---|---|---|---|"]
    for r in shown:
        v = r.a or r.b
        assert v is not None
        unit = f" {v.unit}" if v.unit else ""
        lines.append(
            f"| {r.key[0]} | {r.key[1]} | `{v.metric}` | {_fmt(_num(r.a))}{unit} | "
            f"{_fmt(_num(r.b))}{unit} | {_fmt(r.diff)} | {_fmt(r.half_band)} | "
            f"{r.cls.upper() if r.cls in ('regressed', 'changed') else r.cls} |")
    if len(lines) == 2:
        lines.append("| (no criterion moved beyond its seed spread) | | | | | | | |")
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
             "a": _num(r.a), "b": _num(r.b), "diff": r.diff, "spread": r.half_band,
             "class": r.cls} for r in rows]
