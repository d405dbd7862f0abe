"""A run's pictures, written into its folder and shown in its report.md.

- ``figure.png``: the run at a glance from its capture: the position error of every period,
  the speeds (reference, true, estimated), the true currents and the load torque; the
  windows of the criteria that did not pass are shaded.
- ``criterion-<n>.png`` for each criterion that failed (or XPASSed, or was XFAIL; one not
  evaluated has no window to show): the
  capture columns its metric read, over its window (shaded) and a margin either side, with the
  limit drawn where the limit is in a plotted column's unit (a max/min/mean of one column),
  and the value against the limit in the title.

Cheap by construction, as it runs for every scenario: matplotlib's object API on the Agg
canvas (no pyplot state), imported on first use (and in the background once a run's loop
runs: ``rig.run.execution``), every series reduced to at most ``MAX_POINTS`` points by
keeping each bucket's minimum and maximum (a peak is never dropped), a small DPI.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rig import protocols
from rig.data import capture, metrics
from rig.results.whole import whole

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from rig.results.result import Criterion

OVERVIEW = "figure.png"
# what drawing imports (in the background while a run's loop runs: rig.run.execution)
MODULES = ("rig.results.figures", "matplotlib.figure", "matplotlib.backends.backend_agg")
MAX_POINTS = 1500  # per series: buckets of min and max
DPI = 80
SHOWN = ("fail", "xfail", "xpass")  # criteria that get a picture (not evaluated: no window)
SHADE = {"fail": "tab:red", "not_evaluated": "tab:gray", "xfail": "tab:orange",
         "xpass": "tab:purple"}
MARGIN = 0.25  # of the window's length, either side


def envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS
             ) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) reduced to at most ``max_points`` points: each bucket's minimum and maximum in
    time order, so every peak stays."""
    n = len(y)
    if n <= max_points:
        return t, y
    size = math.ceil(n / (max_points // 2))
    buckets = math.ceil(n / size)
    pad = buckets * size - n  # (less than one bucket: only the last is padded)
    yy = np.concatenate([y, np.full(pad, np.nan)]).reshape(buckets, size)
    tt = np.concatenate([t, np.full(pad, t[-1])]).reshape(buckets, size)
    finite = np.isfinite(yy)
    yy_lo = np.where(finite, yy, np.inf)
    yy_hi = np.where(finite, yy, -np.inf)
    lo, hi = np.argmin(yy_lo, axis=1), np.argmax(yy_hi, axis=1)
    rows = np.arange(buckets)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    t_out = np.stack([tt[rows, first], tt[rows, second]], axis=1).ravel()
    y_out = np.stack([yy[rows, first], yy[rows, second]], axis=1).ravel()
    return t_out, y_out


def column_unit(name: str) -> str:
    """A capture column's unit: the rig's derived ones, else the DBC signal's."""
    if name in capture.DERIVED_UNITS:
        return capture.DERIVED_UNITS[name]
    prefix, _, signal = name.partition(".")
    for spec in capture.default_specs(Path("plant.trace"), Path("fw.trace")):
        for message, pre in spec.messages.items():
            if pre != prefix:
                continue
            for db in protocols.DATABASES:
                try:
                    sig = protocols.database(db).get_message_by_name(message)\
                        .get_signal_by_name(signal)
                except KeyError:
                    continue
                return str(sig.unit or "")
    return ""


def _canvas(rows: int, height: float) -> tuple[Any, list[Axes]]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, height), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    # fixed margins (in inches for the title and the time axis): a layout engine would
    # double the cost of a figure
    fig.subplots_adjust(left=0.1, right=0.91, top=1.0 - 0.6 / height, bottom=0.5 / height,
                        hspace=0.3)
    return fig, list(axes)


def _times(cap: capture.Capture) -> np.ndarray:
    return np.asarray(cap["period"], dtype=np.float64) * cap.ts


def _plot(ax: Axes, cap: capture.Capture, t: np.ndarray, name: str, label: str,
          **style: Any) -> None:
    if name in cap:
        tt, yy = envelope(t, np.asarray(cap[name], dtype=np.float64))
        ax.plot(tt, yy, label=label, lw=style.pop("lw", 0.8), **style)


def overview(cap: capture.Capture, result: Mapping[str, Any], path: Path) -> None:
    fig, (a_err, a_speed, a_cur) = _canvas(3, 6.6)
    t = _times(cap)
    fig.suptitle(f"{result.get('scenario')} ({result.get('profile')}, {result.get('mode')}, "
                 f"{result.get('bus')}): {'PASS' if result.get('passed') else 'FAIL'}",
                 fontsize=10)
    _plot(a_err, cap, t, "pos_err_deg", "θ est - θ (electrical)", color="tab:blue", lw=0.6)
    a_err.set_ylabel("position error (°)")
    _plot(a_speed, cap, t, "speed_ref_rpm", "reference", color="black", lw=1.0)
    _plot(a_speed, cap, t, "speed_true_rpm", "true (plant)", color="tab:green")
    _plot(a_speed, cap, t, "speed_hat_rpm", "estimated (firmware)", color="tab:orange",
          lw=0.5, alpha=0.8)
    a_speed.set_ylabel("speed (r/min)")
    _plot(a_cur, cap, t, "truth.id", "id (true)", color="tab:blue")
    _plot(a_cur, cap, t, "truth.iq", "iq (true)", color="tab:red")
    a_cur.set_ylabel("current (A)")
    a_cur.set_xlabel("time (s)")
    if "truth.tl" in cap:
        a_load = a_cur.twinx()
        _plot(a_load, cap, t, "truth.tl", "load torque", color="tab:gray", lw=1.0)
        a_load.set_ylabel("load (N·m)")
        a_load.legend(loc="upper right", fontsize=7)
    for c in result.get("criteria") or []:
        outcome = str(c.get("outcome"))
        if outcome in ("fail", "not_evaluated"):
            for ax in (a_err, a_speed, a_cur):
                ax.axvspan(c["window"][0], c["window"][1], color=SHADE[outcome], alpha=0.12)
    for ax in (a_err, a_speed, a_cur):
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper left", fontsize=7)
    save(fig, path)


def save(fig: Any, path: Path) -> None:
    """A figure as PNG, whole or not at all (``rig.results.whole``)."""
    with whole(path) as tmp:
        fig.savefig(tmp, format="png")


def _limit_lines(c: Mapping[str, Any], columns: Sequence[str]) -> list[float]:
    """The limit as lines on the plotted column, when it is in that column's unit and the
    metric is a max, min or mean of it: +limit, and -limit for a magnitude (|x|)."""
    limit = c.get("limit")
    metric = metrics.METRICS.get(str(c.get("metric")))
    if limit is None or metric is None or len(columns) != 1:
        return []
    if column_unit(columns[0]) != (c.get("unit") or "") or not c.get("unit"):
        return []
    what = metric.description
    if re.match(r"(max|99th percentile of) \|", what):
        return [float(limit), -float(limit)]
    if re.match(r"(max|min|minimum|maximum|mean|RMS) ", what):
        return [float(limit)]
    return []


def _magnitude(c: Mapping[str, Any]) -> list[float]:
    limit = c.get("limit")
    metric = metrics.METRICS.get(str(c.get("metric")))
    if limit is None or metric is None or not re.match(r"(max|99th percentile of) \|",
                                                         metric.description):
        return []
    return [float(limit), -float(limit)]


def _difference(c: Mapping[str, Any], columns: Sequence[str]) -> tuple[str, str] | None:
    """The two columns of a metric on their difference (max |true speed - reference|), when
    both are in the criterion's unit: that difference is drawn with the limit."""
    if len(columns) != 2 or not c.get("unit") or not _magnitude(c):
        return None
    if any(column_unit(name) != c.get("unit") for name in columns):
        return None
    return columns[0], columns[1]


def criterion_figure(cap: capture.Capture, c: Mapping[str, Any], counters: Mapping[str, float],
                     path: Path) -> bool:
    """Writes the picture of one criterion; False when its metric reads no capture column (a
    counter, a run metric: nothing to draw)."""
    fig = draw_criterion(cap, c, counters)
    if fig is None:
        return False
    save(fig, path)
    return True


def draw_criterion(cap: capture.Capture, c: Mapping[str, Any], counters: Mapping[str, float]
                   ) -> Any:
    """The figure of one criterion (a matplotlib Figure), or None (nothing read to draw)."""
    t0, t1 = float(c["window"][0]), float(c["window"][1])
    reads: list[tuple[str, int, int]] = []
    w = metrics.Window(cap, t0, t1, ts=cap.ts, first_period=cap.first_period,
                       counters=counters, reads=reads)
    try:
        metrics.compute(str(c["metric"]), w, c.get("params") or {})
    except (KeyError, ValueError):
        return None
    columns = list(dict.fromkeys(name for name, _, _ in reads if name != "period"))
    if not columns:
        return None
    difference = _difference(c, columns)
    span = max(t1 - t0, cap.ts)
    lo, hi = t0 - MARGIN * span, t1 + MARGIN * span
    t = _times(cap)
    sel = (t >= lo) & (t <= hi)
    rows = len(columns) + (difference is not None)
    fig, axes = _canvas(rows, 1.2 + 1.6 * rows)
    value = c.get("value")
    shown = "n/a" if value is None else f"{value:.4g}"
    bound = "reported" if c.get("limit") is None else \
        f"{c.get('comparison', '<=')} {c['limit']:g}"
    unit = c.get("unit") or ""
    fig.suptitle(f"{c.get('name')}: {str(c.get('outcome')).upper()}\n{c.get('metric')} = "
                 f"{shown} {unit} (limit {bound} {unit}) over [{t0:g}, {t1:g}] s", fontsize=9)
    panels: list[tuple[str, np.ndarray, list[float]]] = [
        (name, np.asarray(cap[name], dtype=np.float64)[sel], _limit_lines(c, columns))
        for name in columns]
    if difference is not None:
        a, b = difference
        panels = [(name, y, []) for name, y, _ in panels]
        panels.append((f"{a} - {b}", np.asarray(cap[a], dtype=np.float64)[sel]
                       - np.asarray(cap[b], dtype=np.float64)[sel], _magnitude(c)))
    for ax, (name, values, lines) in zip(axes, panels, strict=True):
        tt, yy = envelope(t[sel], values)
        ax.plot(tt, yy, lw=0.8, color="tab:blue", label=name)
        ax.axvspan(t0, t1, color=SHADE.get(str(c.get("outcome")), "tab:gray"), alpha=0.15,
                   label="window")
        for k, y in enumerate(lines):
            ax.axhline(y, color="tab:red", ls="--", lw=1.0,
                       label=f"limit {bound} {unit}" if k == 0 else None)
        col_unit = column_unit(name.split(" - ")[0])
        short = "difference" if " - " in name else name
        ax.set_ylabel(short + (f" ({col_unit})" if col_unit else ""), fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=7)
    axes[-1].set_xlabel("time (s)")
    return fig


def write(out: Path, cap: capture.Capture, result: Mapping[str, Any]) -> dict[str, Any]:
    """Writes the run's pictures; what result.json says of them (``files``: name, what it
    shows, the criterion; the CPU and wall seconds they took)."""
    cpu0, wall0 = time.thread_time(), time.perf_counter()  # this thread: the drawing
    files: list[dict[str, Any]] = []
    overview(cap, result, out / OVERVIEW)
    files.append({"path": OVERVIEW, "shows": "overview"})
    counters = result.get("counters") or {}
    criteria: Sequence[Criterion] = result.get("criteria") or []
    for k, c in enumerate(criteria):
        if str(c.get("outcome")) not in SHOWN:
            continue
        name = f"criterion-{k + 1}.png"
        if criterion_figure(cap, c, counters, out / name):
            files.append({"path": name, "shows": "criterion", "criterion": c.get("name")})
    return {"files": files, "cpu_s": round(time.thread_time() - cpu0, 4),
            "wall_s": round(time.perf_counter() - wall0, 4)}
