"""Flux maps against the profile numbers (docs/design.md section 5) and their consistency."""

from __future__ import annotations

import numpy as np
import pytest
from plant_lib import Plant, profile

H = 1e-5


def numeric_inductances(p: Plant, i_d: float, i_q: float) -> np.ndarray:
    """[[dpsi_d/did, dpsi_d/diq], [dpsi_q/did, dpsi_q/diq]] by central differences."""
    pd_p, _ = p.flux(i_d + H, i_q)
    pd_m, _ = p.flux(i_d - H, i_q)
    pq_p, _ = p.flux(i_d, i_q + H)
    pq_m, _ = p.flux(i_d, i_q - H)
    return np.array([[(pd_p[0] - pd_m[0]) / (2 * H), (pq_p[0] - pq_m[0]) / (2 * H)],
                     [(pd_p[1] - pd_m[1]) / (2 * H), (pq_p[1] - pq_m[1]) / (2 * H)]])


@pytest.mark.parametrize("name", ["ideal", "paper", "harsh"])
def test_incremental_equals_numerical_derivative_and_is_reciprocal(name: str) -> None:
    p = Plant(name)
    rng = np.random.default_rng(1)
    for i_d, i_q in rng.uniform(-12, 12, size=(300, 2)):
        _, linc = p.flux(i_d, i_q)
        num = numeric_inductances(p, i_d, i_q)
        assert num[0, 0] == pytest.approx(linc[0], abs=1e-9)
        assert num[1, 1] == pytest.approx(linc[1], abs=1e-9)
        assert num[0, 1] == pytest.approx(linc[2], abs=1e-9)
        assert num[1, 0] == pytest.approx(num[0, 1], abs=1e-9)  # reciprocity Ldq = Lqd


def test_paper_q_axis_numbers() -> None:
    p = Plant("paper")
    psi_small, _ = p.flux(0.0, 1e-6)
    assert psi_small[1] / 1e-6 == pytest.approx(0.032, rel=1e-9)  # apparent Lq at 0 A
    psi3, linc3 = p.flux(0.0, 3.0)
    assert psi3[1] / 3.0 == pytest.approx(0.028, rel=1e-9)  # apparent Lq at 3 A
    assert linc3[1] == pytest.approx(0.021, abs=1e-3)  # incremental Lq at 3 A
    assert linc3[2] == 0.0  # no cross-saturation in "paper"
    # monotone beyond the fold of the rational law (7.9 A)
    psi = [p.flux(0.0, x)[0][1] for x in np.linspace(0, 40, 801)]
    assert np.all(np.diff(psi) > 0)


@pytest.mark.parametrize("name", ["paper", "harsh"])
def test_d_axis_magnet_side_saturation(name: str) -> None:
    p = Plant(name)
    lds = np.array([p.flux(i_d, 0.0)[1][0] for i_d in np.linspace(-3, 3, 61)])
    assert np.all(lds >= 0.014)
    assert p.flux(0.0, 0.0)[1][0] == pytest.approx(profile(name)["magnetics"]["ld_h"], rel=1e-12)
    # +id adds to the magnet flux and saturates more: smaller incremental Ld
    assert p.flux(3.0, 0.0)[1][0] < p.flux(-3.0, 0.0)[1][0]
    assert np.all(np.diff(lds) < 0)


def test_harsh_cross_saturation() -> None:
    p = Plant("harsh")
    want = profile("harsh")["magnetics"]["ldq_ref_h"]
    assert abs(want) == pytest.approx(0.5e-3)
    _, linc = p.flux(0.0, 3.0)
    num = numeric_inductances(p, 0.0, 3.0)
    assert linc[2] == pytest.approx(want, rel=1e-9)
    assert num[0, 1] == pytest.approx(want, rel=1e-6)
    assert num[1, 0] == pytest.approx(want, rel=1e-6)
    # q-axis self-saturation as in "paper"
    psi, _ = p.flux(0.0, 3.0)
    assert psi[1] / 3.0 == pytest.approx(0.028, rel=1e-9)


@pytest.mark.parametrize("name", ["paper", "harsh"])
def test_truth_apparent_and_incremental(name: str) -> None:
    p = Plant(name)
    prof = profile(name)
    lam = prof["machine"]["lambda_m_wb"]
    for i_d, i_q in [(-2.0, 3.0), (1.5, -2.5), (-4.0, 5.5)]:
        p.set_state(0.3, 0.0, i_d, i_q)
        t = p.truth_now()
        psi, linc = p.flux(i_d, i_q)
        assert t["id"] == pytest.approx(i_d, abs=1e-12)
        assert t["iq"] == pytest.approx(i_q, abs=1e-12)
        assert t["ld_app"] == pytest.approx((psi[0] - lam) / i_d, rel=1e-12)
        assert t["lq_app"] == pytest.approx(psi[1] / i_q, rel=1e-12)
        assert t["ld_inc"] == pytest.approx(linc[0], rel=1e-12)
        assert t["lq_inc"] == pytest.approx(linc[1], rel=1e-12)
        assert t["ldq_inc"] == pytest.approx(linc[2], rel=1e-12, abs=1e-15)
        assert t["lambda_m"] == lam and t["rs"] == prof["machine"]["rs_ohm"]
        # torque from the fluxes (co-energy): Te = 1.5 pp (psi_d iq - psi_q id)
        pp = prof["machine"]["pole_pairs"]
        assert t["te"] == pytest.approx(1.5 * pp * (psi[0] * i_q - psi[1] * i_d), rel=1e-12)


@pytest.mark.parametrize("name", ["paper", "harsh"])
def test_inverse_flux_map(name: str) -> None:
    p = Plant(name)
    rng = np.random.default_rng(2)
    for i_d, i_q in rng.uniform(-60, 60, size=(200, 2)):
        psi, _ = p.flux(i_d, i_q)
        i, iters = p.current_from_flux(psi[0], psi[1])
        assert iters > 0
        assert i == pytest.approx([i_d, i_q], abs=1e-10)
