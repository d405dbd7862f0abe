"""The run's Rerun recording (``recording.rrd``) and the live view.

``write()`` logs the merged capture columnar (``rr.send_columns``) chunk by chunk on the
timeline ``sim_time`` (duration, exact: ``period * 100 µs``; the period index is
``sim_time / 100 µs``), with a blueprint laying out the paper's figures. Two kinds of data:

- the display series (θ, θ est, position error, speeds, currents, ... and the 2-D trajectories)
  every ``step``-th period: 1 kHz (every 10th period), coarser for long runs so that a series
  has at most ``display_max_rows`` rows;
- the evidence: every capture column a criterion read, at the full 10 kHz over exactly the
  rows it read (``evidence``, from ``rig.data.metrics.Window.reads``), in the entity
  ``criteria/data`` (one line per column, the capture's values; NaN where a column was not
  read) with the ranges in ``criteria/manifest`` (JSON). Every criterion of ``result.json``
  can be computed again from the recording alone (``read_evidence``).

The assertion data is the capture (``capture/*.npy``) while it is kept; this file is what
every run keeps.

``LiveView`` logs the decimated telemetry seen on the bus while a run is going on.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import rerun as rr
import rerun.blueprint as rrb

from rig import protocols
from rig.data.capture import Capture
from rig.results.whole import whole

APP_ID = "sensorless_hil"
TS_NS = protocols.timebase().period_ns  # one PWM period in ns
# display series: every 10th period (1 kHz of simulated time, the telemetry's rate) ...
DISPLAY_DECIMATE = protocols.timebase().speed_loop_divider
DISPLAY_MAX_ROWS = 2000  # ... and at most this many rows per series (long runs: coarser)
CHUNK = 1 << 16
TRAIL_S = 0.1  # trajectories show the last 100 ms around the time cursor
# line colours within one plot (true, estimate, reference, ... tell apart)
PALETTE = ([70, 160, 70], [230, 120, 40], [70, 130, 230], [200, 60, 160], [150, 150, 150],
           [220, 200, 60])
EVIDENCE_ENTITY = "criteria/data"
EVIDENCE_MANIFEST = "criteria/manifest"

Arr = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Series:
    entity: str
    keys: tuple[str, ...]
    names: tuple[str, ...]


SERIES: tuple[Series, ...] = (
    Series("position/theta", ("theta_true_deg", "theta_hat_deg"), ("θ (true)", "θ est")),
    Series("position/error", ("pos_err_deg",), ("θ est - θ (deg el.)",)),
    Series("speed/rpm", ("speed_ref_rpm", "speed_true_rpm", "speed_hat_rpm"),
           ("reference", "true", "estimated")),
    Series("speed/error", ("speed_err_rpm",), ("ω est - ω (r/min)",)),
    Series("current/dq", ("truth.id", "truth.iq", "fw.id", "fw.iq", "fw.id_ref", "fw.iq_ref"),
           ("id", "iq", "id (est. frame)", "iq (est. frame)", "id ref", "iq ref")),
    Series("current/magnitude", ("i_mag",), ("|i|",)),
    Series("voltage/dq", ("fw.vd", "fw.vq", "v_mag"), ("vd", "vq", "|v|")),
    Series("params/ld", ("ld_hat_mh", "ld_inc_mh", "ld_app_mh"),
           ("Ld est", "Ld incremental (true)", "Ld apparent (true)")),
    Series("params/lq", ("lq_hat_mh", "lq_inc_mh", "lq_app_mh"),
           ("Lq est", "Lq incremental (true)", "Lq apparent (true)")),
    Series("params/lambda", ("fw.lambda_hat", "mag.lambda_m"), ("λm est", "λm (true)")),
    Series("flux/alpha_beta", ("flux_alpha_hat", "flux_beta_hat", "flux_alpha_true",
                               "flux_beta_true"),
           ("λα (est.)", "λβ (est.)", "λα (true)", "λβ (true)")),
    Series("torque/nm", ("truth.te", "fw.te_hat", "truth.t_shaft", "truth.tl"),
           ("Te (true)", "Te est", "shaft (sensor)", "load")),
    Series("estimator/state", ("fw.state", "fw.sector", "fw.slopes_ok", "fw.fw_active"),
           ("state", "sector", "slopes ok", "flux weakening")),
    Series("estimator/residual", ("fw.residual",), ("residual (1/H)",)),
    Series("plant/vdc", ("truth.vdc",), ("Vdc",)),
)

# The firmware trace (FW_TRACE, capture columns fw.<signal>) in the recording: a signal no
# series above names is shown by itself as firmware/<signal> (trace_series), so a signal added
# to FW_TRACE in protocols/vio.dbc appears without an edit here. These are shown through a
# display array made from them (_derived, the capture's derived columns) or are the timeline.
TRACE_PREFIX = "fw."
TRACE_ENTITY = "firmware"
SHOWN_DERIVED = frozenset({"fw.period", "fw.stamp", "fw.theta_hat", "fw.omega_hat", "fw.ld_hat",
                           "fw.lq_hat"})


def trace_series(columns: Sequence[str]) -> tuple[Series, ...]:
    """One series for each firmware-trace column no curated series shows."""
    shown = {k for s in SERIES for k in s.keys} | SHOWN_DERIVED
    return tuple(Series(f"{TRACE_ENTITY}/{c[len(TRACE_PREFIX):]}", (c,), (c[len(TRACE_PREFIX):],))
                 for c in columns if c.startswith(TRACE_PREFIX) and c not in shown)


TRAJECTORIES = {
    "trajectory/current": ("truth.id", "truth.iq"),
    "trajectory/flux_est": ("flux_alpha_hat", "flux_beta_hat"),
    "trajectory/flux_true": ("flux_alpha_true", "flux_beta_true"),
}


def _derived(cap: Capture, a: int, b: int) -> dict[str, Arr]:
    """Display arrays for rows [a, b) (everything not stored in the capture as such)."""
    out: dict[str, Arr] = {}

    def col(name: str) -> Arr | None:
        return np.asarray(cap[name][a:b], dtype=np.float64) if name in cap else None

    th = col("truth.theta_e")
    hat = col("fw.theta_hat")
    if th is not None:
        out["theta_true_deg"] = np.mod(np.degrees(th), 360.0)
    if hat is not None:
        out["theta_hat_deg"] = np.mod(np.degrees(hat), 360.0)
    for src, dst in (("fw.ld_hat", "ld_hat_mh"), ("mag.ld_inc", "ld_inc_mh"),
                     ("mag.ld_app", "ld_app_mh"), ("fw.lq_hat", "lq_hat_mh"),
                     ("mag.lq_inc", "lq_inc_mh"), ("mag.lq_app", "lq_app_mh")):
        v = col(src)
        if v is not None:
            out[dst] = v * 1e3
    lam_hat = col("fw.lambda_hat")
    if lam_hat is not None and hat is not None:
        out["flux_alpha_hat"] = lam_hat * np.cos(hat)
        out["flux_beta_hat"] = lam_hat * np.sin(hat)
    lam = col("mag.lambda_m")
    if lam is not None and th is not None:
        out["flux_alpha_true"] = lam * np.cos(th)
        out["flux_beta_true"] = lam * np.sin(th)
    return out


def _get(cap: Capture, extra: Mapping[str, Arr], key: str, a: int, b: int) -> Arr | None:
    if key in extra:
        return extra[key]
    if key in cap:
        return np.asarray(cap[key][a:b], dtype=np.float64)
    return None


# Views every recording's blueprint shows (the web-viewer check waits for their names).
THETA_VIEW = "θ vs θ est (deg el.)"
ERROR_VIEW, SPEED_VIEW = "position error (deg el.)", "speed (r/min)"
VIEW_NAMES = [THETA_VIEW, ERROR_VIEW, SPEED_VIEW]


def blueprint(*, with_counters: bool = True, with_evidence: bool = False) -> rrb.Blueprint:
    trail = rrb.VisibleTimeRange(
        "sim_time",
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-TRAIL_S),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    ts = rrb.TimeSeriesView
    tabs: list[Any] = [
        rrb.Vertical(
            ts(origin="/position/theta", name=THETA_VIEW),
            ts(origin="/position/error", name=ERROR_VIEW),
            name="Position (Fig. 5, 6, 11)",
        ),
        rrb.Vertical(
            ts(origin="/speed/rpm", name=SPEED_VIEW),
            ts(origin="/speed/error", name="speed error (r/min)"),
            name="Speed (Fig. 5, 9a, 10a, 11b, 12)",
        ),
        rrb.Horizontal(
            rrb.Vertical(
                ts(origin="/current/dq", name="id / iq (A)"),
                ts(origin="/current/magnitude", name="|i| (A)"),
                ts(origin="/voltage/dq", name="vd / vq (V)"),
            ),
            rrb.Spatial2DView(origin="/trajectory/current", name="current trajectory (id, iq)",
                              time_ranges=trail),
            name="Currents (Fig. 9b, 10b, 10c)",
        ),
        rrb.Horizontal(
            rrb.Vertical(
                ts(origin="/flux/alpha_beta", name="λα / λβ (Wb)"),
                ts(origin="/params/lambda", name="|λ| (Wb)"),
            ),
            rrb.Spatial2DView(
                origin="/trajectory", contents=["/trajectory/flux_est", "/trajectory/flux_true"],
                name="flux circle (λα, λβ)", time_ranges=trail,
            ),
            name="Flux (Fig. 8)",
        ),
        rrb.Vertical(
            ts(origin="/params/ld", name="Ld (mH)"),
            ts(origin="/params/lq", name="Lq (mH)"),
            ts(origin="/params/lambda", name="λm (Wb)"),
            name="Parameters (Fig. 7)",
        ),
        rrb.Vertical(ts(origin="/torque", name="torque (N·m)"), name="Torque (Fig. 9c)"),
    ]
    bus_views: list[Any] = [
        ts(origin="/estimator/state", name="estimator state"),
        ts(origin="/estimator/residual", name="slope residual"),
        ts(origin=f"/{TRACE_ENTITY}", name="firmware trace, other signals"),
        ts(origin="/plant/vdc", name="DC link (V)"),
        ts(origin="/timing", name="lockstep timing"),
    ]
    if with_counters:
        bus_views.append(ts(origin="/counters", name="bus and plant counters"))
    tabs.append(rrb.Grid(*bus_views, name="Bus & timing"))
    if with_evidence:
        tabs.append(rrb.Vertical(
            ts(origin=f"/{EVIDENCE_ENTITY}", name="what the criteria read (10 kHz)"),
            name="Criteria (full rate)",
        ))
    tabs.append(rrb.TextDocumentView(origin="/report", name="Report"))
    return rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=False)


@dataclass
class TimedSamples:
    """Samples at given periods (grant timing, counters received on the bus)."""

    periods: Sequence[int]
    values: Mapping[str, Sequence[float]]


Ranges = Sequence[tuple[int, int]]


def merge_ranges(ranges: Ranges) -> list[tuple[int, int]]:
    """Row ranges ``[a, b)`` sorted and merged (overlapping or touching ones joined)."""
    out: list[tuple[int, int]] = []
    for a, b in sorted((int(a), int(b)) for a, b in ranges if b > a):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def evidence_ranges(reads: Sequence[tuple[str, int, int]]) -> dict[str, list[tuple[int, int]]]:
    """The rows each column was read on (``rig.data.metrics.Window.reads``), merged."""
    by: dict[str, list[tuple[int, int]]] = {}
    for name, a, b in reads:
        by.setdefault(name, []).append((a, b))
    return {name: merge_ranges(r) for name, r in sorted(by.items())}


def display_step(n: int, decimate: int = DISPLAY_DECIMATE,
                 max_rows: int = DISPLAY_MAX_ROWS) -> int:
    """Every how many periods the display series are logged for a run of ``n`` periods."""
    return max(decimate, math.ceil(n / max_rows)) if max_rows > 0 else decimate


def write(path: str | Path, cap: Capture, **options: Any) -> dict[str, Any]:
    """Writes the recording whole or not at all (``rig.results.whole``: a full disk or a
    signal leaves no recording cut short, and no 0-byte one); returns what was written (rows
    per entity, display step, evidence columns and rows). Options: ``_write_to``'s."""
    path = Path(path)
    with whole(path) as tmp:
        info = _write_to(tmp, cap, recording_id=options.pop("recording_id", None)
                         or f"hil-{path.parent.name}", **options)
    info["path"] = str(path)
    return info


def _write_to(
    path: str | Path,
    cap: Capture,
    *,
    title: str = "",
    report_markdown: str = "",
    timing: TimedSamples | None = None,
    counters: TimedSamples | None = None,
    evidence: Mapping[str, Ranges] | None = None,
    decimate: int = DISPLAY_DECIMATE,
    display_max_rows: int = DISPLAY_MAX_ROWS,
    recording_id: str | None = None,
) -> dict[str, Any]:
    path = Path(path)
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id or f"hil-{path.parent.name}")
    try:
        return _log_all(rec, path, cap, title, report_markdown, timing, counters, evidence,
                        decimate, display_max_rows)
    except BaseException:
        with contextlib.suppress(Exception):  # the file sink lets go of the file
            rec.disconnect()
        raise


def _log_all(rec: rr.RecordingStream, path: Path, cap: Capture, title: str,
             report_markdown: str, timing: TimedSamples | None,
             counters: TimedSamples | None, evidence: Mapping[str, Ranges] | None,
             decimate: int, display_max_rows: int) -> dict[str, Any]:
    evidence = {k: merge_ranges(v) for k, v in (evidence or {}).items() if k in cap}
    evidence = {k: v for k, v in evidence.items() if v}
    rec.save(path, default_blueprint=blueprint(with_counters=counters is not None,
                                               with_evidence=bool(evidence)))
    if title:
        rec.send_recording_name(title)
    step = display_step(cap.n, decimate, display_max_rows)
    rows: dict[str, int] = {}

    probe = _derived(cap, 0, min(cap.n, 1))
    candidates = (*SERIES, *trace_series(cap.columns))
    present = {k for s in candidates for k in s.keys if k in probe or k in cap}
    series = [
        Series(s.entity, tuple(k for k in s.keys if k in present),
               tuple(nm for k, nm in zip(s.keys, s.names, strict=True) if k in present))
        for s in candidates
    ]
    series = [s for s in series if s.keys]
    for s in series:
        rec.log(s.entity, rr.SeriesLines(names=list(s.names),
                                         colors=[PALETTE[i % len(PALETTE)]
                                                 for i in range(len(s.names))]), static=True)
    colors = {"trajectory/current": [40, 120, 220], "trajectory/flux_est": [220, 80, 40],
              "trajectory/flux_true": [60, 160, 60]}

    for a in range(0, cap.n, CHUNK):
        b = min(cap.n, a + CHUNK)
        periods = np.asarray(cap["period"][a:b], dtype=np.int64)
        sel = _every(periods, step)
        extra = _derived(cap, a, b)
        for s in series:
            arrays = [_get(cap, extra, k, a, b) for k in s.keys]
            if any(x is None for x in arrays):
                continue
            data = np.stack([x[sel] for x in arrays if x is not None], axis=1)
            _send(rec, s.entity, periods[sel], rr.Scalars.columns(scalars=data))
            rows[s.entity] = rows.get(s.entity, 0) + int(sel.size)
        for ent, (kx, ky) in TRAJECTORIES.items():
            x, y = _get(cap, extra, kx, a, b), _get(cap, extra, ky, a, b)
            if x is None or y is None:
                continue
            pos = np.stack([x[sel], y[sel]], axis=1)
            cols = rr.Points2D.columns(
                positions=pos, radii=np.full(sel.size, -2.0, dtype=np.float32),
                colors=np.tile(np.asarray(colors[ent], dtype=np.uint8), (sel.size, 1)),
            )
            _send(rec, ent, periods[sel], cols)
            rows[ent] = rows.get(ent, 0) + int(sel.size)
        rec.flush()  # bounded memory: each chunk reaches the file before the next one
        cap.release()

    evidence_rows = _write_evidence(rec, cap, evidence)
    if evidence_rows:
        rows[EVIDENCE_ENTITY] = evidence_rows

    for prefix, samples in (("timing", timing), ("counters", counters)):
        if samples is None or not len(samples.periods):
            continue
        p = np.asarray(samples.periods, dtype=np.int64)
        for key, vals in samples.values.items():
            ent = f"{prefix}/{key}"
            v = np.asarray(vals, dtype=np.float64)
            rec.log(ent, rr.SeriesLines(names=[key]), static=True)
            _send(rec, ent, p, rr.Scalars.columns(scalars=v))
            rows[ent] = int(p.size)
    if report_markdown:
        rec.log("report", rr.TextDocument(report_markdown, media_type="text/markdown"),
                static=True)
    rec.flush()
    _finalize(rec)
    return {"path": str(path), "rows": rows, "display_step": step,
            "evidence": {k: [[a, b] for a, b in v] for k, v in evidence.items()},
            "evidence_rows": evidence_rows}


def _write_evidence(rec: rr.RecordingStream, cap: Capture,
                    evidence: Mapping[str, list[tuple[int, int]]]) -> int:
    """The evidence columns at full rate over the union of their rows; returns the rows."""
    if not evidence:
        return 0
    names = sorted(evidence)
    manifest = {"entity": EVIDENCE_ENTITY, "columns": names, "first_period": cap.first_period,
                "ts": cap.ts, "rows": {k: [[a, b] for a, b in evidence[k]] for k in names}}
    rec.log(EVIDENCE_MANIFEST, rr.TextDocument(json.dumps(manifest, indent=1),
                                               media_type="text/plain"), static=True)
    rec.log(EVIDENCE_ENTITY, rr.SeriesLines(
        names=names, colors=[PALETTE[i % len(PALETTE)] for i in range(len(names))]), static=True)
    union = merge_ranges([r for k in names for r in evidence[k]])
    total = 0
    for a0, b0 in union:
        for a in range(a0, b0, CHUNK):
            b = min(b0, a + CHUNK)
            data = np.full((b - a, len(names)), np.nan)
            for j, name in enumerate(names):
                for ra, rb in evidence[name]:
                    lo, hi = max(a, ra), min(b, rb)
                    if hi > lo:
                        data[lo - a : hi - a, j] = np.asarray(cap[name][lo:hi], dtype=np.float64)
            periods = np.asarray(cap["period"][a:b], dtype=np.int64)
            _send(rec, EVIDENCE_ENTITY, periods, rr.Scalars.columns(scalars=data))
            total += b - a
            rec.flush()
            cap.release()
    return total


def _finalize(rec: rr.RecordingStream) -> None:
    """Flushes the file sink so the .rrd is complete (footer written) when we return."""
    from rerun import bindings

    rec.flush()
    bindings.finalize_deferred_sinks(recording=rec.to_native())
    rec.disconnect()


def _every(periods: npt.NDArray[np.int64], factor: int) -> npt.NDArray[np.intp]:
    if factor <= 1:
        return np.arange(periods.size)
    return np.flatnonzero(periods % factor == 0)


def _send(rec: rr.RecordingStream, entity: str, periods: npt.NDArray[np.int64],
          columns: Any) -> None:
    if periods.size == 0:
        return
    rec.send_columns(
        entity,
        indexes=[
            rr.TimeColumn("sim_time", duration=(periods * TS_NS).astype("timedelta64[ns]")),
            rr.TimeColumn("period", sequence=periods),
        ],
        columns=columns,
    )


def entity_rows(path: str | Path) -> dict[str, int]:
    """Rows per entity (non-static data) of the first recording in an .rrd file."""
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(Path(path)).stream():
        if chunk.is_static:
            continue
        ent = chunk.entity_path.lstrip("/")
        rows[ent] = rows.get(ent, 0) + chunk.num_rows
    return rows


def read_column(path: str | Path, entity: str) -> tuple[npt.NDArray[np.int64], np.ndarray]:
    """(periods, values) logged for an entity (tests; small recordings)."""
    from rerun.chunk import RrdReader

    ps: list[np.ndarray] = []
    vs: list[np.ndarray] = []
    for chunk in RrdReader(Path(path)).stream():
        if chunk.is_static or chunk.entity_path.lstrip("/") != entity:
            continue
        batch = chunk.to_record_batch()
        ps.append(np.asarray(batch.column("period").to_numpy(), dtype=np.int64))
        comp = [n for n in batch.schema.names if n.endswith(":scalars") or n.endswith(":positions")]
        col = batch.column(comp[0])
        vs.append(np.asarray(col.to_pylist(), dtype=np.float64))
    if not ps:
        return np.zeros(0, np.int64), np.zeros(0)
    order = np.argsort(np.concatenate(ps), kind="stable")
    return np.concatenate(ps)[order], np.concatenate(vs)[order]


def read_evidence(path: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The evidence of a recording: its manifest and, per column, an array over the capture's
    rows (``first_period`` onwards, up to the last row kept) with the values the criteria
    read and NaN elsewhere."""
    from rerun.chunk import RrdReader

    manifest: dict[str, Any] = {}
    for chunk in RrdReader(Path(path)).stream():
        if chunk.is_static and chunk.entity_path.lstrip("/") == EVIDENCE_MANIFEST:
            batch = chunk.to_record_batch()
            col = next(n for n in batch.schema.names if n.endswith(":text"))
            manifest = json.loads(str(batch.column(col).to_pylist()[0][0]))
    if not manifest:
        return {}, {}
    periods, values = read_column(path, EVIDENCE_ENTITY)
    names: list[str] = list(manifest["columns"])
    rows = periods - int(manifest["first_period"])
    n = int(rows.max()) + 1 if rows.size else 0
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(names):
        arr = np.full(n, np.nan)
        arr[rows] = values[:, j]
        out[name] = arr
    return manifest, out


# --------------------------------------------------------------------------------------
# Live view


LIVE_FIELDS: dict[str, tuple[str, Callable[[Mapping[str, float]], float]]] = {}


class LiveView:
    """Decimated telemetry (TLM_* frames, BENCH_TRUTH) logged to a recording stream.

    ``add(name, period, values)`` for every decoded frame of interest; ``flush()`` sends
    what was buffered (call it a few times a second). ``min_interval`` periods between two
    logged samples of one entity (default 100: 100 Hz of simulated time).
    """

    def __init__(self, rec: rr.RecordingStream, *, min_interval: int = 100) -> None:
        self.rec = rec
        self.min_interval = min_interval
        self._last: dict[str, int] = {}
        self._buf: dict[str, tuple[list[int], list[list[float]]]] = {}
        self._named: dict[str, list[str]] = {}
        self.rows: dict[str, int] = {}
        rec.send_blueprint(self.blueprint())

    @staticmethod
    def blueprint() -> rrb.Blueprint:
        ts = rrb.TimeSeriesView
        return rrb.Blueprint(
            rrb.Grid(
                ts(origin="/live/position", name="θ est and θ (deg)"),
                ts(origin="/live/speed", name="speed (r/min)"),
                ts(origin="/live/current", name="id / iq (A)"),
                ts(origin="/live/params", name="Ld est / Lq est (mH), λm est (Wb)"),
                ts(origin="/live/torque", name="torque (N·m)"),
                ts(origin="/live/error", name="position error (deg)"),
            )
        )

    def add(self, entity: str, period: int, values: Mapping[str, float]) -> None:
        last = self._last.get(entity)
        if last is not None and 0 <= period - last < self.min_interval:
            return
        self._last[entity] = period
        if entity not in self._named:
            self._named[entity] = sorted(values)
            self.rec.log(f"live/{entity}", rr.SeriesLines(names=self._named[entity]),
                         static=True)
        # an entity's lines are fixed by its first sample: a value missing later is NaN (a
        # gap), one never seen before is left out (one row shape per entity)
        names = self._named[entity]
        ps, vs = self._buf.setdefault(entity, ([], []))
        ps.append(period)
        vs.append([float(values.get(k, math.nan)) for k in names])

    def flush(self) -> None:
        for entity, (ps, vs) in self._buf.items():
            if not ps:
                continue
            p = np.asarray(ps, dtype=np.int64)
            _send(self.rec, f"live/{entity}", p,
                  rr.Scalars.columns(scalars=np.asarray(vs, dtype=np.float64)))
            self.rows[entity] = self.rows.get(entity, 0) + len(ps)
            ps.clear()
            vs.clear()

    def close(self) -> None:
        """The last rows sent, waiting at most LIVE_FLUSH_S for the viewer to take them (a
        viewer that went away must not hold the run, nor Ctrl-C: the wait is in native code),
        then the stream disconnected (nothing left for rerun's exit handler to wait on)."""
        self.flush()
        try:
            self.rec.flush(timeout_sec=LIVE_FLUSH_S)
        except Exception as exc:  # rerun raises on the time-out
            print(f"rig: the live viewer did not take the last rows within {LIVE_FLUSH_S:g} s "
                  f"({exc})", file=sys.stderr)
        with contextlib.suppress(Exception):
            self.rec.disconnect()


LIVE_FLUSH_S = 5.0


def spawn_live(title: str, grpc_url: str | None = None) -> rr.RecordingStream:
    """A recording stream connected to a native viewer window (``rig.results.webview.start_native``:
    127.0.0.1 only, started here unless one listens already), or with ``grpc_url`` to a
    running server (the web viewer's: ``rig.results.webview.start``)."""
    from rig.results import webview

    url = grpc_url or webview.start_native()
    rec = rr.RecordingStream(APP_ID + "_live")
    rec.connect_grpc(url)
    rec.send_recording_name(title)
    return rec


def bytes_per_sim_second(path: Path, sim_s: float) -> float:
    return path.stat().st_size / sim_s if sim_s > 0 and path.exists() else math.nan
