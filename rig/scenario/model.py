"""A scenario as the rig runs it: the fidelity profile (plus overrides), the drive modes, a
speed profile (a sequence of segments), a load profile (events at absolute times), faults
(``rig.scenario.faults``), the initial rotor state, the duration and the pass criteria; and what
the profiles expand to (speed commands, the ramped reference, load commands, breakpoints).
Suites list scenarios and compare runs.

Times are simulated seconds from the start of PWM period 0 and are rounded to the PWM
period (100 µs) when the scenario is planned.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from rig.scenario import faults
from rig.scenario.checks import check_overrides, check_stuck_codes
from rig.scenario.schema import Checker, Issue, ScenarioError, read_text

PROFILES = ("ideal", "paper", "harsh")
def side_of(comparison: str) -> str:
    """Which way a criterion's value improves, from its comparison: lower for < and <=,
    higher for > and >=, either (any move counts) for == and reported values."""
    if comparison in ("<", "<="):
        return "lower"
    if comparison in (">", ">="):
        return "higher"
    return "either"


# the plant profile field that seeds its noise (plant_rt/profiles/*.toml, [sensors] seed)
SEED_KEY = "sensors.seed"
# the start-angle dither per seed (Scenario.with_seed): far below anything a drive could
# care about, enough to show how a deterministic closed loop spreads
SEED_THETA_DITHER_DEG = 0.001
# seeds 1..8 (the baselines') dither by (seed - 1) steps; every other seed by a step count
# spread over the same range, so no seed starts further away than the baselines saw
DITHER_SEEDS = 8
_GOLDEN = (5 ** 0.5 - 1) / 2


def dither_deg(seed: int) -> float:
    """The start angle's dither of a run at ``seed``: (seed - 1) * 0.001 deg for seeds 1-8,
    and within the same 0 .. 0.008 deg for any other (the golden-ratio sequence)."""
    if 1 <= seed <= DITHER_SEEDS:
        return (seed - 1) * SEED_THETA_DITHER_DEG
    return ((seed * _GOLDEN) % 1.0) * DITHER_SEEDS * SEED_THETA_DITHER_DEG


@dataclass(frozen=True)
class SpeedSegment:
    kind: str
    duration: float
    to: float | None = None
    peak: float | None = None
    rise: float = 0.0
    hold: float = 0.0
    fall: float = 0.0
    dwell: float = 0.0
    repeat: int = 1


@dataclass(frozen=True)
class SpeedCommand:
    """At time ``t`` command speed_ref ``target`` with acceleration limit ``accel`` (r/min/s)."""

    t: float
    target: float
    accel: float


@dataclass(frozen=True)
class LoadEvent:
    at: float
    kind: str  # step | ramp | off | speed_hold
    torque: float = 0.0
    duration: float = 0.0
    speed: float = 0.0
    k_speed: float = 0.0


@dataclass(frozen=True)
class LoadCommand:
    """At time ``t`` set the load machine (mode name as in the DBC, lower case)."""

    t: float
    mode: str
    torque: float = 0.0
    speed: float = 0.0
    k_speed: float = 0.0


@dataclass(frozen=True)
class Criterion:
    name: str
    metric: str
    window: tuple[float, float]
    limit: float
    comparison: str = "<="
    params: Mapping[str, float] = field(default_factory=dict)
    # fidelity profiles the criterion applies on (empty: every profile)
    profiles: tuple[str, ...] = ()
    # known failure: the reason with the measured value; reported XFAIL (XPASS if it passes)
    xfail: str = ""
    # which way the value improves (lower, higher, either) for the baseline; "" derives it
    # from the comparison (side_of)
    better: str = ""

    def side(self) -> str:
        return self.better or side_of(self.comparison)

    def applies_to(self, profile: str) -> bool:
        return not self.profiles or profile in self.profiles


@dataclass(frozen=True)
class Scenario:
    name: str
    file: Path
    description: str
    profile: str
    duration: float
    figure: str = ""
    tags: tuple[str, ...] = ()
    overrides: Mapping[str, float | int | str | bool] = field(default_factory=dict)
    firmware: Mapping[str, float | int | str | bool] = field(default_factory=dict)
    ctrl_mode: str = "speed"
    fw_mode: str = "realtime"
    enable_at: float = 0.0
    iq_ref: float = 0.0
    i_max: float = 3.0
    speed_max: float = 3300.0
    step_accel: float = 0.0  # 0: the DBC maximum of accel_max
    initial_theta_deg: float = 0.0
    initial_speed_rpm: float = 0.0
    speed: tuple[SpeedSegment, ...] = ()
    load: tuple[LoadEvent, ...] = ()
    faults: tuple[faults.Fault, ...] = ()
    criteria: tuple[Criterion, ...] = ()
    grant_max_s: float = 0.1
    timeout_s: float = 0.0  # 0: derived from the duration
    ready_timeout_s: float = 10.0
    realtime_ok: bool = True
    # decide the criteria over these plant noise seeds (worst case; rig.run.multi_seed)
    seeds: tuple[int, ...] = ()
    # added to the start angle by a run's seed (with_seed): not part of the scenario
    theta_dither_deg: float = 0.0

    @property
    def start_theta_deg(self) -> float:
        """The rotor angle the plant starts from: the scenario's plus the seed's dither."""
        return self.initial_theta_deg + self.theta_dither_deg

    def with_profile(self, profile: str) -> Scenario:
        """The same scenario on another fidelity profile, named ``<name>@<profile>``; only
        the criteria that apply on that profile are kept. Its overrides and stuck ADC codes
        are checked on that profile (``ScenarioError``)."""
        if profile not in PROFILES:
            import difflib

            near = difflib.get_close_matches(profile, PROFILES, n=1)
            raise ScenarioError([Issue(str(self.file), None, f"{self.name}@{profile}",
                                       f"unknown profile {profile!r} (one of: "
                                       f"{', '.join(PROFILES)})"
                                       + (f"; did you mean {self.name}@{near[0]}?" if near
                                          else ""))])
        if self.overrides and profile != self.profile:
            c = Checker(self.file, self._text())
            check_overrides(c, profile, self.overrides)
            if c.issues:
                raise ScenarioError(c.issues)
        if self.faults and profile != self.profile:
            c = Checker(self.file, self._text())
            check_stuck_codes(c, profile, self.overrides, self.faults)
            if c.issues:
                raise ScenarioError(c.issues)
        base = self.name.split("@", 1)[0]
        crits = tuple(c for c in self.criteria if c.applies_to(profile))
        return replace(self, name=f"{base}@{profile}", profile=profile, criteria=crits)

    def _text(self) -> str:
        """The scenario file's text, for the lines of errors ("" when it cannot be read)."""
        try:
            return read_text(self.file)
        except OSError:
            return ""

    def with_seed(self, seed: int) -> Scenario:
        """The same scenario under other immaterial conditions: the plant's noise drawn from
        another seed (the profile field ``SEED_KEY``) and the start angle moved by
        ``dither_deg(seed)``, a few thousandths of a degree. The dither gives the noise-free
        ``ideal`` profile a spread too: its closed loop is deterministic but not insensitive
        (a start 0.001 deg away moved its Table 2 cell at 1000 r/min from 0.0046 to 0.0033
        deg and its speed excursion from 0.16 to 0.08 r/min, as any change of rounding
        would). The name is unchanged: the seed is a dimension of a run, not another
        scenario. A scenario decided over its own k seeds moves them as a block: at seed s
        it runs seeds (s - 1) k + 1 .. s k (seed 1: its own)."""
        if self.seeds:
            k = len(self.seeds)
            shift = (int(seed) - 1) * k
            return replace(self, seeds=tuple(x + shift for x in self.seeds))
        return replace(self, overrides={**self.overrides, SEED_KEY: int(seed)},
                       theta_dither_deg=dither_deg(int(seed)))

    @property
    def periods(self) -> int:
        """The PWM periods it runs: its duration on the bench's time base."""
        return round(self.duration / faults.TS)

    @property
    def seed(self) -> int | None:
        """The noise seed the scenario sets (None: the profile's own)."""
        value = self.overrides.get(SEED_KEY)
        return int(value) if isinstance(value, int | float) else None

    def on_own_profile(self) -> Scenario:
        """Only the criteria that apply on the scenario's own profile."""
        if all(cr.applies_to(self.profile) for cr in self.criteria):
            return self
        return replace(self, criteria=tuple(cr for cr in self.criteria
                                            if cr.applies_to(self.profile)))

    # -- derived profiles ------------------------------------------------------------
    def speed_commands(self, step_accel: float) -> list[SpeedCommand]:
        """The commands the speed profile expands to (targets and acceleration limits)."""
        out: list[SpeedCommand] = []
        t, cur = 0.0, self.initial_speed_rpm
        accel_step = self.step_accel or step_accel

        def ramp(to: float, dur: float) -> None:
            nonlocal t, cur
            if dur <= 0:
                out.append(SpeedCommand(t, to, accel_step))
            else:
                out.append(SpeedCommand(t, to, abs(to - cur) / dur if to != cur else accel_step))
            cur = to
            t += max(dur, 0.0)

        for seg in self.speed:
            if seg.kind == "hold":
                t += seg.duration
            elif seg.kind == "step":
                assert seg.to is not None
                out.append(SpeedCommand(t, seg.to, accel_step))
                cur = seg.to
                t += seg.duration
            elif seg.kind in ("ramp", "reversal"):
                assert seg.to is not None
                ramp(seg.to, seg.duration)
            elif seg.kind in ("trapezoid", "triangle"):
                assert seg.peak is not None
                base = cur
                for _ in range(seg.repeat):
                    ramp(seg.peak, seg.rise)
                    t += seg.hold
                    ramp(base, seg.fall)
                    t += seg.dwell
        if self.initial_speed_rpm and (not out or out[0].t > 0.0):
            # a shaft that turns at the start: the drive is told to hold that speed (a first
            # hold segment commands nothing, and the reference the rig expects is this speed)
            out.insert(0, SpeedCommand(0.0, self.initial_speed_rpm, accel_step))
        return out

    def speed_reference(self, t: npt.ArrayLike, step_accel: float) -> npt.NDArray[np.float64]:
        """The ramped speed reference the firmware follows (rate limiter of the commands)."""
        knots_t, knots_v = [0.0], [self.initial_speed_rpm]
        v = self.initial_speed_rpm
        cmds = self.speed_commands(step_accel)
        for k, cmd in enumerate(cmds):
            # the value reached at cmd.t under the previous command is the last knot
            t_next = cmds[k + 1].t if k + 1 < len(cmds) else math.inf
            if cmd.t > knots_t[-1]:
                knots_t.append(cmd.t)
                knots_v.append(v)
            if cmd.accel <= 0 or cmd.target == v:
                continue
            t_reach = cmd.t + abs(cmd.target - v) / cmd.accel
            if t_reach <= t_next:
                knots_t.append(t_reach)
                knots_v.append(cmd.target)
                v = cmd.target
            else:
                v = v + math.copysign(cmd.accel * (t_next - cmd.t), cmd.target - v)
                knots_t.append(t_next)
                knots_v.append(v)
        tt = np.asarray(t, dtype=np.float64)
        return np.interp(tt, np.asarray(knots_t), np.asarray(knots_v))

    def load_commands(self, resolution_s: float = 1e-3) -> list[LoadCommand]:
        """Load machine commands; a torque ramp becomes steps of ``resolution_s``."""
        out: list[LoadCommand] = [LoadCommand(0.0, "torque")]
        torque = 0.0
        k_speed = 0.0
        for ev in sorted(self.load, key=lambda e: e.at):
            if ev.kind == "step":
                k_speed = ev.k_speed
                out.append(LoadCommand(ev.at, "torque", ev.torque, 0.0, k_speed))
                torque = ev.torque
            elif ev.kind == "ramp":
                k_speed = ev.k_speed
                n = max(1, round(ev.duration / resolution_s))
                for j in range(n):
                    frac = (j + 0.5) / n
                    out.append(
                        LoadCommand(ev.at + j * ev.duration / n, "torque",
                                    torque + (ev.torque - torque) * frac, 0.0, k_speed)
                    )
                out.append(LoadCommand(ev.at + ev.duration, "torque", ev.torque, 0.0, k_speed))
                torque = ev.torque
            elif ev.kind == "off":
                out.append(LoadCommand(ev.at, "off"))
            elif ev.kind == "speed_hold":
                out.append(LoadCommand(ev.at, "speed_hold", 0.0, ev.speed, 0.0))
        return out

    def breakpoints(self, step_accel: float) -> list[float]:
        """Times at which a command changes (grants end exactly there)."""
        ts = {0.0, self.enable_at}
        ts.update(c.t for c in self.speed_commands(step_accel))
        ts.update(c.t for c in self.load_commands())
        for f in self.faults:
            ts.add(f.at)
            if f.duration is not None:
                ts.add(f.at + f.duration)
        return sorted(t for t in ts if 0.0 <= t < self.duration)


@dataclass(frozen=True)
class Comparison:
    """A suite-level criterion between two runs of the suite: the value of the criterion
    ``criterion`` in run ``a`` must stand in ``relation`` to its value in run ``b`` (for
    example Fig. 9: the real-time MTPA drops less speed than the conventional one)."""

    name: str
    criterion: str
    a: str
    b: str
    relation: str = "<"
    xfail: str = ""


@dataclass(frozen=True)
class Suite:
    name: str
    file: Path
    description: str
    scenarios: tuple[Scenario, ...]
    comparisons: tuple[Comparison, ...] = ()
