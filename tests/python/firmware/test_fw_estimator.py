"""Position and inductance estimator against the model of docs/estimator.md.

Synthetic slopes come from the model equations (section 2, and the full voltage equation with
back-EMF, resistance and a turning rotor for section 4.5); the noise test draws per-sample
current noise, runs the core's least-squares slope, slope difference and estimator, and
compares the spread with the noise law of section 6.
"""

from __future__ import annotations

import math

import fwlib
import numpy as np
import pytest

LD, LQ, LAM, RS, VDC = 0.015, 0.032, 0.216, 1.93, 200.0
KV = 2.0 * VDC / 3.0
G0 = 0.5 * (1 / LD + 1 / LQ)
G1 = 0.5 * (1 / LD - 1 / LQ)


def vec(k: int) -> complex:
    return KV * complex(math.cos((k - 1) * math.pi / 3), math.sin((k - 1) * math.pi / 3))


def gamma(theta: float, ld: float = LD, lq: float = LQ) -> np.ndarray:
    """inverse inductance matrix in alpha-beta (section 1)"""
    g0 = 0.5 * (1 / ld + 1 / lq)
    g1 = 0.5 * (1 / ld - 1 / lq)
    c, s = math.cos(2 * theta), math.sin(2 * theta)
    return np.array([[g0 + g1 * c, g1 * s], [g1 * s, g0 - g1 * c]])


def apply(m: np.ndarray, v: complex) -> complex:
    r = m @ np.array([v.real, v.imag])
    return complex(r[0], r[1])


def model_slope(theta: float, omega: float, idq: complex, v: complex) -> complex:
    """di/dt = Gamma (v - rs i - e - omega dL/dtheta i), steady-state rotor-frame current"""
    i = idq * complex(math.cos(theta), math.sin(theta))
    l1 = 0.5 * (LD - LQ)
    c2, s2 = math.cos(2 * theta), math.sin(2 * theta)
    dl_i = complex(2 * l1 * (-s2 * i.real + c2 * i.imag), 2 * l1 * (c2 * i.real + s2 * i.imag))
    e = omega * LAM * complex(-math.sin(theta), math.cos(theta))
    return apply(gamma(theta), v - RS * i - e - omega * dl_i)


@pytest.mark.parametrize("sector", range(1, 7))
def test_exact_in_every_sector_and_both_polarities(sector: int) -> None:
    vecs = [sector, sector % 6 + 1]
    worst = 0.0
    for theta in np.linspace(0.0, 2 * math.pi, 181)[:-1] + 0.002:
        est = fwlib.est_solve(vecs, [apply(gamma(theta), vec(k)) for k in vecs], [1e-5, 9e-5], KV)
        flipped = fwlib.est_solve(
            vecs, [apply(gamma(theta + math.pi), vec(k)) for k in vecs], [1e-5, 9e-5], KV
        )
        assert est.ok and est.n_active == 2
        worst = max(worst, abs(float(fwlib.diff_mod_pi(est.theta_raw, theta))))
        # theta and theta + pi are the same raw estimate
        assert abs(float(fwlib.diff_mod_pi(flipped.theta_raw, est.theta_raw))) <= 1e-6
        assert est.ld == pytest.approx(LD, rel=1e-5)
        assert est.lq == pytest.approx(LQ, rel=1e-5)
        assert abs(est.residual) <= 1e-4 * est.gamma0
    assert worst <= 1e-6


@pytest.mark.parametrize("rpm", [600.0, 2000.0, 3000.0])
def test_exact_with_back_emf_and_rotation(rpm: float) -> None:
    """Rotor turning between the windows, EMF and load current: with the zero-slope rotation
    (section 4.5) and the rotating least squares the estimate is exact at the stamp (mean of
    the two active windows); without them it is off by the amounts the note quotes."""
    omega = rpm / 60 * 2 * math.pi * 2
    t1, t0, t2 = 15e-6, 52e-6, 91e-6
    idq = complex(-0.7, 2.2)
    worst = 0.0
    worst_raw = 0.0
    for sector in range(1, 7):
        vecs = [sector, sector % 6 + 1]
        for theta0 in np.linspace(0.0, 2 * math.pi, 61)[:-1] + 0.01:
            s0 = model_slope(theta0 + omega * t0, omega, idq, 0j)
            s = [
                model_slope(theta0 + omega * tk, omega, idq, vec(k))
                for tk, k in zip((t1, t2), vecs, strict=True)
            ]
            di = [
                fwlib.slope_diff(sk, tk, s0, t0, omega) for sk, tk in zip(s, (t1, t2), strict=True)
            ]
            est = fwlib.est_solve(vecs, di, [t1, t2], KV, omega)
            raw = fwlib.est_solve(vecs, [sk - s0 for sk in s], [t1, t2], KV, 0.0)
            truth = theta0 + omega * 0.5 * (t1 + t2)
            assert est.t_ref == pytest.approx(0.5 * (t1 + t2), abs=1e-10)
            worst = max(worst, abs(float(fwlib.diff_mod_pi(est.theta_raw, truth))))
            worst_raw = max(worst_raw, abs(float(fwlib.diff_mod_pi(raw.theta_raw, truth))))
            assert est.ld == pytest.approx(LD, rel=2e-5)
            assert est.lq == pytest.approx(LQ, rel=2e-5)
    assert worst <= 1e-6
    assert worst_raw > 50 * worst


def test_single_vector_fallback() -> None:
    for k in range(1, 7):
        for theta in np.linspace(0, 2 * math.pi, 37):
            est = fwlib.est_solve([k], [apply(gamma(theta), vec(k))], [4e-5], KV, gamma0_prior=G0)
            assert abs(float(fwlib.diff_mod_pi(est.theta_raw, theta))) <= 2e-6


def test_residual_flags_inconsistent_data() -> None:
    vecs = [1, 2]
    good = [apply(gamma(0.4), vec(k)) for k in vecs]
    bad = [good[0], good[1] * complex(math.cos(0.2), math.sin(0.2))]
    assert abs(fwlib.est_solve(vecs, good, [1e-5, 9e-5], KV).residual) < 1e-3
    assert abs(fwlib.est_solve(vecs, bad, [1e-5, 9e-5], KV).residual) > 1.0


ADC_BITS = 24
ADC_RANGE = 10.0


def codes(i: np.ndarray) -> list[int]:
    full = 2**ADC_BITS
    return [
        int(c)
        for c in np.clip(np.floor((i + ADC_RANGE) / (2 * ADC_RANGE) * full + 0.5), 0, full - 1)
    ]


def noisy_estimate(
    rng: np.random.Generator, theta: float, sector: int, sigma: float, w_ticks: int, n: int
) -> fwlib.Estimate:
    """Three states (active, zero, active) sampled n times over w_ticks each; current noise
    sigma per sample and phase; standstill, no current."""
    vecs = [sector, sector % 6 + 1]
    starts = {"a1": 0, "z": 3000, "a2": 6000}
    slopes = {
        "a1": apply(gamma(theta), vec(vecs[0])),
        "z": 0j,
        "a2": apply(gamma(theta), vec(vecs[1])),
    }
    meas: dict[str, tuple[complex, float]] = {}
    for key, start in starts.items():
        ticks = [start + round(k * w_ticks / (n - 1)) for k in range(n)]
        t = np.array(ticks) * fwlib.TICK
        s = slopes[key]
        i_alpha = s.real * t
        i_beta = s.imag * t
        ia = i_alpha + rng.normal(0, sigma, n)
        ib = -0.5 * i_alpha + 0.5 * math.sqrt(3) * i_beta + rng.normal(0, sigma, n)
        res = fwlib.slope_window(ticks, codes(ia), codes(ib), ADC_BITS, ADC_RANGE)
        assert res is not None
        meas[key] = (res[0], res[1] * fwlib.TICK)
    di = [
        fwlib.slope_diff(meas[k][0], meas[k][1], meas["z"][0], meas["z"][1], 0.0)
        for k in ("a1", "a2")
    ]
    return fwlib.est_solve(vecs, di, [meas["a1"][1], meas["a2"][1]], KV)


@pytest.mark.parametrize(("sigma", "w_us"), [(1e-3, 15.0), (0.5e-3, 5.0), (2e-3, 15.0)])
def test_noise_follows_the_noise_law(sigma: float, w_us: float) -> None:
    """sigma_theta ~ 0.91 sigma_i / (kv W Gamma1) (section 6), two samples per state, RMS
    over random angles and sectors, within 20 %."""
    rng = np.random.default_rng(7)
    w_ticks = round(w_us * 100)
    errs = []
    gam0 = []
    gam1 = []
    for _ in range(3000):
        theta = rng.uniform(0, 2 * math.pi)
        sector = int(rng.integers(1, 7))
        est = noisy_estimate(rng, theta, sector, sigma, w_ticks, 2)
        errs.append(float(fwlib.diff_mod_pi(est.theta_raw, theta)))
        gam0.append(est.gamma0)
        gam1.append((est.g * complex(math.cos(-2 * theta), math.sin(-2 * theta))).real)
    rms = math.sqrt(float(np.mean(np.square(errs))))
    law = 0.91 * sigma / (KV * w_us * 1e-6 * G1)
    print(
        f"sigma {sigma * 1e3:.1f} mA W {w_us:.0f} us: rms {math.degrees(rms):.3f} deg, "
        f"law {math.degrees(law):.3f} deg, ratio {rms / law:.3f}"
    )
    assert 0.8 <= rms / law <= 1.2
    # Ld, Lq recovered from the averaged (unbiased) inverse inductances
    g0m, g1m = float(np.mean(gam0)), float(np.mean(gam1))
    assert 1 / (g0m + g1m) == pytest.approx(LD, rel=0.01)
    assert 1 / (g0m - g1m) == pytest.approx(LQ, rel=0.01)


def test_more_samples_per_state_reduce_the_spread() -> None:
    rng = np.random.default_rng(3)
    spread = {}
    for n in (2, 5):
        errs = [
            float(
                fwlib.diff_mod_pi(noisy_estimate(rng, th, 1 + k % 6, 1e-3, 1500, n).theta_raw, th)
            )
            for k, th in enumerate(rng.uniform(0, 2 * math.pi, 2000))
        ]
        spread[n] = math.sqrt(float(np.mean(np.square(errs))))
    # least squares over n equally spaced samples: variance ratio 12(n-1)/(n(n+1)) / 2
    expected = math.sqrt(12 * 4 / (5 * 6) / 2)
    assert spread[5] / spread[2] == pytest.approx(expected, rel=0.15)


def test_pll_resolves_the_branch_and_tracks() -> None:
    lib = fwlib.lib()
    import ctypes as C

    buf = C.create_string_buffer(int(lib.fwt_tracker_size()))
    omega = 2 * math.pi * 40.0
    lib.fwt_tracker_init(buf, 60.0, 1.0, 2.0 + math.pi, 0.0)  # prediction on the pi branch
    out = fwlib.dbuf(4)
    truth = 0.0
    for k in range(1, 2001):
        truth = 2.0 + math.pi + omega * k * fwlib.TS
        raw = float(fwlib.diff_mod_pi(truth, 0.0))  # the estimator only knows theta mod pi
        lib.fwt_tracker_step(buf, raw, 0, out)
    assert abs(float(fwlib.wrap_pi(out[2] - truth))) < 1e-3
    assert out[3] == pytest.approx(omega, rel=1e-3)
