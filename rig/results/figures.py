"""A run's pictures, written into its folder and shown in its report.md.

- ``figure.png``: the run at a glance from its capture: the position error of every period,
  the speeds (reference, true, estimated), the true currents and the load torque; the
  windows of the criteria that did not pass are shaded. A scenario with faults has each
  fault's start (and end) marked on every panel and the firmware's state (FW_TRACE.state,
  by its DBC names) as a strip below.
- ``criterion-<n>.png`` for each criterion that failed (or XPASSed, or was XFAIL; one not
  evaluated has no window to show): the
  capture columns its metric read, over its window (shaded) and a margin either side, with the
  limit drawn on the quantity it applies to: on the column where the limit is in its unit (a
  max/min/mean of one column), on the difference of two columns a metric bounds, and for a
  phase current's peak on the three phase currents (ic = -ia - ib, where the peak often is)
  at +-limit; the firmware's state as a strip by its DBC names; the faults marked; the value
  against the limit in the title (enumerated values by name: ``rig.results.shown``).

Every artist a reader checks carries a ``gid`` (``limit``, ``fault-start``, ``fault-end``,
``fw-state``, ``window``), so tests read what a figure shows from the Figure object.

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
from rig.results import shown
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


def _canvas(rows: int, height: float, ratios: Sequence[float] | None = None
            ) -> tuple[Any, list[Axes]]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, height), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False,
                        gridspec_kw={"height_ratios": list(ratios)} if ratios else None)[:, 0]
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


def fault_events(result: Mapping[str, Any]) -> list[tuple[float, float | None, str]]:
    """Each fault of a run: (start s, end s or None: to the end, what it is)."""
    out: list[tuple[float, float | None, str]] = []
    for f in result.get("faults") or []:
        at = float(f.get("at", 0.0))
        end = at + float(f["duration"]) if f.get("duration") else None
        what = " ".join([str(f.get("kind")), *(f"{v}" for k, v in f.items()
                                               if k not in ("kind", "at", "duration"))])
        out.append((at, end, what))
    return out


def mark_faults(axes: Sequence[Axes], faults: Sequence[tuple[float, float | None, str]],
                lo: float = -math.inf, hi: float = math.inf) -> None:
    """Each fault's start (solid) and end (dash-dotted) on every panel, labelled on the first."""
    for at, end, what in faults:
        for i, ax in enumerate(axes):
            if lo <= at <= hi:
                ax.axvline(at, color="tab:red", lw=1.2, gid="fault-start",
                           label=f"fault: {what} at {at:g} s" if i == 0 else None)
            if end is not None and lo <= end <= hi:
                ax.axvline(end, color="tab:red", lw=1.2, ls="-.", gid="fault-end",
                           label=f"fault ends at {end:g} s" if i == 0 else None)


def state_strip(ax: Axes, t: np.ndarray, state: np.ndarray) -> None:
    """The firmware's state over time as a step line, its levels named as the DBC names
    them (``RUN (3)``)."""
    enum = metrics.enumerated("fw.state")
    assert enum is not None
    tt, yy = envelope(t, np.asarray(state, dtype=np.float64))
    ax.step(tt, yy, where="post", color="black", lw=1.0, gid="fw-state",
            label="firmware state (FW_TRACE.state)")
    levels = sorted({float(v) for v in np.unique(yy[np.isfinite(yy)])})
    ax.set_yticks(levels, [protocols.named_value(*enum, v) for v in levels], fontsize=7)
    if levels:
        ax.set_ylim(levels[0] - 0.6, levels[-1] + 0.6)


def draw_overview(cap: capture.Capture, result: Mapping[str, Any]) -> Any:
    """The overview figure (a matplotlib Figure)."""
    faults = fault_events(result)
    strip = bool(faults) and "fw.state" in cap
    fig, axes = _canvas(4 if strip else 3, 7.6 if strip else 6.6,
                        (1.0, 1.0, 1.0, 0.45) if strip else None)
    a_err, a_speed, a_cur = axes[:3]
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
    if "truth.tl" in cap:
        a_load = a_cur.twinx()
        _plot(a_load, cap, t, "truth.tl", "load torque", color="tab:gray", lw=1.0)
        a_load.set_ylabel("load (N·m)")
        a_load.legend(loc="upper right", fontsize=7)
    if strip:
        state_strip(axes[3], t, np.asarray(cap["fw.state"]))
    for c in result.get("criteria") or []:
        outcome = str(c.get("outcome"))
        if outcome in ("fail", "not_evaluated"):
            for ax in axes:
                ax.axvspan(c["window"][0], c["window"][1], color=SHADE[outcome], alpha=0.12)
    mark_faults(axes, faults)
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper left", fontsize=7)
    axes[-1].set_xlabel("time (s)")
    return fig


def overview(cap: capture.Capture, result: Mapping[str, Any], path: Path) -> None:
    save(draw_overview(cap, result), path)


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


PHASES = ("truth.ia", "truth.ib")  # the phase currents the capture holds; ic = -ia - ib


def _phase_lines(c: Mapping[str, Any]) -> list[tuple[float, str]]:
    """The bound a phase-current metric puts on |ia|, |ib| and |ic|: for a peak its limit,
    for the safe state its ``i_safe_a`` (+- each)."""
    metric = metrics.METRICS.get(str(c.get("metric")))
    if metric is None:
        return []
    if "i_safe_a" in metric.params:
        level = float((c.get("params") or {}).get("i_safe_a", metric.params["i_safe_a"]))
        label = f"i_safe_a {level:g} A: |ia|, |ib|, |ic| within"
    elif c.get("limit") is not None and c.get("unit") == "A":
        level = float(c["limit"])
        label = f"limit {shown.bound(c)} on |ia|, |ib|, |ic|"
    else:
        return []
    return [(level, label), (-level, "")]


def criterion_figure(cap: capture.Capture, c: Mapping[str, Any], counters: Mapping[str, float],
                     path: Path, faults: Sequence[tuple[float, float | None, str]] = ()
                     ) -> bool:
    """Writes the picture of one criterion; False when its metric reads no capture column (a
    counter, a run metric: nothing to draw)."""
    fig = draw_criterion(cap, c, counters, faults)
    if fig is None:
        return False
    save(fig, path)
    return True


def draw_criterion(cap: capture.Capture, c: Mapping[str, Any], counters: Mapping[str, float],
                   faults: Sequence[tuple[float, float | None, str]] = ()) -> Any:
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
    span = max(t1 - t0, cap.ts)
    lo, hi = t0 - MARGIN * span, t1 + MARGIN * span
    counted = [float(c[k]) for k in ("value", "limit") if c.get(k) is not None
               and math.isfinite(float(c[k]))]
    if c.get("unit") == "periods" and counted:  # a count from the window's start: zoom in
        focus = max(*counted, 10.0) * cap.ts
        lo, hi = t0 - 0.5 * focus, min(hi, t0 + 2.0 * focus)
    t = _times(cap)
    if t.size:  # (no margin past the capture's end)
        lo, hi = max(lo, float(t[0])), min(hi, float(t[-1]))
    sel = (t >= lo) & (t <= hi)

    def col(name: str) -> np.ndarray:
        return np.asarray(cap[name], dtype=np.float64)[sel]

    # (title, [(label, values)], [(level, label)], unit)
    panels: list[tuple[str, list[tuple[str, np.ndarray]], list[tuple[float, str]], str]] = []
    rest = [name for name in columns if name not in (*PHASES, "fw.state")]
    peak: tuple[float, float, str] | None = None
    if all(p in columns for p in PHASES):
        ia, ib = col(PHASES[0]), col(PHASES[1])
        phases = {"ia": ia, "ib": ib, "ic": -ia - ib}
        panels.append(("phase currents", [("ia (true)", ia), ("ib (true)", ib),
                                          ("ic = -ia - ib (true)", phases["ic"])],
                       _phase_lines(c), "A"))
        inside = (t[sel] >= t0) & (t[sel] <= t1)
        if inside.any():  # where the largest |phase current| of the window is, and in which
            name, k = max(((n, int(np.argmax(np.where(inside, np.abs(v), -1.0))))
                           for n, v in phases.items()), key=lambda x: abs(phases[x[0]][x[1]]))
            peak = (float(t[sel][k]), float(phases[name][k]), name)
    else:
        rest = [name for name in columns if name != "fw.state"]
    difference = _difference(c, rest)
    bound = shown.bound(c)
    for name in rest:
        lines = [] if difference is not None else [
            (y, f"limit {bound}" if k == 0 else "") for k, y in enumerate(_limit_lines(c, rest))]
        panels.append((name, [(name, col(name))], lines, column_unit(name)))
    if difference is not None:
        a, b = difference
        panels.append((f"{a} - {b}", [(f"{a} - {b}", col(a) - col(b))],
                       [(y, f"limit {bound}" if k == 0 else "")
                        for k, y in enumerate(_magnitude(c))], column_unit(a)))
    strip = "fw.state" in columns
    rows = len(panels) + strip
    fig, axes = _canvas(rows, 1.4 + 2.0 * len(panels) + 0.9 * strip,
                        [1.0] * len(panels) + [0.45] * strip)
    fig.suptitle(f"{c.get('name')}: {str(c.get('outcome')).upper()}\n{shown.measured(c)} "
                 f"(limit {bound}) over [{t0:g}, {t1:g}] s", fontsize=9)
    colors = ("tab:blue", "tab:orange", "tab:green")
    for ax, (title, series, lines, unit) in zip(axes, panels, strict=False):
        for k, (label, values) in enumerate(series):
            tt, yy = envelope(t[sel], values)
            ax.plot(tt, yy, lw=0.8, color=colors[k % len(colors)], label=label)
        for y, label in lines:
            ax.axhline(y, color="tab:red", ls="--", lw=1.0, gid="limit", label=label or None)
        short = "difference" if " - " in title and len(series) == 1 else title
        ax.set_ylabel(short + (f" ({unit})" if unit else ""), fontsize=8)
        if peak is not None and title == "phase currents":
            ax.plot([peak[0]], [peak[1]], "o", color="black", ms=5, gid="peak",
                    label=f"peak |{peak[2]}| = {abs(peak[1]):.4g} A at {peak[0]:.4g} s")
    if strip:
        state_strip(axes[-1], t[sel], np.asarray(cap["fw.state"])[sel])
        if metrics.enumerated(str(c.get("metric"))) == metrics.enumerated("fw.state") \
                and c.get("limit") is not None:  # a state the criterion asks for, by name
            axes[-1].axhline(float(c["limit"]), color="tab:red", ls="--", lw=1.0, gid="limit",
                             label=f"limit {bound}")
    for ax in axes:
        ax.axvspan(t0, t1, color=SHADE.get(str(c.get("outcome")), "tab:gray"), alpha=0.15,
                   label="window", gid="window")
    if c.get("unit") == "periods":  # periods counted from the window's start: a time
        for k, ax in enumerate(axes):
            if c.get("value") is not None:
                ax.axvline(t0 + float(c["value"]) * cap.ts, color="black", ls=":", lw=1.2,
                           gid="value", label=f"{c.get('metric')} = {c['value']:g} periods"
                           if k == 0 else None)
            if c.get("limit") is not None:
                ax.axvline(t0 + float(c["limit"]) * cap.ts, color="tab:red", ls="--", lw=1.0,
                           gid="limit", label=f"limit {bound}" if k == 0 else None)
    mark_faults(axes, faults, lo, hi)
    axes[0].set_xlim(lo, hi)  # (the window's shading may reach beyond a zoomed view)
    fig.subplots_adjust(right=0.7)  # the legends beside the panels: the data stays in view
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, borderaxespad=0)
    axes[-1].set_xlabel("time (s)")
    return fig


def write(out: Path, cap: capture.Capture, result: Mapping[str, Any]) -> dict[str, Any]:
    """Writes the run's pictures; what result.json says of them (``files``: name, what it
    shows, the criterion; the CPU and wall seconds they took)."""
    cpu0, wall0 = time.thread_time(), time.perf_counter()  # this thread: the drawing
    files: list[dict[str, Any]] = []
    overview(cap, result, out / OVERVIEW)
    files.append({"path": OVERVIEW, "shows": "overview"})
    faults = fault_events(result)
    counters = result.get("counters") or {}
    criteria: Sequence[Criterion] = result.get("criteria") or []
    for k, c in enumerate(criteria):
        if str(c.get("outcome")) not in SHOWN:
            continue
        name = f"criterion-{k + 1}.png"
        if criterion_figure(cap, c, counters, out / name, faults):
            files.append({"path": name, "shows": "criterion", "criterion": c.get("name")})
    return {"files": files, "cpu_s": round(time.thread_time() - cpu0, 4),
            "wall_s": round(time.perf_counter() - wall0, 4)}
