"""The run's Rerun recording (``recording.rrd``) and the live view.

``write()`` logs the merged capture columnar (``rr.send_columns``) chunk by chunk, on the
timelines ``sim_time`` (duration, exact: ``period * 100 µs``) and ``period`` (sequence),
with a blueprint laying out the paper's figures. Core series (θ, θ̂, position error,
speeds) are always at the full 10 kHz; for runs longer than ``full_rate_max_s`` the other
series are decimated (every ``decimate``-th period) so long recordings stay openable. The
2-D trajectories (current, flux circle) are always decimated. The assertion data is the
capture (``capture/*.npy``), never this file.

``LiveView`` logs the decimated telemetry seen on the bus while a run is going on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import rerun as rr
import rerun.blueprint as rrb

from rig.capture import Capture

APP_ID = "sensorless_hil"
TS_NS = 100_000  # one PWM period in ns
FULL_RATE_MAX_S = 20.0
DECIMATE = 10
TRAJECTORY_DECIMATE = 10
CHUNK = 1 << 16
TRAIL_S = 0.1  # trajectories show the last 100 ms around the time cursor

Arr = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Series:
    entity: str
    keys: tuple[str, ...]
    names: tuple[str, ...]
    core: bool = False


SERIES: tuple[Series, ...] = (
    Series("position/theta", ("theta_true_deg", "theta_hat_deg"), ("θ (true)", "θ̂"), True),
    Series("position/error", ("pos_err_deg",), ("θ̂ - θ (deg el.)",), True),
    Series("speed/rpm", ("speed_ref_rpm", "speed_true_rpm", "speed_hat_rpm"),
           ("reference", "true", "estimated"), True),
    Series("speed/error", ("speed_err_rpm",), ("ω̂ - ω (r/min)",), True),
    Series("current/dq", ("truth.id", "truth.iq", "fw.id", "fw.iq", "fw.id_ref", "fw.iq_ref"),
           ("id", "iq", "id (est. frame)", "iq (est. frame)", "id ref", "iq ref")),
    Series("current/magnitude", ("i_mag",), ("|i|",)),
    Series("voltage/dq", ("fw.vd", "fw.vq", "v_mag"), ("vd", "vq", "|v|")),
    Series("params/ld", ("ld_hat_mh", "ld_inc_mh", "ld_app_mh"),
           ("Ld̂", "Ld incremental (true)", "Ld apparent (true)")),
    Series("params/lq", ("lq_hat_mh", "lq_inc_mh", "lq_app_mh"),
           ("Lq̂", "Lq incremental (true)", "Lq apparent (true)")),
    Series("params/lambda", ("fw.lambda_hat", "mag.lambda_m"), ("λ̂m", "λm (true)")),
    Series("flux/alpha_beta", ("flux_alpha_hat", "flux_beta_hat", "flux_alpha_true",
                               "flux_beta_true"),
           ("λα (est.)", "λβ (est.)", "λα (true)", "λβ (true)")),
    Series("torque/nm", ("truth.te", "fw.te_hat", "truth.t_shaft", "truth.tl"),
           ("Te (true)", "T̂e", "shaft (sensor)", "load")),
    Series("estimator/state", ("fw.state", "fw.sector", "fw.slopes_ok", "fw.fw_active"),
           ("state", "sector", "slopes ok", "flux weakening")),
    Series("estimator/residual", ("fw.residual",), ("residual (1/H)",)),
    Series("plant/vdc", ("truth.vdc",), ("Vdc",)),
)

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


def blueprint(*, with_counters: bool = True) -> rrb.Blueprint:
    trail = rrb.VisibleTimeRange(
        "sim_time",
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-TRAIL_S),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    ts = rrb.TimeSeriesView
    tabs: list[Any] = [
        rrb.Vertical(
            ts(origin="/position/theta", name="θ vs θ̂ (deg el.)"),
            ts(origin="/position/error", name="position error (deg el.)"),
            name="Position (Fig. 5, 6, 11)",
        ),
        rrb.Vertical(
            ts(origin="/speed/rpm", name="speed (r/min)"),
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
        ts(origin="/plant/vdc", name="DC link (V)"),
        ts(origin="/timing", name="lockstep timing"),
    ]
    if with_counters:
        bus_views.append(ts(origin="/counters", name="bus and plant counters"))
    tabs.append(rrb.Grid(*bus_views, name="Bus & timing"))
    tabs.append(rrb.TextDocumentView(origin="/report", name="Report"))
    return rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=False)


@dataclass
class TimedSamples:
    """Samples at given periods (grant timing, counters received on the bus)."""

    periods: Sequence[int]
    values: Mapping[str, Sequence[float]]


def write(
    path: str | Path,
    cap: Capture,
    *,
    title: str = "",
    report_markdown: str = "",
    timing: TimedSamples | None = None,
    counters: TimedSamples | None = None,
    full_rate_max_s: float = FULL_RATE_MAX_S,
    decimate: int = DECIMATE,
    recording_id: str | None = None,
) -> dict[str, Any]:
    """Writes the recording; returns what was written (entities, rows, decimation)."""
    path = Path(path)
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id or f"hil-{path.parent.name}")
    rec.save(path, default_blueprint=blueprint(with_counters=counters is not None))
    if title:
        rec.send_recording_name(title)
    long_run = cap.duration > full_rate_max_s
    rows: dict[str, int] = {}
    rates: dict[str, int] = {}

    probe = _derived(cap, 0, min(cap.n, 1))
    present = {k for s in SERIES for k in s.keys if k in probe or k in cap}
    series = [
        Series(s.entity, tuple(k for k in s.keys if k in present),
               tuple(nm for k, nm in zip(s.keys, s.names, strict=True) if k in present), s.core)
        for s in SERIES
    ]
    series = [s for s in series if s.keys]
    for s in series:
        rec.log(s.entity, rr.SeriesLines(names=list(s.names)), static=True)
        rates[s.entity] = 1 if (s.core or not long_run) else decimate
    for ent in TRAJECTORIES:
        rates[ent] = TRAJECTORY_DECIMATE
    colors = {"trajectory/current": [40, 120, 220], "trajectory/flux_est": [220, 80, 40],
              "trajectory/flux_true": [60, 160, 60]}

    for a in range(0, cap.n, CHUNK):
        b = min(cap.n, a + CHUNK)
        extra = _derived(cap, a, b)
        periods = np.asarray(cap["period"][a:b], dtype=np.int64)
        for s in series:
            arrays = [_get(cap, extra, k, a, b) for k in s.keys]
            if any(x is None for x in arrays):
                continue
            sel = _every(periods, rates[s.entity])
            data = np.stack([x[sel] for x in arrays if x is not None], axis=1)
            _send(rec, s.entity, periods[sel], rr.Scalars.columns(scalars=data))
            rows[s.entity] = rows.get(s.entity, 0) + int(sel.size)
        for ent, (kx, ky) in TRAJECTORIES.items():
            x, y = _get(cap, extra, kx, a, b), _get(cap, extra, ky, a, b)
            if x is None or y is None:
                continue
            sel = _every(periods, rates[ent])
            pos = np.stack([x[sel], y[sel]], axis=1)
            cols = rr.Points2D.columns(
                positions=pos, radii=np.full(sel.size, -2.0, dtype=np.float32),
                colors=np.tile(np.asarray(colors[ent], dtype=np.uint8), (sel.size, 1)),
            )
            _send(rec, ent, periods[sel], cols)
            rows[ent] = rows.get(ent, 0) + int(sel.size)
        rec.flush()  # bounded memory: each chunk reaches the file before the next one
        cap.release()

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
    return {"path": str(path), "rows": rows, "decimation": rates, "long_run": long_run}


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
        self._named: set[str] = set()
        self.rows: dict[str, int] = {}
        rec.send_blueprint(self.blueprint())

    @staticmethod
    def blueprint() -> rrb.Blueprint:
        ts = rrb.TimeSeriesView
        return rrb.Blueprint(
            rrb.Grid(
                ts(origin="/live/position", name="θ̂ and θ (deg)"),
                ts(origin="/live/speed", name="speed (r/min)"),
                ts(origin="/live/current", name="id / iq (A)"),
                ts(origin="/live/params", name="Ld̂ / Lq̂ (mH), λ̂m (Wb)"),
                ts(origin="/live/torque", name="torque (N·m)"),
                ts(origin="/live/error", name="position error (deg)"),
            )
        )

    def add(self, entity: str, period: int, values: Mapping[str, float]) -> None:
        last = self._last.get(entity)
        if last is not None and 0 <= period - last < self.min_interval:
            return
        self._last[entity] = period
        names = sorted(values)
        if entity not in self._named:
            self.rec.log(f"live/{entity}", rr.SeriesLines(names=names), static=True)
            self._named.add(entity)
        ps, vs = self._buf.setdefault(entity, ([], []))
        ps.append(period)
        vs.append([float(values[k]) for k in names])

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
        self.flush()
        self.rec.flush()


def spawn_live(title: str) -> rr.RecordingStream:
    """A recording stream connected to a freshly spawned local viewer."""
    rec = rr.RecordingStream(APP_ID + "_live")
    rec.spawn(connect=True)
    rec.send_recording_name(title)
    return rec


def bytes_per_sim_second(path: Path, sim_s: float) -> float:
    return path.stat().st_size / sim_s if sim_s > 0 and path.exists() else math.nan
