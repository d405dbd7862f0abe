"""MTPA (paper eq. 50), flux weakening (eq. 53) and the current references, against the
printed closed forms and against a numerical optimum of the torque eq. 10 on the current
circle and the voltage ellipse (scipy)."""

from __future__ import annotations

import math

import fwlib
import numpy as np
import pytest
from scipy.optimize import minimize

LD, LQ, LAM, PP = 0.015, 0.032, 0.216, 2.0
I_MAX = 7.5
VMAX = 0.92 * 0.8 * 200.0 / math.sqrt(3.0)  # the core's default FW voltage at 200 V


def torque(i: np.ndarray, ld: float = LD, lq: float = LQ, lam: float = LAM) -> float:
    """eq. 10 with P = 4 poles: Te = 3P/4 [(Ld - Lq) id iq + lambda iq]"""
    id_, iq = i
    return 3 * 4 / 4 * ((ld - lq) * id_ * iq + lam * iq)


def eq50(iq: float, ld: float, lq: float, lam: float) -> float:
    d = ld - lq
    return -lam / (2 * d) - math.sqrt(lam**2 / (4 * d**2) + iq**2)


def eq53(iq: float, omega: float, vmax: float, ld: float, lq: float, lam: float) -> float:
    return (-lam + math.sqrt((vmax / omega) ** 2 - (lq * iq) ** 2)) / ld


def refs(
    iq_demand: float,
    omega: float,
    mode: int = 0,
    vmax: float = VMAX,
    i_max: float = I_MAX,
    ld: float = LD,
    lq: float = LQ,
    lam: float = LAM,
) -> tuple[float, float, bool]:
    out = fwlib.dbuf(2)
    fw = fwlib.lib().fwt_refs_select(mode, iq_demand, omega, vmax, i_max, ld, lq, lam, 0.0, out)
    return out[0], out[1], bool(fw)


@pytest.mark.parametrize("params", [(LD, LQ, LAM), (0.010, 0.030, 0.15), (0.02, 0.025, 0.3)])
def test_mtpa_matches_eq50(params: tuple[float, float, float]) -> None:
    ld, lq, lam = params
    for iq in np.linspace(-8, 8, 33):
        got = fwlib.lib().fwt_refs_mtpa_id(iq, ld, lq, lam)
        assert got == pytest.approx(eq50(iq, ld, lq, lam), abs=2e-5 + 1e-5 * abs(iq))


@pytest.mark.parametrize("te", [0.3, 1.0, 2.0, 3.5])
def test_mtpa_is_the_minimum_current_for_the_torque(te: float) -> None:
    res = minimize(
        lambda i: i @ i,
        x0=np.array([-0.2, 1.0]),
        constraints=[{"type": "eq", "fun": lambda i: torque(i) - te}],
        method="SLSQP",
        options={"ftol": 1e-14, "maxiter": 500},
    )
    assert res.success
    id_opt, iq_opt = res.x
    assert fwlib.lib().fwt_refs_mtpa_id(iq_opt, LD, LQ, LAM) == pytest.approx(id_opt, abs=2e-4)
    te_opt = fwlib.lib().fwt_refs_torque(id_opt, iq_opt, LD, LQ, LAM, PP)
    assert te_opt == pytest.approx(te, rel=1e-6)


def test_flux_weakening_matches_eq53() -> None:
    for omega in (500.0, 628.0, 800.0):
        for iq in (0.0, 1.0, 2.5):
            got = fwlib.lib().fwt_refs_fluxweak_id(iq, omega, VMAX, LD, LQ, LAM)
            assert got == pytest.approx(eq53(iq, omega, VMAX, LD, LQ, LAM), abs=1e-4)


def max_torque_point(omega: float, vmax: float = VMAX, i_max: float = I_MAX) -> np.ndarray:
    cons = [
        {"type": "ineq", "fun": lambda i: i_max**2 - i @ i},
        {
            "type": "ineq",
            "fun": lambda i: (vmax / omega) ** 2 - (LD * i[0] + LAM) ** 2 - (LQ * i[1]) ** 2,
        },
    ]
    best = None
    for x0 in ([-1.0, 1.0], [-4.0, 4.0], [-6.0, 2.0]):
        res = minimize(
            lambda i: -torque(i),
            x0=np.array(x0),
            constraints=cons,
            method="SLSQP",
            options={"ftol": 1e-12, "maxiter": 1000},
        )
        if res.success and (best is None or -res.fun > -best.fun):
            best = res
    assert best is not None
    return np.asarray(best.x)


@pytest.mark.parametrize("rpm", [500.0, 1500.0, 2200.0, 2600.0, 3000.0, 3400.0])
def test_full_demand_gives_the_maximum_torque_point(rpm: float) -> None:
    """Constant-torque region: MTPA on the current circle; field-weakening region: the
    intersection of the current circle with the voltage ellipse."""
    omega = rpm / 60 * 2 * math.pi * PP
    id_ref, iq_ref, fw = refs(I_MAX, omega)
    opt = max_torque_point(omega)
    assert id_ref == pytest.approx(opt[0], abs=2e-3)
    assert iq_ref == pytest.approx(opt[1], abs=2e-3)
    on_ellipse = math.hypot(LD * id_ref + LAM, LQ * iq_ref) * omega
    assert fw == (on_ellipse >= VMAX * (1 - 1e-4))


@pytest.mark.parametrize("rpm", [2600.0, 3000.0])
def test_partial_demand_in_field_weakening_sits_on_the_voltage_ellipse(rpm: float) -> None:
    omega = rpm / 60 * 2 * math.pi * PP
    for iq_demand in (0.2, 0.8, 1.5):
        id_ref, iq_ref, fw = refs(iq_demand, omega)
        assert fw
        assert iq_ref == pytest.approx(iq_demand)
        assert id_ref == pytest.approx(eq53(iq_demand, omega, VMAX, LD, LQ, LAM), abs=1e-4)
        assert math.hypot(LD * id_ref + LAM, LQ * iq_ref) * omega == pytest.approx(VMAX, rel=1e-5)
    # below base speed the same demand is plain MTPA
    id_ref, iq_ref, fw = refs(1.5, 100.0)
    assert not fw and id_ref == pytest.approx(eq50(1.5, LD, LQ, LAM), abs=1e-5)


def test_id_zero_mode_never_weakens() -> None:
    for omega in (100.0, 700.0):
        id_ref, iq_ref, fw = refs(2.0, omega, mode=2)
        assert (id_ref, iq_ref, fw) == (0.0, pytest.approx(2.0), False)
    id_ref, iq_ref, _ = refs(20.0, 100.0, mode=2)
    assert iq_ref == pytest.approx(I_MAX)
