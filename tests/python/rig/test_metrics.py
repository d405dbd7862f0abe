"""Metrics against analytic cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.optimize import brentq

from rig import protocols
from rig.data import metrics

TS = protocols.timebase().ts


def test_sinusoidal_error_statistics() -> None:
    # e(t) = a*sin(2*pi*f*t) over whole periods: max a, RMS a/sqrt(2), mean 0,
    # p99 of |e| = a*sin(0.99*pi/2) (|sin| of a uniform phase has CDF (2/pi)*asin(x)).
    a, f = 2.5, 50.0
    t = np.arange(0, 1.0, TS)
    e = a * np.sin(2 * math.pi * f * t + 0.1)
    s = metrics.error_stats(e)
    assert s.max_abs == pytest.approx(a, rel=1e-4)
    assert s.rms == pytest.approx(a / math.sqrt(2), rel=1e-4)
    assert abs(s.mean) < 1e-9
    assert s.p99_abs == pytest.approx(a * math.sin(0.99 * math.pi / 2), rel=2e-3)
    assert s.count == t.size


def test_error_stats_ignore_nan_and_empty() -> None:
    s = metrics.error_stats([np.nan, 1.0, -3.0, np.nan])
    assert (s.max_abs, s.mean, s.count) == (3.0, -1.0, 2)
    assert s.rms == pytest.approx(math.sqrt(5.0))
    empty = metrics.error_stats([np.nan])
    assert empty.count == 0 and math.isnan(empty.max_abs)


@given(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False))
def test_wrap_deg_range_and_congruence(x: float) -> None:
    w = float(metrics.wrap_deg(x))
    assert -180.0 <= w < 180.0
    k = (x - w) / 360.0
    assert abs(k - round(k)) < 1e-6


def test_speed_dip_analytic() -> None:
    # speed = base - A*x*exp(1-x), x = (t - t0)/tau: minimum A below base at t0 + tau;
    # it re-enters a band b around base when A*x*exp(1-x) = b (x > 1).
    base, amp, tau, t0, band_pct = 1000.0, 180.0, 0.05, 1.0, 1.0
    t = np.arange(0.0, 2.0, TS)
    x = np.clip((t - t0) / tau, 0.0, None)
    speed = base - amp * x * np.exp(1.0 - x)
    band = base * band_pct / 100.0
    x_rec = brentq(lambda u: amp * u * math.exp(1.0 - u) - band, 1.0, 50.0)
    dip = metrics.speed_dip(t, speed, t0, 2.0, baseline_s=0.1, band_pct=band_pct)
    assert dip.baseline_rpm == pytest.approx(base)
    assert dip.drop_rpm == pytest.approx(amp, rel=1e-6)
    assert dip.drop_pct == pytest.approx(18.0, rel=1e-6)
    assert dip.t_min == pytest.approx(t0 + tau, abs=TS)
    assert dip.recovery_s == pytest.approx(x_rec * tau, abs=1.01 * TS)


def test_speed_dip_never_recovers_and_no_dip() -> None:
    t = np.arange(0.0, 1.0, TS)
    falling = np.where(t < 0.5, 1000.0, 1000.0 - 400.0 * (t - 0.5))
    assert math.isinf(metrics.speed_dip(t, falling, 0.5, 1.0).recovery_s)
    flat = np.full_like(t, 500.0)
    d = metrics.speed_dip(t, flat, 0.5, 1.0)
    assert d.drop_rpm == 0.0 and d.recovery_s == 0.0


def test_polarity_losses_counts_episodes_and_periods() -> None:
    e = np.zeros(100)
    e[10:13] = 170.0
    e[50] = -95.0
    e[98:] = 120.0
    assert metrics.polarity_losses(e) == (3, 6)
    assert metrics.polarity_losses(e, threshold_deg=150.0) == (1, 3)
    assert metrics.polarity_losses(np.full(5, 179.0)) == (1, 5)


def test_relative_error_and_circularity() -> None:
    assert metrics.relative_error_pct([0.0153, 0.0147], [0.015, 0.015]) == pytest.approx(0.0)
    assert metrics.relative_error_pct([0.033], [0.030]) == pytest.approx(10.0)
    phi = np.linspace(0, 2 * math.pi, 10001)[:-1]
    eps = 0.04
    r = 0.22 * (1 + eps * np.sin(phi))
    assert metrics.circularity_pct(r) == pytest.approx(100 * eps / math.sqrt(2), rel=1e-3)


def _columns(n: int) -> dict[str, np.ndarray]:
    t = np.arange(n) * TS
    return {
        "period": np.arange(n),
        "pos_err_deg": np.where(t < 0.05, 150.0, 1.0),
        "speed_true_rpm": 100.0 + 0 * t,
        "speed_ref_rpm": 100.0 + 2.0 * (t > 0.08),
    }


def test_window_selects_inclusive_periods() -> None:
    cols = _columns(1000)
    w = metrics.Window(cols, 0.01, 0.02, ts=TS)
    assert (w.i0, w.i1) == (100, 201)
    assert len(metrics.Window(cols, 0.0, 1.0, ts=TS)) == 1000
    assert len(metrics.Window(cols, 0.2, 0.3, ts=TS)) == 0


def test_compute_registry_and_compare() -> None:
    cols = _columns(1000)
    w = metrics.Window(cols, 0.06, 0.0999, ts=TS, counters={"plant.late_cmds": 3.0})
    assert metrics.compute("pos_err_max_deg", w) == 1.0
    assert metrics.compute("speed_track_err_max_rpm", w) == pytest.approx(2.0)
    whole = metrics.Window(cols, 0.0, 0.0999, ts=TS)
    assert metrics.compute("polarity_loss_count", whole) == 1.0
    assert metrics.compute("polarity_loss_count", whole, {"threshold_deg": 160}) == 0.0
    assert metrics.compute("plant.late_cmds", w) == 3.0
    with pytest.raises(KeyError):
        metrics.compute("pos_err_max_deg", w, {"nonsense": 1})
    empty = metrics.Window(cols, 0.5, 0.6, ts=TS)
    assert math.isnan(metrics.compute("pos_err_max_deg", empty))
    assert not metrics.compare(float("nan"), "<=", 1.0)
    assert metrics.compare(1.0, "<=", 1.0) and not metrics.compare(1.0, "<", 1.0)
    assert metrics.known("firmware.bus.tx_drops") and not metrics.known("nope")


def test_block_means_and_the_1khz_speed_error() -> None:
    # a 5 kHz square wave of +-3 r/min averages to zero over every 1 ms block (10 periods);
    # a 2 r/min offset in one block is what the 1 kHz report shows
    n = 1000
    err = np.where(np.arange(n) % 2 == 0, 3.0, -3.0)
    err[500:510] += 2.0
    cols = {"period": np.arange(n), "speed_err_rpm": err}
    w = metrics.Window(cols, 0.0, (n - 1) * TS, ts=TS)
    assert metrics.compute("speed_err_max_rpm", w) == pytest.approx(5.0)
    assert metrics.compute("speed_err_1khz_max_rpm", w) == pytest.approx(2.0)
    assert metrics.block_means(np.arange(25.0), 10).tolist() == [4.5, 14.5]


def test_settling_time_analytic() -> None:
    # first-order approach e(t) = 100 exp(-t/tau): inside 30 from t = tau ln(100/30)
    tau = 0.05
    t = np.arange(0, 0.5, TS)
    e = 100.0 * np.exp(-t / tau)
    expected = tau * math.log(100.0 / 30.0)
    assert metrics.settling_time(t, e, 0.0, 30.0) == pytest.approx(expected, abs=TS)
    assert metrics.settling_time(t, -e, 0.0, 30.0) == pytest.approx(expected, abs=TS)
    assert metrics.settling_time(t, e, 0.0, 200.0) == 0.0
    assert metrics.settling_time(t, e + 50.0, 0.0, 30.0) == math.inf
    cols = {"period": np.arange(t.size), "speed_true_rpm": 1500.0 - e,
            "speed_ref_rpm": np.full(t.size, 1500.0)}
    w = metrics.Window(cols, 0.0, t[-1], ts=TS)
    assert metrics.compute("speed_settling_time_s", w) == pytest.approx(expected, abs=TS)
    assert metrics.compute("speed_settling_time_s", w, {"band_rpm": 10.0}) == pytest.approx(
        tau * math.log(10.0), abs=TS)


def test_flux_min_max_ratio() -> None:
    lam = 0.216 * (1.0 + 0.02 * np.sin(np.linspace(0, 20, 2000)))
    cols = {"period": np.arange(lam.size), "fw.lambda_hat": lam}
    w = metrics.Window(cols, 0.0, 0.2, ts=TS)
    assert metrics.compute("lambda_min_max_ratio", w) == pytest.approx(0.98 / 1.02, rel=1e-4)


def test_start_metrics_against_a_constant_load() -> None:
    # A load of +2 N*m (it opposes positive rotation) on J = 0.0005 kg*m^2 from t = 0 with no
    # torque until t_d, then a torque of 3 N*m: the shaft runs back at a1 = TL/J, then brakes
    # at a2 = (Te - TL)/J. It turns back by a1 t_d^2/2 + (a1 t_d)^2/(2 a2) rad before it
    # reverses; the torque holds half the load from t_d on; RUN from t_run on.
    j, tl, te, t_d, t_run = 0.0005, 2.0, 3.0, 0.006, 0.004
    n = 1000
    t = np.arange(n) * TS
    a1, a2 = tl / j, (te - tl) / j
    omega = np.where(t < t_d, -a1 * t, -a1 * t_d + a2 * (t - t_d))  # rad/s mechanical
    cols = {
        "period": np.arange(n),
        # the metric integrates the speed sample by sample: the speed of each period's end
        "speed_true_rpm": np.append(omega[1:], omega[-1] + a2 * TS) * 60 / (2 * math.pi),
        "truth.tl": np.full(n, tl),
        "truth.te": np.where(t < t_d, 0.0, te),
        "fw.state": np.where(t < t_run, 2.0, float(metrics.firmware_state("RUN"))),
    }
    w = metrics.Window(cols, 0.0, (n - 1) * TS, ts=TS)
    back = a1 * t_d**2 / 2 + (a1 * t_d) ** 2 / (2 * a2)
    assert metrics.compute("kickback_deg", w) == pytest.approx(math.degrees(back), rel=0.01)
    assert metrics.compute("torque_time_s", w) == pytest.approx(t_d)
    assert metrics.compute("torque_time_s", w, {"fraction": 2.0}) == math.inf
    assert metrics.compute("run_time_s", w) == pytest.approx(t_run)
    # the load the other way round: the shaft turns back the other way, the same angle
    other = dict(cols, **{"speed_true_rpm": -cols["speed_true_rpm"], "truth.tl": -cols["truth.tl"],
                          "truth.te": -cols["truth.te"]})
    wo = metrics.Window(other, 0.0, (n - 1) * TS, ts=TS)
    assert metrics.compute("kickback_deg", wo) == pytest.approx(math.degrees(back), rel=0.01)
    assert metrics.compute("torque_time_s", wo) == pytest.approx(t_d)
    # no load at the enable: neither is defined (a criterion on them fails: NaN)
    none = dict(cols, **{"truth.tl": np.zeros(n)})
    wn = metrics.Window(none, 0.0, (n - 1) * TS, ts=TS)
    assert math.isnan(metrics.compute("torque_time_s", wn))
    assert math.isnan(metrics.compute("kickback_deg", wn))
