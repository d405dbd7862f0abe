"""Independent reference of the bench for the plant tests, integrated with scipy solve_ivp.

Written from the physics, not from the C code, and deliberately in other coordinates:

* state: the phase currents as (i_alpha, i_beta) in the stator frame (the C plant uses
  the dq fluxes), plus theta, omega and the sensor-filter outputs;
* Faraday in the stator frame, d psi_ab/dt = v_ab - rs*i_ab, with psi_ab = R(theta) Psi(i_dq)
  and Psi the profile's flux map; the incremental inductances come from complex-step
  differentiation of Psi (the C plant uses closed-form Hessians);
* the gate timing is built globally over the whole run from the command signals (the C
  plant carries gate memory from period to period);
* conduction modes at a zero current are found by trying every assignment of
  {open, conducting +, conducting -} to the legs at zero current and keeping the consistent
  one (the C plant resolves them step by step);
* the open-phase voltage is found from two evaluations of the linear dependence of
  d i_x/dt on u_x;
* a disconnected phase (the OPEN_PHASE fault, ``run(disconnect=...)``) is a leg whose terminal
  floats: from the period it opens its current is cut while the loop through the other two
  phases keeps its flux linkage (``_cut``: a bracketing root search on the stator-frame flux;
  the C plant runs Newton in dq), and the other legs then conduct by the signs of the
  currents that are left.
"""

from __future__ import annotations

import cmath
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

TBPRD = 5000
PERIOD_TICKS = 2 * TBPRD
TICK = 1e-8
TS = PERIOD_TICKS * TICK
SQ3 = math.sqrt(3.0)

POS, NEG, OPEN = "pos", "neg", "open"
UPPER, LOWER, NONE = "upper", "lower", "none"
DISCONNECTED = "disconnected"  # a phase cut off the inverter: its terminal floats


@dataclass
class Command:
    cmp_up: Sequence[int]
    cmp_dn: Sequence[int]
    soc: Sequence[int]
    gate_enable: int = 1


class FluxMap:
    """psi(id, iq) of the profile (see the comments in plant_rt/profiles/*.toml)."""

    def __init__(self, prof: dict[str, dict[str, Any]]):
        m = prof["magnetics"]
        self.lam = float(prof["machine"]["lambda_m_wb"])
        self.ld0 = float(m["ld_h"])
        self.ld_sat = float(m["ld_sat_h"])
        self.knee = float(m["ld_knee_a"])
        self.width = float(m["ld_width_a"])
        logistic0 = 1.0 / (1.0 + math.exp(-self.knee / self.width))
        self.ld_delta = (self.ld0 - self.ld_sat) / logistic0
        self.lq0 = float(m["lq_h"])
        self.a = float(m["lq_sat_per_a2"])
        self.x1 = float(m["lq_ext_from_a"])
        self.lq_inf = float(m["lq_inf_h"])
        # incremental Lq of the rational law at x1 and its slope, numerically
        self.l1 = self._lq_rational_inc(self.x1)
        delta = 1e-4
        slope = (
            self._lq_rational_inc(self.x1 + delta) - self._lq_rational_inc(self.x1 - delta)
        ) / (2 * delta)
        self.s = -slope / (self.l1 - self.lq_inf) if self.a > 0 else 0.0
        self.psi1 = self.lq0 * self.x1 / (1 + self.a * self.x1**2)
        self.S = float(m["cross_scale_a"])
        iref = float(m["cross_ref_a"])
        self.K = -float(m["ldq_ref_h"]) / (iref * math.exp(-(iref**2) / (2 * self.S**2)))

    def _lq_rational(self, x: complex) -> complex:
        return self.lq0 * x / (1 + self.a * x * x)

    def _lq_rational_inc(self, x: float) -> float:
        h = 1e-30
        return self._lq_rational(complex(x, h)).imag / h

    def psi(self, i_d: complex, i_q: complex) -> tuple[complex, complex]:
        w, k = self.width, self.knee
        # psi_d = lam + Lsat*id + dL * integral_0^id logistic((k - x)/w) dx
        integral = w * (cmath.log(1 + cmath.exp(k / w)) - cmath.log(1 + cmath.exp((k - i_d) / w)))
        psi_d = self.lam + self.ld_sat * i_d + self.ld_delta * integral
        sign = -1.0 if i_q.real < 0 else 1.0
        x = sign * i_q
        if self.a == 0 or x.real <= self.x1:
            psi_q = self._lq_rational(i_q)
        else:
            dx = x - self.x1
            tail = (1 - cmath.exp(-self.s * dx)) / self.s
            psi_q = sign * (self.psi1 + self.lq_inf * dx + (self.l1 - self.lq_inf) * tail)
        if self.K != 0.0:
            S = self.S
            g = cmath.exp(-(i_q**2) / (2 * S * S))
            psi_d -= self.K * (1 / cmath.cosh(i_d / S)) ** 2 * S * S * (1 - g)
            psi_q -= self.K * S * cmath.tanh(i_d / S) * i_q * g
        return psi_d, psi_q

    def psi_real(self, i_d: float, i_q: float) -> tuple[float, float]:
        pd, pq = self.psi(complex(i_d), complex(i_q))
        return pd.real, pq.real

    def incremental(self, i_d: float, i_q: float) -> np.ndarray:
        """[[dpsi_d/did, dpsi_d/diq], [dpsi_q/did, dpsi_q/diq]] by complex step."""
        h = 1e-30
        a = self.psi(complex(i_d, h), complex(i_q))
        b = self.psi(complex(i_d), complex(i_q, h))
        return np.array([[a[0].imag / h, b[0].imag / h], [a[1].imag / h, b[1].imag / h]])


def gate_timeline(cmds: Sequence[Command], dead_ticks: int) -> list[list[tuple[int, str]]]:
    """Per leg: [(absolute tick, gate state from then on)], starting at tick 0."""
    legs: list[list[tuple[int, str]]] = []
    n = len(cmds)
    for x in range(3):
        upper: list[list[int]] = []
        lower: list[list[int]] = []

        def add(lst: list[list[int]], s: int, e: int) -> None:
            if e <= s:
                return
            if lst and lst[-1][1] == s:
                lst[-1][1] = e  # the command simply stays on across the boundary
            else:
                lst.append([s, e])

        for k, c in enumerate(cmds):
            base = k * PERIOD_TICKS
            if not c.gate_enable:
                continue
            on0, on1 = c.cmp_up[x], PERIOD_TICKS - c.cmp_dn[x]
            if on0 < on1:
                add(lower, base, base + on0)
                add(upper, base + on0, base + on1)
                add(lower, base + on1, base + PERIOD_TICKS)
            else:
                add(lower, base, base + PERIOD_TICKS)
        # dead-band: a gate turns on only after its command has been on for dead_ticks
        up = [(s + dead_ticks, e) for s, e in upper if s + dead_ticks < e]
        lo = [(s + dead_ticks, e) for s, e in lower if s + dead_ticks < e]
        points = sorted({0, n * PERIOD_TICKS} | {t for iv in up + lo for t in iv})

        def state_at(t: int, up: list[tuple[int, int]] = up, lo: list[tuple[int, int]] = lo) -> str:
            if any(s <= t < e for s, e in up):
                return UPPER
            if any(s <= t < e for s, e in lo):
                return LOWER
            return NONE

        timeline: list[tuple[int, str]] = []
        for t in points:
            if t >= n * PERIOD_TICKS:
                break
            st = state_at(t)
            if not timeline or timeline[-1][1] != st:
                timeline.append((t, st))
        legs.append(timeline)
    return legs


class Reference:
    """The bench model; run() integrates a command sequence and samples the SOCs."""

    def __init__(
        self,
        prof: dict[str, dict[str, Any]],
        theta0: float,
        omega0: float,
        load_mode: int,
        load_torque: float = 0.0,
        load_k: float = 0.0,
    ):
        self.flux = FluxMap(prof)
        self.rs = float(prof["machine"]["rs_ohm"])
        self.pp = float(prof["machine"]["pole_pairs"])
        self.vdc = float(prof["inverter"]["vdc_v"])
        self.drop = float(prof["inverter"]["device_drop_v"])
        self.dead_ticks = round(float(prof["inverter"]["dead_time_s"]) / TICK)
        bw = float(prof["sensors"]["bandwidth_hz"])
        self.tau = 1.0 / (2 * math.pi * bw) if bw > 0 else 0.0
        self.J = float(prof["shaft"]["j_kgm2"]) + float(prof["shaft"]["j_load_kgm2"])
        self.B = float(prof["shaft"]["b_nms"]) + float(prof["shaft"]["b_load_nms"])
        self.load_mode = load_mode
        self.load_torque = load_torque
        self.load_k = load_k
        self.theta0 = theta0
        self.omega0 = omega0

    # ------------------------------------------------------------------ electrical model
    def band(self, gate: str) -> tuple[float, float]:
        """Terminal voltage for positive current (lo) and negative current (hi)."""
        if gate == DISCONNECTED:
            return -math.inf, math.inf
        if gate == UPPER:
            return self.vdc - self.drop, self.vdc + self.drop
        if gate == LOWER:
            return -self.drop, self.drop
        return -self.drop, self.vdc + self.drop

    @staticmethod
    def phase_currents(ia: float, ib: float) -> tuple[float, float, float]:
        return ia, -0.5 * ia + 0.5 * SQ3 * ib, -0.5 * ia - 0.5 * SQ3 * ib

    def current_slope(
        self, y: np.ndarray, u: Sequence[float]
    ) -> tuple[np.ndarray, float, tuple[float, float]]:
        """d i_ab/dt for leg voltages u; also the torque and (id, iq)."""
        ial, ibe, th, om = y[0], y[1], y[2], y[3]
        c, s = math.cos(th), math.sin(th)
        i_d, i_q = c * ial + s * ibe, -s * ial + c * ibe
        psi_d, psi_q = self.flux.psi_real(i_d, i_q)
        lin = self.flux.incremental(i_d, i_q)
        we = self.pp * om
        v_al = (2.0 / 3.0) * (u[0] - 0.5 * u[1] - 0.5 * u[2])
        v_be = (u[1] - u[2]) / SQ3
        ea, eb = v_al - self.rs * ial, v_be - self.rs * ibe  # = d psi_ab / dt
        rd, rq = c * ea + s * eb, -s * ea + c * eb
        # R(-th) dpsi_ab/dt = we*J*Psi + Linc*(d idq/dt + ... ) -> solve for d idq/dt part
        rhs = np.array([rd + we * psi_q, rq - we * psi_d])
        z = np.linalg.solve(lin, rhs) + we * np.array([-i_q, i_d])
        di = np.array([c * z[0] - s * z[1], s * z[0] + c * z[1]])
        te = 1.5 * self.pp * (psi_d * i_q - psi_q * i_d)
        return di, te, (i_d, i_q)

    def open_leg_voltage(
        self, y: np.ndarray, u: list[float], leg: int
    ) -> tuple[float, list[float]]:
        """Terminal voltage that keeps leg's current at zero (d i_x/dt is affine in u_x)."""
        u0, u1 = list(u), list(u)
        u0[leg], u1[leg] = 0.0, 100.0
        d0 = self.phase_currents(*self.current_slope(y, u0)[0])[leg]
        d1 = self.phase_currents(*self.current_slope(y, u1)[0])[leg]
        ux = -d0 * 100.0 / (d1 - d0)
        out = list(u)
        out[leg] = ux
        return ux, out

    def emf(self, theta: float, omega: float) -> tuple[float, float, float]:
        """Phase voltages with all currents zero: d/dt of the PM flux in each phase."""
        psi0 = self.flux.psi_real(0.0, 0.0)[0]
        we = self.pp * omega
        return tuple(-we * psi0 * math.sin(theta - k * 2 * math.pi / 3) for k in range(3))  # type: ignore[return-value]

    def voltages(
        self, y: np.ndarray, gates: Sequence[str], modes: Sequence[str]
    ) -> tuple[list[float], dict[str, float]]:
        info: dict[str, float] = {}
        u = [
            self.band(g)[1] if m == NEG else self.band(g)[0]
            for g, m in zip(gates, modes, strict=True)
        ]
        opened = [k for k in range(3) if modes[k] == OPEN]
        if len(opened) == 1:
            ux, u = self.open_leg_voltage(y, u, opened[0])
            info["u_open"] = ux
        return u, info

    def mechanics(self, te: float, om: float) -> float:
        if self.load_mode == 1:
            return 0.0
        tl = self.load_torque + self.load_k * om if self.load_mode == 0 else 0.0
        return (te - tl - self.B * om) / self.J

    def rhs(
        self, t: float, y: np.ndarray, gates: Sequence[str], modes: Sequence[str]
    ) -> np.ndarray:
        dy = np.zeros_like(y)
        if all(m == OPEN for m in modes):
            dy[2] = self.pp * y[3]
            dy[3] = self.mechanics(0.0, y[3])
        else:
            u, _ = self.voltages(y, gates, modes)
            di, te, _ = self.current_slope(y, u)
            dy[0], dy[1] = di
            dy[2] = self.pp * y[3]
            dy[3] = self.mechanics(te, y[3])
        if self.tau > 0:
            ia, ib, _ = self.phase_currents(y[0], y[1])
            dy[4] = (ia - y[4]) / self.tau
            dy[5] = (ib - y[5]) / self.tau
        return dy

    # ------------------------------------------------------------------ conduction modes
    def consistent(
        self, y: np.ndarray, gates: Sequence[str], modes: Sequence[str], at_zero: Sequence[int]
    ) -> bool:
        if any(g == DISCONNECTED and m != OPEN for g, m in zip(gates, modes, strict=True)):
            return False  # no current through a disconnected phase
        n_open = sum(m == OPEN for m in modes)
        if n_open == 2:
            return False
        if n_open == 3:
            e = self.emf(y[2], y[3])
            lo = max(self.band(g)[0] - e[k] for k, g in enumerate(gates))
            hi = min(self.band(g)[1] - e[k] for k, g in enumerate(gates))
            return lo <= hi
        u, info = self.voltages(y, gates, modes)
        if n_open == 1:
            leg = modes.index(OPEN)
            lo, hi = self.band(gates[leg])
            if not (lo <= info["u_open"] <= hi) or lo == hi:
                return False
        slopes = self.phase_currents(*self.current_slope(y, u)[0])
        # at a mode boundary the slope of a starting current is zero up to rounding
        for k in at_zero:
            if modes[k] == POS and slopes[k] < -1e-6:
                return False
            if modes[k] == NEG and slopes[k] > 1e-6:
                return False
        return True

    def choose_modes(
        self,
        y: np.ndarray,
        gates: Sequence[str],
        modes: Sequence[str],
        at_zero: Sequence[int],
        exclude: tuple[str, ...] | None = None,
    ) -> list[str]:
        """Tries every mode assignment of the legs at zero current; keeps the consistent one."""
        for combo in itertools.product((OPEN, POS, NEG), repeat=len(at_zero)):
            trial = list(modes)
            for k, m in zip(at_zero, combo, strict=True):
                trial[k] = m
            if exclude is not None and tuple(trial) == exclude:
                continue
            if self.consistent(y, gates, trial, at_zero):
                return trial
        raise RuntimeError(f"no consistent conduction mode for gates {gates}")

    def event_functions(
        self, gates: Sequence[str], modes: Sequence[str]
    ) -> list[Callable[[float, np.ndarray], float]]:
        events: list[Callable[[float, np.ndarray], float]] = []
        n_open = sum(m == OPEN for m in modes)
        if n_open == 3:

            def margin(t: float, y: np.ndarray, *_args: object) -> float:
                e = self.emf(y[2], y[3])
                lo = max(self.band(g)[0] - e[k] for k, g in enumerate(gates))
                hi = min(self.band(g)[1] - e[k] for k, g in enumerate(gates))
                return hi - lo

            events.append(margin)
        else:
            for k in range(3):
                lo, hi = self.band(gates[k])
                if modes[k] == OPEN:

                    def inside(t: float, y: np.ndarray, *_args: object, lo: float = lo,
                               hi: float = hi) -> float:
                        _, info = self.voltages(y, gates, modes)
                        return min(info["u_open"] - lo, hi - info["u_open"])

                    events.append(inside)
                elif hi > lo:
                    sgn = 1.0 if modes[k] == POS else -1.0

                    def current(t: float, y: np.ndarray, *_args: object, k: int = k,
                                sgn: float = sgn) -> float:
                        return sgn * self.phase_currents(y[0], y[1])[k]

                    events.append(current)
        for ev in events:
            ev.terminal = True  # type: ignore[attr-defined]
            ev.direction = -1  # type: ignore[attr-defined]
        return events

    # ------------------------------------------------------------------ run
    def run(
        self, cmds: Sequence[Command], i0: tuple[float, float] = (0.0, 0.0),
        disconnect: dict[int, int] | None = None,
    ) -> list[dict[str, np.ndarray]]:
        """Per period: true currents and sensor outputs at the SOCs (in the given order).
        ``disconnect``: {phase: period} cuts that phase off from the start of that period."""
        timelines = gate_timeline(cmds, self.dead_ticks)
        for x, period in (disconnect or {}).items():
            start = period * PERIOD_TICKS
            kept = [(t, st) for t, st in timelines[x] if t < start]
            timelines[x] = [*kept, (start, DISCONNECTED)]
        n = len(cmds)
        # all edge ticks and SOC ticks, absolute
        edges = sorted({t for tl in timelines for t, _ in tl} | {n * PERIOD_TICKS})
        socs = sorted({k * PERIOD_TICKS + s for k, c in enumerate(cmds) for s in c.soc})
        stops = sorted(set(edges) | set(socs))
        i_d0, i_q0 = i0
        c0, s0 = math.cos(self.theta0), math.sin(self.theta0)
        y = np.array([c0 * i_d0 - s0 * i_q0, s0 * i_d0 + c0 * i_q0, self.theta0, self.omega0,
                      0.0, 0.0])
        ia, ib, _ = self.phase_currents(y[0], y[1])
        y[4], y[5] = ia, ib
        pos = [0, 0, 0]
        gates = [NONE, NONE, NONE]
        modes = [POS, POS, POS]
        cur = self.phase_currents(y[0], y[1])
        modes = [POS if v > 0 else NEG if v < 0 else OPEN for v in cur]
        sampled: dict[int, tuple[float, float, float, float]] = {}
        soc_set = set(socs)
        t_tick = 0
        for stop in stops:
            # gate changes at t_tick (at 0 the initial modes are settled in any case)
            changed = t_tick == 0
            for x in range(3):
                while pos[x] < len(timelines[x]) and timelines[x][pos[x]][0] <= t_tick:
                    if gates[x] != timelines[x][pos[x]][1]:
                        changed = True
                    gates[x] = timelines[x][pos[x]][1]
                    pos[x] += 1
                if gates[x] == DISCONNECTED and modes[x] != OPEN:
                    # the cut: no current in x from now on; _settle labels the other legs
                    # by the currents that are left
                    modes[x] = OPEN
                    self._cut(y, x, modes)
            if changed:
                modes = self._settle(y, gates, modes, None)
            if t_tick in soc_set:
                cur = self.phase_currents(y[0], y[1])
                ya, yb = (y[4], y[5]) if self.tau > 0 else (cur[0], cur[1])
                sampled[t_tick] = (cur[0], cur[1], ya, yb)
            if stop == t_tick:
                continue
            y, modes = self._integrate(y, gates, modes, t_tick * TICK, stop * TICK)
            t_tick = stop
        cur = self.phase_currents(y[0], y[1])
        out: list[dict[str, np.ndarray]] = []
        for k, c in enumerate(cmds):
            vals = [sampled[k * PERIOD_TICKS + s] for s in c.soc]
            arr = np.array(vals).reshape(-1, 4)
            out.append({"ia": arr[:, 0], "ib": arr[:, 1], "ya": arr[:, 2], "yb": arr[:, 3]})
        self.final_state = y
        return out

    def _settle(
        self,
        y: np.ndarray,
        gates: Sequence[str],
        modes: list[str],
        exclude: tuple[str, ...] | None,
    ) -> list[str]:
        cur = self.phase_currents(y[0], y[1])
        at_zero = [k for k in range(3) if modes[k] == OPEN or abs(cur[k]) < 1e-9]
        fixed = [POS if cur[k] > 0 else NEG for k in range(3)]
        base = [OPEN if k in at_zero else fixed[k] for k in range(3)]
        if not at_zero:
            return base
        new = self.choose_modes(y, gates, base, at_zero, exclude)
        self._project(y, new)
        return new

    def _project(self, y: np.ndarray, modes: Sequence[str]) -> None:
        """Puts open phases exactly at zero current."""
        opened = [k for k in range(3) if modes[k] == OPEN]
        if len(opened) >= 2:
            y[0] = y[1] = 0.0
        elif len(opened) == 1:
            k = opened[0]
            ang = k * 2 * math.pi / 3
            cx, sx = math.cos(ang), math.sin(ang)
            proj = cx * y[0] + sx * y[1]
            y[0] -= proj * cx
            y[1] -= proj * sx

    def psi_ab(self, theta: float, i_al: float, i_be: float) -> np.ndarray:
        """Stator-frame flux linkage of the stator-frame current (the profile's map in dq)."""
        c, s = math.cos(theta), math.sin(theta)
        psi_d, psi_q = self.flux.psi_real(c * i_al + s * i_be, -s * i_al + c * i_be)
        return np.array([c * psi_d - s * psi_q, s * psi_d + c * psi_q])

    def _cut(self, y: np.ndarray, leg: int, modes: Sequence[str]) -> None:
        """The current of ``leg`` is cut when it is disconnected while carrying current.

        Physics: the contact that opens draws an arc, and the arc's voltage appears in the
        opened phase alone; the loop through the two phases still connected sees only the
        finite leg voltages and its resistance, so its flux linkage psi_x - psi_y cannot jump
        (a jump would need an infinite voltage around that loop). The current after the cut is
        the one with no current in ``leg`` and the loop's flux of before. Phase k's flux and
        current are a_k . psi_ab and a_k . i_ab with a_k its axis; a_x - a_y is perpendicular
        to a_leg, so the current after the cut is s * n (n perpendicular to a_leg) with
        n . psi_ab(s n) = n . psi_ab(i_ab before). The map is monotone along n (positive
        definite incremental inductance): one root, bracketed and found by Brent's method.
        With a second phase open no loop is left and every current is zero."""
        if sum(m == OPEN for m in modes) != 1:
            y[0] = y[1] = 0.0
            return
        ang = leg * 2 * math.pi / 3
        n = np.array([-math.sin(ang), math.cos(ang)])
        theta = float(y[2])
        target = float(n @ self.psi_ab(theta, float(y[0]), float(y[1])))

        def loop_flux_error(s: float) -> float:
            return float(n @ self.psi_ab(theta, s * n[0], s * n[1])) - target

        s0 = float(n @ y[:2])
        lo, hi, width = s0 - 1.0, s0 + 1.0, 1.0
        while loop_flux_error(lo) > 0.0:
            width *= 2.0
            lo = s0 - width
        while loop_flux_error(hi) < 0.0:
            width *= 2.0
            hi = s0 + width
        s = brentq(loop_flux_error, lo, hi, xtol=1e-14, rtol=4 * np.finfo(float).eps)
        y[0], y[1] = s * n[0], s * n[1]

    def _integrate(
        self, y: np.ndarray, gates: Sequence[str], modes: list[str], t0: float, t1: float
    ) -> tuple[np.ndarray, list[str]]:
        t = t0
        guard = 0
        while t < t1 - 1e-15:
            guard += 1
            if guard > 100:
                raise RuntimeError("too many conduction events in one interval")
            events = self.event_functions(gates, modes)
            atol = np.array([1e-13, 1e-13, 1e-13, 1e-12, 1e-13, 1e-13])
            sol = solve_ivp(
                self.rhs, (t, t1), y, method="DOP853", rtol=1e-11, atol=atol,
                events=events, args=(gates, modes),
            )
            if sol.status == 1:
                hit = next(k for k, te in enumerate(sol.t_events) if len(te))
                t = float(sol.t_events[hit][0])
                y = np.array(sol.y_events[hit][0])
                before = tuple(modes)
                cur = self.phase_currents(y[0], y[1])
                # the leg(s) that reached zero join the candidates
                for k in range(3):
                    if modes[k] != OPEN and abs(cur[k]) < 1e-7:
                        modes[k] = OPEN
                modes = self._settle(y, gates, modes, before)
            else:
                y = np.array(sol.y[:, -1])
                t = t1
        return y, modes
