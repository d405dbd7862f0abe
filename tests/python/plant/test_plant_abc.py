"""The paper's abc model (eqs. 1-7, with a leakage Ll) gives the same phase currents as
the plant's dq flux model: with an isolated neutral, Ll only acts on the zero sequence."""

from __future__ import annotations

import math

import numpy as np
import pytest
from plant_lib import Plant, profile
from plant_reference import PERIOD_TICKS, TICK, UPPER, Command, gate_timeline
from plant_sequences import varied_sequence
from scipy.integrate import solve_ivp


def inductance_abc(theta: float, ll: float, lx: float, ly: float) -> tuple[np.ndarray, np.ndarray]:
    """L_abc(theta) of eqs. 2-7 and its derivative with respect to theta."""
    t2, p = 2 * theta, 2 * math.pi / 3

    def mat(f: float, g: float, h: float, k: float) -> np.ndarray:
        # f: scale of the constant parts; g, h, k: cos terms for angles 2t, 2t+p, 2t-p
        return np.array([
            [f * (ll + lx) - ly * g, f * (-lx / 2) - ly * k, f * (-lx / 2) - ly * h],
            [f * (-lx / 2) - ly * k, f * (ll + lx) - ly * h, f * (-lx / 2) - ly * g],
            [f * (-lx / 2) - ly * h, f * (-lx / 2) - ly * g, f * (ll + lx) - ly * k],
        ])

    lmat = mat(1.0, math.cos(t2), math.cos(t2 + p), math.cos(t2 - p))
    dmat = mat(0.0, -2 * math.sin(t2), -2 * math.sin(t2 + p), -2 * math.sin(t2 - p))
    return lmat, dmat


@pytest.mark.parametrize("leakage", [0.0, 3e-3])
def test_abc_model_equals_plant(leakage: float) -> None:
    rpm, theta0, n = 1200.0, 0.9, 200
    over = {"load.mode": 1, "load.speed_rpm": rpm, "initial.theta_e_deg": math.degrees(theta0)}
    prof = profile("ideal", over)
    ld, lq = prof["magnetics"]["ld_h"], prof["magnetics"]["lq_h"]
    rs, lam = prof["machine"]["rs_ohm"], prof["machine"]["lambda_m_wb"]
    vdc, pp = prof["inverter"]["vdc_v"], prof["machine"]["pole_pairs"]
    # eqs. 8, 9: Ld = Ll + 1.5 (Lx - Ly), Lq = Ll + 1.5 (Lx + Ly)
    lx = (ld + lq - 2 * leakage) / 3
    ly = (lq - ld) / 3
    we = pp * rpm / 60 * 2 * math.pi

    seq = varied_sequence(n, rpm, theta0, amps=2.5, seed=21, dead_ticks=0)
    for c in seq:
        c.gate_enable = 1  # ideal switches only: no diode conduction in this comparison
    plant = Plant("ideal", over)
    got = [plant.step(c) for c in seq]

    def rhs(t: float, i: np.ndarray, u: np.ndarray) -> np.ndarray:
        th = theta0 + we * t
        lmat, dmat = inductance_abc(th, leakage, lx, ly)
        emf = np.array([-we * lam * math.sin(th - k * 2 * math.pi / 3) for k in range(3)])
        # eq. 1 with the star-point voltage vn as a fourth unknown and ia + ib + ic = 0
        a = np.zeros((4, 4))
        a[:3, :3] = lmat
        a[:3, 3] = 1.0
        a[3, :3] = 1.0
        b = np.zeros(4)
        b[:3] = u - rs * i - we * dmat @ i - emf
        return np.linalg.solve(a, b)[:3]

    timeline = gate_timeline([Command(c.cmp_up, c.cmp_dn, c.soc) for c in seq], 0)
    edges = sorted({t for tl in timeline for t, _ in tl} | {n * PERIOD_TICKS})
    socs = {k * PERIOD_TICKS + s for k, c in enumerate(seq) for s in c.soc}
    stops = sorted(set(edges) | socs)
    i = np.zeros(3)
    values: dict[int, np.ndarray] = {}
    t_prev = 0
    for stop in stops:
        if t_prev in socs:
            values[t_prev] = i.copy()
        if stop == t_prev:
            continue
        u = np.array([
            vdc if [s for tk, s in tl if tk <= t_prev][-1] == UPPER else 0.0 for tl in timeline
        ])
        sol = solve_ivp(rhs, (t_prev * TICK, stop * TICK), i, method="DOP853", rtol=1e-11,
                        atol=1e-13, args=(u,))
        i = sol.y[:, -1]
        t_prev = stop
    err = 0.0
    for k, (c, g) in enumerate(zip(seq, got, strict=True)):
        ref = np.array([values[k * PERIOD_TICKS + s] for s in c.soc])
        err = max(err, float(np.max(np.abs(g.ia_true - ref[:, 0]))),
                  float(np.max(np.abs(g.ib_true - ref[:, 1]))))
    print(f"abc model (Ll = {leakage * 1e3:.0f} mH) vs plant: {err * 1e3:.3g} mA")
    assert max(float(np.max(np.abs(g.ia_true))) for g in got) > 1.0
    assert err < 1e-6
