"""PWM command sequences for the plant tests (same commands go to the C plant and the
reference)."""

from __future__ import annotations

import math

import numpy as np
from plant_lib import TBPRD, TS, Pwm


def minmax_compares(v_alpha: float, v_beta: float, vdc: float) -> list[int]:
    """Centre-aligned compare values of the min-max (SVPWM-equivalent) modulation."""
    ph = [v_alpha, -0.5 * v_alpha + 0.5 * math.sqrt(3) * v_beta,
          -0.5 * v_alpha - 0.5 * math.sqrt(3) * v_beta]
    mid = 0.5 * (max(ph) + min(ph))
    out = []
    for v in ph:
        duty = min(1.0, max(0.0, 0.5 + (v - mid) / vdc))
        out.append(round(TBPRD * (1.0 - duty)))
    return out


def varied_sequence(
    n: int, rpm: float, theta0: float, amps: float, seed: int, dead_ticks: int
) -> list[Pwm]:
    """n periods of SVPWM whose voltage vector turns with the rotor (all six sectors when
    n*Ts covers an electrical turn), with random amplitude, asymmetric ('stretched')
    compare values, a leg clamped fully on or off now and then, bursts with the gates
    disabled, and SOCs at random instants and right at switching and dead-time edges."""
    rng = np.random.default_rng(seed)
    we = rpm / 60 * 2 * math.pi * 2
    seq: list[Pwm] = []
    for k in range(n):
        th = theta0 + we * k * TS
        vd = -we * 0.032 * amps
        vq = 1.93 * amps + we * 0.216
        scale = 1.0 + 0.25 * rng.uniform(-1, 1)
        va = scale * (vd * math.cos(th) - vq * math.sin(th))
        vb = scale * (vd * math.sin(th) + vq * math.cos(th))
        cmp = minmax_compares(va, vb, 200.0)
        up, dn = [], []
        for c in cmp:
            stretch = int(rng.integers(-400, 401)) if rng.uniform() < 0.5 else 0
            up.append(int(min(TBPRD, max(0, c - stretch))))
            dn.append(int(min(TBPRD, max(0, c + stretch))))
        if rng.uniform() < 0.05:
            leg = int(rng.integers(0, 3))
            up[leg] = dn[leg] = 0 if rng.uniform() < 0.5 else TBPRD
        socs = sorted(int(s) for s in rng.integers(0, 2 * TBPRD, size=4))
        socs += [min(2 * TBPRD - 1, up[0] + dead_ticks), up[1], 2 * TBPRD - dn[2]]
        socs = [min(max(s, 0), 2 * TBPRD - 1) for s in socs]
        enable = 0 if (k % 60) in (30, 31, 32) else 1
        seq.append(Pwm(cmp_up=(up[0], up[1], up[2]), cmp_dn=(dn[0], dn[1], dn[2]), soc=socs,
                       gate_enable=enable))
    return seq
