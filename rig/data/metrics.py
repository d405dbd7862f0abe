"""Metrics the pass criteria assert on: pure array functions plus a registry by name.

Every metric is computed from the merged capture (``rig.data.capture``): one row per PWM period,
truth sampled at the period start, the firmware's estimate at the instant it claims. Windows
are ``[t0, t1]`` in simulated seconds (``t = period * Ts``). Run-level metrics (counters,
capture loss) ignore the window.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

from rig import protocols

FloatArray = npt.NDArray[np.float64]

POLARITY_THRESHOLD_DEG = 90.0


# --------------------------------------------------------------------------------------
# Pure functions (tested against analytic cases)


def wrap_deg(x: npt.ArrayLike) -> FloatArray:
    """Angles in degrees wrapped to [-180, 180)."""
    a = np.asarray(x, dtype=np.float64)
    return np.mod(a + 180.0, 360.0) - 180.0


def wrap_rad(x: npt.ArrayLike) -> FloatArray:
    """Angles in radians wrapped to [-pi, pi)."""
    a = np.asarray(x, dtype=np.float64)
    return np.mod(a + math.pi, 2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of a signed error signal: max and p99 of |e|, RMS, signed mean, count."""

    max_abs: float
    rms: float
    mean: float
    p99_abs: float
    count: int


def error_stats(err: npt.ArrayLike) -> ErrorStats:
    """Max/RMS/mean/p99 of an error series, NaNs (samples without a valid pair) ignored."""
    e = np.asarray(err, dtype=np.float64)
    e = e[np.isfinite(e)]
    if e.size == 0:
        nan = float("nan")
        return ErrorStats(nan, nan, nan, nan, 0)
    a = np.abs(e)
    return ErrorStats(
        max_abs=float(a.max()),
        rms=float(np.sqrt(np.mean(e * e))),
        mean=float(e.mean()),
        p99_abs=float(np.percentile(a, 99.0)),
        count=int(e.size),
    )


def polarity_losses(err_deg: npt.ArrayLike, threshold_deg: float = POLARITY_THRESHOLD_DEG) -> tuple[
    int, int
]:
    """(episodes, periods) with |error| > threshold: an episode is a maximal run of such periods."""
    e = np.asarray(err_deg, dtype=np.float64)
    bad = np.abs(np.nan_to_num(e, nan=0.0)) > threshold_deg
    if bad.size == 0:
        return 0, 0
    starts = np.count_nonzero(bad[1:] & ~bad[:-1]) + int(bad[0])
    return int(starts), int(np.count_nonzero(bad))


@dataclass(frozen=True)
class SpeedDip:
    """Response of the speed to a load step at ``t_step``."""

    baseline_rpm: float
    drop_rpm: float
    drop_pct: float
    t_min: float
    recovery_s: float  # inf when the speed never settles back into the band


def settling_time(t: npt.ArrayLike, err: npt.ArrayLike, t0: float, band: float) -> float:
    """Time from ``t0`` to the first sample after which |err| stays within ``band`` to the
    end (0 when it never leaves, inf when it is outside at the end)."""
    tt = np.asarray(t, dtype=np.float64)
    e = np.abs(np.asarray(err, dtype=np.float64))
    if e.size == 0 or not np.isfinite(e).any():
        return float("nan")
    outside = ~(e <= band)
    if not outside.any():
        return 0.0
    if outside[-1]:
        return math.inf
    return float(tt[int(np.flatnonzero(outside)[-1]) + 1] - t0)


def speed_dip(
    t: npt.ArrayLike,
    speed_rpm: npt.ArrayLike,
    t_step: float,
    t_end: float,
    *,
    baseline_s: float = 0.05,
    band_pct: float = 2.0,
    band_rpm: float = 0.0,
) -> SpeedDip:
    """Speed drop and recovery time after a load step.

    baseline: mean speed over ``[t_step - baseline_s, t_step)``; drop: baseline minus the
    minimum over ``[t_step, t_end]``; recovery time: from ``t_step`` to the first sample
    after which the speed stays within the band (``band_rpm`` if > 0, else ``band_pct`` % of
    |baseline|) around the baseline until ``t_end``.
    """
    tt = np.asarray(t, dtype=np.float64)
    w = np.asarray(speed_rpm, dtype=np.float64)
    pre = (tt >= t_step - baseline_s) & (tt < t_step) & np.isfinite(w)
    post = (tt >= t_step) & (tt <= t_end) & np.isfinite(w)
    if not pre.any() or not post.any():
        nan = float("nan")
        return SpeedDip(nan, nan, nan, nan, nan)
    base = float(w[pre].mean())
    tp, wp = tt[post], w[post]
    k = int(np.argmin(wp))
    drop = base - float(wp[k])
    band = band_rpm if band_rpm > 0 else abs(base) * band_pct / 100.0
    recovery = settling_time(tp, wp - base, t_step, band)
    pct = 100.0 * drop / abs(base) if base != 0 else float("nan")
    return SpeedDip(base, drop, pct, float(tp[k]), recovery)


def relative_error_pct(estimate: npt.ArrayLike, truth: npt.ArrayLike) -> float:
    """|mean(estimate) - mean(truth)| / |mean(truth)| in percent (finite samples only)."""
    e = np.asarray(estimate, dtype=np.float64)
    r = np.asarray(truth, dtype=np.float64)
    ok = np.isfinite(e) & np.isfinite(r)
    if not ok.any():
        return float("nan")
    ref = float(r[ok].mean())
    return float(abs(float(e[ok].mean()) - ref) / abs(ref) * 100.0) if ref else float("nan")


def circularity_pct(radius: npt.ArrayLike) -> float:
    """Standard deviation of a trajectory's radius relative to its mean, in percent."""
    r = np.asarray(radius, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size == 0 or r.mean() == 0:
        return float("nan")
    return float(r.std() / abs(r.mean()) * 100.0)


def _finite(x: npt.ArrayLike) -> FloatArray:
    a = np.asarray(x, dtype=np.float64)
    return a[np.isfinite(a)]


def _stat(x: npt.ArrayLike, how: str) -> float:
    a = _finite(x)
    if a.size == 0:
        return float("nan")
    if how == "mean":
        return float(a.mean())
    if how == "max":
        return float(a.max())
    if how == "min":
        return float(a.min())
    if how == "maxabs":
        return float(np.abs(a).max())
    if how == "rms":
        return float(np.sqrt(np.mean(a * a)))
    raise ValueError(how)


# --------------------------------------------------------------------------------------
# Window access and the registry


class ColumnSource(Protocol):
    """Columns by name, one row per period (a ``rig.data.capture.Capture`` or a dict of arrays)."""

    def __getitem__(self, name: str, /) -> np.ndarray: ...

    def __contains__(self, name: object, /) -> bool: ...


class Overlay:
    """A column source with columns added (the ISR's cost per period beside a capture)."""

    def __init__(self, base: ColumnSource, extra: Mapping[str, np.ndarray]) -> None:
        self.base, self.extra = base, dict(extra)

    def __getitem__(self, name: str, /) -> np.ndarray:
        return self.extra[name] if name in self.extra else self.base[name]

    def __contains__(self, name: object, /) -> bool:
        return name in self.extra or name in self.base

    def names_with(self, prefix: str) -> list[str]:
        return [n for n in self.extra if n.startswith(prefix)]


class Window:
    """The rows of a capture in ``[t0, t1]`` plus what run-level metrics need."""

    def __init__(
        self,
        columns: ColumnSource,
        t0: float,
        t1: float,
        *,
        ts: float,
        first_period: int = 0,
        counters: Mapping[str, float] | None = None,
        reads: list[tuple[str, int, int]] | None = None,
    ) -> None:
        self._cols = columns
        # every (column, first row, end row) a metric reads: the evidence a recording keeps
        self.reads = reads
        self.ts = ts
        self.t0 = t0
        self.t1 = t1
        self.first_period = first_period
        self.counters = dict(counters or {})
        n = len(columns["period"]) if "period" in columns else 0
        self.n_total = n
        i0 = math.ceil(t0 / ts - 1e-6) - first_period
        i1 = math.floor(t1 / ts + 1e-6) - first_period + 1
        self.i0 = min(max(i0, 0), n)
        self.i1 = min(max(i1, self.i0), n)

    def __len__(self) -> int:
        return self.i1 - self.i0

    def has(self, name: str) -> bool:
        return name in self._cols

    def names_with(self, prefix: str) -> list[str]:
        """The columns whose names start with ``prefix``, for a source that lists its
        columns (``Overlay``); none for one that does not."""
        lister = getattr(self._cols, "names_with", None)
        return list(lister(prefix)) if lister is not None else []

    def get(self, name: str) -> FloatArray:
        return self._read(name, self.i0, self.i1)

    def _read(self, name: str, i0: int, i1: int) -> FloatArray:
        values = np.asarray(self._cols[name][i0:i1], dtype=np.float64)
        if self.reads is not None and i1 > i0:
            self.reads.append((name, i0, i1))
        return values

    def around(self, name: str, t_from: float, t_to: float) -> tuple[FloatArray, FloatArray]:
        """(t, values) of a column over any range (for baselines before the window)."""
        n = self.n_total
        i0 = min(max(math.ceil(t_from / self.ts - 1e-6) - self.first_period, 0), n)
        i1 = min(max(math.floor(t_to / self.ts + 1e-6) - self.first_period + 1, i0), n)
        periods = np.arange(i0, i1, dtype=np.float64) + self.first_period
        return periods * self.ts, self._read(name, i0, i1)


MetricFn = Callable[[Window, Mapping[str, float]], float]
# what a metric says besides its value (result.json's "detail": numbers by name), for the
# baseline to tell where a value moved (rig.regression.baseline: the ISR's steps)
DetailFn = Callable[[Window, Mapping[str, float]], dict[str, float]]


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    description: str
    fn: MetricFn
    scope: Literal["window", "run"] = "window"
    params: Mapping[str, float] = field(default_factory=dict)
    detail: DetailFn | None = None
    # what the metric's data needs besides a capture: "" or "target" (the ISR's cost on the
    # emulated target, measured on the in-process bench only: rig.target_m4.cost)
    needs: str = ""


METRICS: dict[str, Metric] = {}
COUNTER_PREFIXES = ("plant", "firmware", "bench", "rejects", "rig")


def _register(
    name: str,
    unit: str,
    description: str,
    scope: Literal["window", "run"] = "window",
    params: Mapping[str, float] | None = None,
    detail: DetailFn | None = None,
    needs: str = "",
) -> Callable[[MetricFn], MetricFn]:
    def deco(fn: MetricFn) -> MetricFn:
        METRICS[name] = Metric(name, unit, description, fn, scope, dict(params or {}), detail,
                               needs)
        return fn

    return deco


def _column_metric(name: str, unit: str, description: str, column: str, stat: str) -> None:
    """Registers a metric that is one statistic of one capture column over the window."""

    def metric(w: Window, p: Mapping[str, float]) -> float:
        return _stat(w.get(column), stat)

    _register(name, unit, description)(metric)


def _error_metric(name: str, unit: str, description: str, column: str, statistic: str,
                  minus: str | None = None) -> None:
    """Registers a metric that is one of the error statistics (``ErrorStats``) of one capture
    column over the window, or of its difference from another (``minus``)."""

    def metric(w: Window, p: Mapping[str, float]) -> float:
        err = w.get(column) if minus is None else w.get(column) - w.get(minus)
        return float(getattr(error_stats(err), statistic))

    _register(name, unit, description)(metric)


_error_metric("pos_err_max_deg", "deg", "max |position error| (electrical, wrapped to ±180°)",
              "pos_err_deg", "max_abs")
_error_metric("pos_err_rms_deg", "deg", "RMS position error (electrical)", "pos_err_deg", "rms")
_error_metric("pos_err_mean_deg", "deg", "mean (signed) position error (electrical)",
              "pos_err_deg", "mean")
_error_metric("pos_err_p99_deg", "deg", "99th percentile of |position error| (electrical)",
              "pos_err_deg", "p99_abs")


@_register(
    "polarity_loss_count",
    "",
    "episodes with |position error| > threshold_deg (default 90°)",
    params={"threshold_deg": POLARITY_THRESHOLD_DEG},
)
def _pol_count(w: Window, p: Mapping[str, float]) -> float:
    return float(polarity_losses(w.get("pos_err_deg"), p["threshold_deg"])[0])


@_register(
    "polarity_loss_periods",
    "",
    "PWM periods with |position error| > threshold_deg (default 90°)",
    params={"threshold_deg": POLARITY_THRESHOLD_DEG},
)
def _pol_periods(w: Window, p: Mapping[str, float]) -> float:
    return float(polarity_losses(w.get("pos_err_deg"), p["threshold_deg"])[1])


_error_metric("speed_err_max_rpm", "r/min", "max |estimated - true speed| (mechanical)",
              "speed_err_rpm", "max_abs")


# the firmware's speed loop and telemetry run every 10th period (1 kHz; drive.dbc)
SPEED_LOOP_PERIODS = protocols.timebase().speed_loop_divider


def block_means(x: npt.ArrayLike, n: int) -> FloatArray:
    """Means of consecutive blocks of ``n`` samples (an incomplete last block is dropped)."""
    a = np.asarray(x, dtype=np.float64)
    k = a.size // n
    return a[: k * n].reshape(k, n).mean(axis=1) if k else np.empty(0)


@_register("speed_err_1khz_max_rpm", "r/min",
           "max |estimated - true speed| of 1 ms means (the speed loop's 1 kHz rate)")
def _spd_err_1khz(w: Window, p: Mapping[str, float]) -> float:
    return error_stats(block_means(w.get("speed_err_rpm"), SPEED_LOOP_PERIODS)).max_abs


_error_metric("speed_err_rms_rpm", "r/min", "RMS estimated - true speed", "speed_err_rpm", "rms")
_error_metric("speed_err_mean_rpm", "r/min", "mean estimated - true speed", "speed_err_rpm", "mean")


_error_metric("speed_track_err_max_rpm", "r/min", "max |true speed - scenario speed reference|",
              "speed_true_rpm", "max_abs", minus="speed_ref_rpm")
_error_metric("speed_track_err_rms_rpm", "r/min", "RMS true speed - scenario speed reference",
              "speed_true_rpm", "rms", minus="speed_ref_rpm")


@_register(
    "speed_settling_time_s", "s",
    "time from window t0 until |true speed - reference| stays within band_rpm up to t1",
    params={"band_rpm": 30.0},
)
def _settle(w: Window, p: Mapping[str, float]) -> float:
    t, ref = w.around("speed_ref_rpm", w.t0, w.t1)
    _, v = w.around("speed_true_rpm", w.t0, w.t1)
    return settling_time(t, v - ref, w.t0, p["band_rpm"])


_column_metric("speed_mean_rpm", "r/min", "mean true speed", "speed_true_rpm", "mean")
_column_metric("speed_min_rpm", "r/min", "minimum true speed", "speed_true_rpm", "min")
_column_metric("speed_max_rpm", "r/min", "maximum true speed", "speed_true_rpm", "max")


# --------------------------------------------------------------------------------------
# Starts (window t0 = the enable): against a load already on the shaft, or a shaft turning


def first_time_s(mask: npt.ArrayLike, ts: float) -> float:
    """Seconds from the first sample to the first true one; inf when none is."""
    return first_index(mask) * ts


def load_direction(tl: npt.ArrayLike) -> float:
    """+1 when the load torque (plant convention: it opposes positive rotation) is positive
    at the first sample, -1 when negative, NaN without a load."""
    t = np.asarray(tl, dtype=np.float64)
    if t.size == 0 or not math.isfinite(t[0]) or t[0] == 0.0:
        return math.nan
    return math.copysign(1.0, float(t[0]))


def kickback_deg(speed_rpm: npt.ArrayLike, direction: float, ts: float) -> float:
    """Largest mechanical angle (degrees) the shaft turns in ``direction`` (+1/-1) from where
    it was at the first sample: the running integral of the speed, at least 0."""
    w = np.asarray(speed_rpm, dtype=np.float64)
    if w.size == 0 or not math.isfinite(direction):
        return math.nan
    angle = np.cumsum(w) * (ts * 360.0 / 60.0)
    return max(0.0, float(np.max(direction * angle)))


@_register(
    "torque_time_s", "s",
    "start against a load (window t0 = the enable): time until the true torque first holds "
    "fraction of the load torque there (same sign as the load, which opposes positive "
    "rotation); inf: never within the window, NaN without a load",
    params={"fraction": 0.5},
)
def _torque_time(w: Window, p: Mapping[str, float]) -> float:
    tl = w.get("truth.tl")
    d = load_direction(tl)
    if not math.isfinite(d):
        return math.nan
    return first_time_s(d * w.get("truth.te") >= p["fraction"] * abs(float(tl[0])), w.ts)


@_register(
    "kickback_deg", "deg",
    "start against a load (window t0 = the enable): the largest mechanical angle the shaft "
    "turns the load's way (back) from where it was at t0 (true speed integrated)",
)
def _kickback(w: Window, p: Mapping[str, float]) -> float:
    return kickback_deg(w.get("speed_true_rpm"), -load_direction(w.get("truth.tl")), w.ts)


@_register(
    "run_time_s", "s",
    "time from the window's start (the enable) until the firmware is first in RUN "
    "(FW_TRACE.state); inf: not within the window",
)
def _run_time(w: Window, p: Mapping[str, float]) -> float:
    return first_time_s(w.get("fw.state") == firmware_state("RUN"), w.ts)


_DIP_PARAMS = {"baseline_s": 0.05, "band_pct": 2.0, "band_rpm": 0.0}


def _dip(w: Window, p: Mapping[str, float]) -> SpeedDip:
    t, v = w.around("speed_true_rpm", w.t0 - p["baseline_s"], w.t1)
    return speed_dip(
        t, v, w.t0, w.t1, baseline_s=p["baseline_s"], band_pct=p["band_pct"],
        band_rpm=p["band_rpm"],
    )


@_register(
    "speed_drop_rpm", "r/min",
    "load step at window t0: baseline (mean over baseline_s before t0) minus minimum speed",
    params=_DIP_PARAMS,
)
def _drop_rpm(w: Window, p: Mapping[str, float]) -> float:
    return _dip(w, p).drop_rpm


@_register("speed_drop_pct", "%", "speed drop in percent of the baseline speed",
           params=_DIP_PARAMS)
def _drop_pct(w: Window, p: Mapping[str, float]) -> float:
    return _dip(w, p).drop_pct


@_register(
    "recovery_time_s", "s",
    "time from the load step (window t0) until the speed stays within the band "
    "(band_rpm, else band_pct % of the baseline) up to t1",
    params=_DIP_PARAMS,
)
def _recovery(w: Window, p: Mapping[str, float]) -> float:
    return _dip(w, p).recovery_s


@_register("ld_err_pct", "%", "estimated Ld vs the plant's incremental Ld (window means)")
def _ld_err(w: Window, p: Mapping[str, float]) -> float:
    return relative_error_pct(w.get("fw.ld_hat"), w.get("mag.ld_inc"))


@_register("lq_err_pct", "%", "estimated Lq vs the plant's incremental Lq (window means)")
def _lq_err(w: Window, p: Mapping[str, float]) -> float:
    return relative_error_pct(w.get("fw.lq_hat"), w.get("mag.lq_inc"))


@_register("lambda_err_pct", "%", "estimated λm vs the plant's λm (window means)")
def _lam_err(w: Window, p: Mapping[str, float]) -> float:
    return relative_error_pct(w.get("fw.lambda_hat"), w.get("mag.lambda_m"))


@_register("ld_hat_mean_mh", "mH", "mean estimated Ld")
def _ld_mean(w: Window, p: Mapping[str, float]) -> float:
    return 1e3 * _stat(w.get("fw.ld_hat"), "mean")


@_register("lq_hat_mean_mh", "mH", "mean estimated Lq")
def _lq_mean(w: Window, p: Mapping[str, float]) -> float:
    return 1e3 * _stat(w.get("fw.lq_hat"), "mean")


_column_metric("lambda_hat_mean_wb", "Wb", "mean estimated PM flux linkage (flux magnitude)",
               "fw.lambda_hat", "mean")


@_register("flux_circularity_pct", "%", "std/mean of the estimated flux vector's radius")
def _circ(w: Window, p: Mapping[str, float]) -> float:
    return circularity_pct(w.get("fw.lambda_hat"))


@_register("lambda_min_max_ratio", "", "min/max of the estimated PM flux magnitude")
def _lam_ratio(w: Window, p: Mapping[str, float]) -> float:
    x = _finite(w.get("fw.lambda_hat"))
    return float(x.min() / x.max()) if x.size and x.max() > 0 else float("nan")


_column_metric("i_mag_max_a", "A", "max true current magnitude sqrt(id² + iq²)", "i_mag", "max")
_column_metric("i_mag_rms_a", "A", "RMS true current magnitude", "i_mag", "rms")
_column_metric("v_mag_max_v", "V", "max commanded voltage magnitude sqrt(vd² + vq²)",
               "v_mag", "max")
_column_metric("id_mean_a", "A", "mean true d-axis current", "truth.id", "mean")
_column_metric("iq_mean_a", "A", "mean true q-axis current", "truth.iq", "mean")


_error_metric("te_err_max_nm", "N*m", "max |estimated - true electromagnetic torque|",
              "fw.te_hat", "max_abs", minus="truth.te")
_error_metric("te_err_mean_nm", "N*m", "mean estimated - true electromagnetic torque",
              "fw.te_hat", "mean", minus="truth.te")


_column_metric("fw_active_fraction", "", "fraction of periods with flux weakening active",
               "fw.fw_active", "mean")


@_register("slopes_ok_fraction", "", "fraction of periods where both active vectors were measured")
def _slopes(w: Window, p: Mapping[str, float]) -> float:
    s = w.get("fw.slopes_ok")
    return float(np.mean(s == 2)) if s.size else float("nan")


# --------------------------------------------------------------------------------------
# Faults: what the firmware's protection made of an injected fault (window t0 = the fault)


def _drive_status_choice(signal: str, name: str) -> int:
    return protocols.choices("drive", "DRIVE_STATUS", signal)[name.lower()]


def firmware_state(name: str) -> int:
    """A drive state's number (DRIVE_STATUS.state in protocols/drive.dbc; FW_TRACE.state
    carries the same values)."""
    return _drive_status_choice("state", name)


def fault_code(name: str) -> int:
    """A fault code's number (DRIVE_STATUS.fault_code in protocols/drive.dbc; the counter
    ``firmware.fault_code`` of a run carries the same values)."""
    return _drive_status_choice("fault_code", name)


def first_index(mask: npt.ArrayLike) -> float:
    """Index of the first true element; inf when there is none."""
    hits = np.flatnonzero(np.asarray(mask, dtype=bool))
    return float(hits[0]) if hits.size else math.inf


def periods_until_held(ok: npt.ArrayLike) -> float:
    """Periods from the start until ``ok`` holds in every later period (0 when it holds
    throughout, inf when it does not hold at the end)."""
    good = np.asarray(ok, dtype=bool)
    if good.size == 0:
        return math.nan
    if good.all():
        return 0.0
    if not good[-1]:
        return math.inf
    return float(np.flatnonzero(~good)[-1] + 1)


def phase_current_peak(ia: npt.ArrayLike, ib: npt.ArrayLike) -> FloatArray:
    """max(|ia|, |ib|, |ic|) per sample, ic = -ia - ib (isolated star point)."""
    a = np.abs(np.asarray(ia, dtype=np.float64))
    b = np.abs(np.asarray(ib, dtype=np.float64))
    c = np.abs(np.asarray(ia, dtype=np.float64) + np.asarray(ib, dtype=np.float64))
    return np.maximum(np.maximum(a, b), c)


@_register("detect_periods", "periods",
           "periods from the window's start (the fault) until the firmware is in its FAULT "
           "state (FW_TRACE.state; 0: its ISR of that very period); inf: not within the window")
def _detect(w: Window, p: Mapping[str, float]) -> float:
    return first_index(w.get("fw.state") == firmware_state("FAULT"))


@_register("fw_state_start", "",
           "firmware state in the window's first period (DRIVE_STATUS.state values: 3 RUN, "
           "4 FAULT, ...)")
def _state_start(w: Window, p: Mapping[str, float]) -> float:
    s = w.get("fw.state")
    return float(s[0]) if s.size else math.nan


@_register("fw_state_end", "",
           "firmware state in the window's last period (DRIVE_STATUS.state values: 3 RUN, "
           "4 FAULT, ...)")
def _state_end(w: Window, p: Mapping[str, float]) -> float:
    s = w.get("fw.state")
    return float(s[-1]) if s.size else math.nan


@_register("i_phase_peak_a", "A", "max |phase current| of the three phases (truth)")
def _i_phase_peak(w: Window, p: Mapping[str, float]) -> float:
    return _stat(phase_current_peak(w.get("truth.ia"), w.get("truth.ib")), "max")


@_register("safe_state_periods", "periods",
           "periods from the window's start until the drive is safe to the window's end: "
           "the firmware in FAULT (its outputs off) and every phase current within i_safe_a "
           "(truth); inf: not within the window", params={"i_safe_a": 0.1})
def _safe(w: Window, p: Mapping[str, float]) -> float:
    safe = (w.get("fw.state") == firmware_state("FAULT")) & (
        phase_current_peak(w.get("truth.ia"), w.get("truth.ib")) <= p["i_safe_a"])
    return periods_until_held(safe)


@_register("capture_lost", "", "capture loss: missing periods over all traces", scope="run")
def _lost(w: Window, p: Mapping[str, float]) -> float:
    return float(w.counters.get("capture.lost", float("nan")))


@_register("capture_duplicates", "", "capture duplicates over all traces", scope="run")
def _dups(w: Window, p: Mapping[str, float]) -> float:
    return float(w.counters.get("capture.duplicates", float("nan")))


# The ISR's cost on the emulated Cortex-M4F (rig.target_m4.cost): the instructions of each
# journalled period, in total and by step of fw_core_isr. A period of the window that was
# not replayed makes the value NaN (no data), never a smaller sample.
ISR_COLUMN = "isr.instructions"
ISR_STEP_PREFIX = "isr.step."
TARGET = "target"


def _isr_column(w: Window) -> FloatArray:
    v = w.get(ISR_COLUMN) if w.has(ISR_COLUMN) else np.empty(0)
    return v if v.size and np.isfinite(v).all() else np.empty(0)


def _isr_steps(w: Window) -> dict[str, FloatArray]:
    return {name[len(ISR_STEP_PREFIX):]: w.get(name) for name in _isr_step_names(w)}


def _isr_step_names(w: Window) -> list[str]:
    return w.names_with(ISR_STEP_PREFIX)


def _isr_median_detail(w: Window, p: Mapping[str, float]) -> dict[str, float]:
    if not _isr_column(w).size:
        return {}
    return {k: float(np.median(v)) for k, v in _isr_steps(w).items()}


def _isr_worst_detail(w: Window, p: Mapping[str, float]) -> dict[str, float]:
    total = _isr_column(w)
    if not total.size:
        return {}
    i = int(np.argmax(total))  # (the first of equal worst periods)
    return {k: float(v[i]) for k, v in _isr_steps(w).items()}


@_register("isr_instructions_median", "instructions",
           "median instructions of fw_core_isr per period on the emulated Cortex-M4F "
           "(in-process runs only; detail: each step's median)",
           detail=_isr_median_detail, needs=TARGET)
def _isr_median(w: Window, p: Mapping[str, float]) -> float:
    v = _isr_column(w)
    return float(np.median(v)) if v.size else math.nan


@_register("isr_instructions_max", "instructions",
           "largest instructions of fw_core_isr in a period on the emulated Cortex-M4F "
           "(in-process runs only; detail: the steps of that period)",
           detail=_isr_worst_detail, needs=TARGET)
def _isr_max(w: Window, p: Mapping[str, float]) -> float:
    v = _isr_column(w)
    return float(v.max()) if v.size else math.nan


# What an infinite value means, per metric (the criterion's note).
INFINITE_NOTES: dict[str, str] = {
    "recovery_time_s": "never settled",
    "torque_time_s": "the torque never held the load within the window",
    "run_time_s": "never in RUN within the window",
    "detect_periods": "no FAULT state within the window (not detected)",
    "safe_state_periods": "no safe state within the window",
}


def is_counter(name: str) -> bool:
    """``plant.<key>``, ``firmware.<key>``, ``bench.<signal>``, ``rejects.<signal>``,
    ``rig.<key>``: counters of the run (exit JSON of the programs, bus frames, the rig)."""
    head, _, tail = name.partition(".")
    return head in COUNTER_PREFIXES and bool(tail) and tail.replace("_", "").replace(
        ".", ""
    ).isalnum()


# Metrics, counters and capture columns whose values are raw values of an enumerated DBC
# signal (its value table names them): shown as ``RUN (3)`` wherever a person reads them
# (``rig.results.shown``). FW_TRACE.state carries DRIVE_STATUS.state's values.
ENUMERATED: dict[str, tuple[str, str, str]] = {
    "fw_state_start": ("drive", "DRIVE_STATUS", "state"),
    "fw_state_end": ("drive", "DRIVE_STATUS", "state"),
    "fw.state": ("drive", "DRIVE_STATUS", "state"),
    "firmware.fault_code": ("drive", "DRIVE_STATUS", "fault_code"),
    "firmware.fault_code_last": ("drive", "DRIVE_STATUS", "fault_code"),
}


def enumerated(name: str) -> tuple[str, str, str] | None:
    """(database, message, signal) whose value table names the values of a metric, counter
    or capture column; None for a quantity."""
    return ENUMERATED.get(name)


def known(name: str) -> bool:
    return name in METRICS or is_counter(name)


def params_of(name: str) -> Mapping[str, float]:
    return METRICS[name].params if name in METRICS else {}


def unit_of(name: str) -> str:
    return METRICS[name].unit if name in METRICS else ""


def compute(name: str, window: Window, params: Mapping[str, Any] | None = None) -> float:
    """Value of metric ``name`` over ``window`` (NaN when the window holds no data)."""
    if is_counter(name) and name not in METRICS:
        return float(window.counters.get(name, float("nan")))
    metric = METRICS[name]
    merged = dict(metric.params)
    for k, v in (params or {}).items():
        if k not in merged:
            raise KeyError(f"metric {name} has no parameter {k!r}")
        merged[k] = float(v)
    if metric.scope == "window" and len(window) == 0:
        return float("nan")
    return float(metric.fn(window, merged))


def detail(name: str, window: Window, params: Mapping[str, Any] | None = None
           ) -> dict[str, float]:
    """What metric ``name`` says besides its value over ``window`` (empty for most)."""
    metric = METRICS.get(name)
    if metric is None or metric.detail is None or len(window) == 0:
        return {}
    return metric.detail(window, dict(metric.params) | dict(params or {}))


def needs_target(name: str) -> bool:
    """Whether metric ``name`` is measured on the emulated target (in-process runs only)."""
    return name in METRICS and METRICS[name].needs == TARGET


COMPARISONS: dict[str, Callable[[float, float], bool]] = {
    "<=": lambda v, lim: v <= lim,
    "<": lambda v, lim: v < lim,
    ">=": lambda v, lim: v >= lim,
    ">": lambda v, lim: v > lim,
    "==": lambda v, lim: v == lim,
    "report": lambda v, lim: True,  # value recorded, no limit (NaN still fails)
}


def compare(value: float, comparison: str, limit: float) -> bool:
    """A NaN value never passes (no data is not a pass)."""
    if value is None or math.isnan(value):
        return False
    return COMPARISONS[comparison](value, limit)
