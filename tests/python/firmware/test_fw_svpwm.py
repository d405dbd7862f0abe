"""SVPWM pattern and sampling plan, checked from the compare values alone.

The expectations come from docs/interfaces.md (upper gate on during [cmp_up, 2*TBPRD - cmp_dn))
and the isolated-neutral voltage of a switching state: the volt-seconds of a period follow from
the per-phase on-times. Nothing here reuses the firmware's own arithmetic.
"""

from __future__ import annotations

import math

import fwlib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

P = fwlib.PERIOD_TICKS
TICK = fwlib.TICK
VEC_BITS = {1: 0b001, 2: 0b011, 3: 0b010, 4: 0b110, 5: 0b100, 6: 0b101, 7: 0b111}


def on_intervals(plan: fwlib.Plan) -> list[tuple[int, int]]:
    return [(plan.cmp_up[x], 2 * fwlib.TBPRD - plan.cmp_dn[x]) for x in range(3)]


def states(plan: fwlib.Plan) -> np.ndarray:
    """switching state (bit0 = a) at every tick of the period"""
    t = np.arange(P)
    s = np.zeros(P, dtype=int)
    for x, (on, off) in enumerate(on_intervals(plan)):
        s |= ((t >= on) & (t < off)).astype(int) << x
    return s


def applied_volt_seconds(plan: fwlib.Plan, vdc: float) -> complex:
    tau = [max(off - on, 0) * TICK for on, off in on_intervals(plan)]
    va = vdc * 2.0 / 3.0 * (tau[0] - 0.5 * (tau[1] + tau[2]))
    vb = vdc / math.sqrt(3.0) * (tau[1] - tau[2])
    return complex(va, vb)


def check_plan(plan: fwlib.Plan, tmin: int, on: int, off: int, n: int) -> None:
    s = states(plan)
    assert all(0 <= c <= fwlib.TBPRD for c in plan.cmp_up + plan.cmp_dn)
    assert len(plan.soc) <= fwlib.MAX_SOC
    used = 0
    assert plan.windows[0].measured, "the zero state is always measured"
    for w in plan.windows:
        if not w.measured:
            continue
        bits = VEC_BITS[w.vec]
        assert w.end - w.start >= tmin
        assert np.all(s[w.start : w.end] == bits), "a measured window is one switching state"
        if w.start > 0:
            assert s[w.start - 1] != bits
        if w.end < P:
            assert s[w.end] != bits
        socs = plan.soc[w.soc_first : w.soc_first + w.soc_count]
        assert len(socs) == n
        assert all(w.start + on <= t <= w.end - off for t in socs), "SOCs inside their state"
        used += len(socs)
    assert used == len(plan.soc)


def unit(k: int) -> complex:
    return complex(math.cos((k - 1) * math.pi / 3), math.sin((k - 1) * math.pi / 3))


@settings(max_examples=400, deadline=None)
@given(
    sector=st.integers(1, 6),
    frac1=st.floats(0.0, 1.0),
    frac2=st.floats(0.0, 1.0),
    vdc=st.sampled_from([150.0, 200.0, 240.0]),
    tmin_us=st.sampled_from([16.0, 20.0, 24.0]),
    n=st.integers(2, 5),
    stretch=st.booleans(),
    parity=st.integers(0, 1),
)
def test_lattice_references_are_reproduced_exactly(
    sector: int,
    frac1: float,
    frac2: float,
    vdc: float,
    tmin_us: float,
    n: int,
    stretch: bool,
    parity: int,
) -> None:
    """Any reference on the tick lattice, all sectors, up to the modulation limit: the
    compare values apply exactly its volt-seconds (1e-9 V*s), stretched periods included."""
    tmin = round(tmin_us * 100)
    budget = P - tmin
    n1 = round(frac1 * budget)
    n2 = round(frac2 * (budget - n1))
    kv = 2.0 * vdc / 3.0
    ref_vs = kv * (n1 * unit(sector) + n2 * unit(sector % 6 + 1)) * TICK
    v = ref_vs / fwlib.TS
    plan = fwlib.svpwm(
        vdc, v.real, v.imag, tmin_us=tmin_us, n_per_state=n, stretch=stretch, parity=parity
    )
    got = applied_volt_seconds(plan, vdc)
    assert abs(got - ref_vs) <= 1e-9
    assert not plan.clipped
    check_plan(plan, tmin, 1000, 500, n)
    both_long = n1 >= tmin and n2 >= tmin
    if both_long:
        assert plan.windows[1].measured and plan.windows[2].measured
    if stretch and 5 * tmin <= P:
        assert plan.windows[1].measured or plan.windows[2].measured
    if stretch and n1 < tmin and n2 < tmin and 5 * tmin <= P:
        # small voltages: both short vectors are stretched and compensated
        assert plan.windows[1].measured and plan.windows[2].measured


@settings(max_examples=300, deadline=None)
@given(
    angle=st.floats(0.0, 2 * math.pi),
    mag_frac=st.floats(0.0, 0.9999),
    on_us=st.sampled_from([6.0, 8.0, 10.0]),
    off_us=st.sampled_from([3.0, 5.0]),
    n=st.integers(2, 5),
)
def test_any_reference_within_the_limit(
    angle: float, mag_frac: float, on_us: float, off_us: float, n: int
) -> None:
    """Off the lattice: error below one tick of each vector, never clipped inside the circle
    (1 - Tmin/Ts) Vdc/sqrt(3), every measured state >= Tmin with its SOCs inside."""
    vdc = 200.0
    vmax = fwlib.svpwm_vmax(vdc, 20.0)
    assert vmax == pytest.approx(0.8 * vdc / math.sqrt(3.0), rel=1e-6)
    v = mag_frac * vmax * complex(math.cos(angle), math.sin(angle))
    plan = fwlib.svpwm(vdc, v.real, v.imag, on_us=on_us, off_us=off_us, n_per_state=n)
    kv = 2.0 * vdc / 3.0
    assert abs(applied_volt_seconds(plan, vdc) - v * fwlib.TS) <= kv * TICK
    assert not plan.clipped
    check_plan(plan, 2000, round(on_us * 100), round(off_us * 100), n)


def test_carried_rounding_error_does_not_drift() -> None:
    vdc = 200.0
    vmax = fwlib.svpwm_vmax(vdc, 20.0)
    carry = [0.0, 0.0]
    acc = 0j
    worst = 0.0
    for k in range(3000):
        v = 0.97 * vmax * abs(math.sin(0.002 * k)) * complex(math.cos(0.05 * k), math.sin(0.05 * k))
        plan = fwlib.svpwm(vdc, v.real, v.imag, parity=k, carry=carry)
        acc += applied_volt_seconds(plan, vdc) - v * fwlib.TS
        worst = max(worst, abs(acc))
    assert worst <= 1.5 * (2.0 * vdc / 3.0) * TICK


def test_outside_the_hexagon_is_clipped_and_keeps_the_zero_window() -> None:
    vdc = 200.0
    for deg in range(0, 360, 7):
        a = math.radians(deg)
        plan = fwlib.svpwm(vdc, 130.0 * math.cos(a), 130.0 * math.sin(a))
        assert plan.clipped
        check_plan(plan, 2000, 1000, 500, 2)
