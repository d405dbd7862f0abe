"""Bench time: how the rig lets time pass on the bench.

The owner says ``clock.advance(0.2)`` ("let 200 ms of bench time pass") or, with a plan of
its own, ``clock.grant(run_until)``, and never sleeps:

* ``WallClock`` (a real bench, a virtual one in real time): the wall clock; the link is
  pumped meanwhile and the cyclic hooks (the drive command, every 10 ms as drive.dbc asks)
  run on time.
* ``LockstepClock`` (a virtual bench in lockstep): time passes only by BENCH_STEP grants.
  Before each grant the cyclic hooks send their frames (so they reach the plant and the
  firmware before the grant's first period, per-sender order), then the clock waits for
  BENCH_PROGRESS, sends the grant's frames again when the plant waits for a grant it should
  have had (the frame was lost), and reports a stall.
* ``InprocClock`` (the in-process bench, ``rig.bench.sil``): the same frames before each grant,
  then the bench runs to the grant's end.

Every clock calls the idle hooks (child-process watch, load-bench watchdog, progress line,
run time-out) every ``IDLE_S`` of wall time while it waits, so a slow lockstep run still
refreshes the Modbus watchdog.
"""

from __future__ import annotations

import contextlib
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator

from rig.bench import sil
from rig.data import capture
from rig.link.bus import BusLink, Signals

TS = capture.TS  # PWM period of the bench (docs/interfaces.md)
CYCLE_S = 0.01  # DRIVE_CMD cycle (drive.dbc GenMsgCycleTime)
IDLE_S = 0.1
RESEND_S = 1.0  # send a grant again when the plant has waited for it this long
STALL_S = 10.0  # no progress at all for this long: the lockstep is stuck
PUMP_S = 0.02  # longest wait for a frame before the clock looks at the time again


class BenchTimeout(TimeoutError):
    """A condition was not met within its bench-time limit."""


class BenchStall(RuntimeError):
    """Lockstep: the plant stopped taking grants (or the in-process bench broke)."""


Hook = Callable[[], None]


class PlantProgress:
    """What the plant last said of its progress (BENCH_PROGRESS: the next period it
    simulates, and whether it waits for a grant).

    With ``grants_from_start`` (a lockstep run whose plant the rig started: period 0, no
    grant, seq 0) every report is checked against the grants the rig sent (``granted``): the
    plant reports the seq of the last grant it took and a period no later than that grant's
    end, and its periods never go back. A report that breaks this is not the plant's: it is
    ignored, and named to the link's ``note_foreign`` (a spoofed BENCH_PROGRESS once moved a
    scenario's load step by 999 periods and the run passed)."""

    def __init__(self, link: BusLink, *, grants_from_start: bool = False) -> None:
        self.link = link
        self.period: int | None = None
        self.waiting = False
        self.frames = 0
        self.wall = 0.0  # when the last report came (time.monotonic)
        # seq -> the end of the latest grant sent with it (None: not checked)
        self.grants: dict[int, int] | None = {0: 0} if grants_from_start else None
        self.implausible = 0
        link.on("BENCH_PROGRESS", self._heard)

    def granted(self, seq: int, run_until: int) -> None:
        """The rig sends a grant (BENCH_STEP) with this seq and end."""
        if self.grants is not None:
            self.grants[seq] = run_until

    def _plausible(self, period: int, seq: int) -> str | None:
        """Why a report cannot be the plant's, or None."""
        if self.grants is None:
            return None
        end = self.grants.get(seq)
        if end is None:
            return f"seq {seq}, of no grant the rig sent"
        if period > end:
            return f"period {period} beyond the end of grant seq {seq} ({end})"
        if self.period is not None and period < self.period:
            return f"period {period} before the plant's last report ({self.period})"
        return None

    def _heard(self, v: Signals) -> None:
        period, seq = int(v["period"]), int(v["seq"])
        why = self._plausible(period, seq)
        if why is not None:
            self.implausible += 1
            self.link.note_foreign(f"a BENCH_PROGRESS the plant cannot have sent ({why})")
            return
        self.period = period
        self.waiting = int(v["state"]) == 0
        self.frames += 1
        self.wall = time.monotonic()

    def reached(self, period: int) -> bool:
        return self.period is not None and self.period >= period


class BenchClock(ABC):
    mode = "abstract"

    def __init__(self, link: BusLink) -> None:
        self.link = link
        self._cycle: list[Hook] = []
        self._idle: list[Hook] = []
        self._last_idle = 0.0

    def on_cycle(self, fn: Hook) -> None:
        """Runs fn before each lockstep grant / every 10 ms of wall time."""
        self._cycle.append(fn)

    def on_idle(self, fn: Hook) -> None:
        """Runs fn every IDLE_S of wall time while the clock waits."""
        self._idle.append(fn)

    @contextlib.contextmanager
    def without_idle_hooks(self) -> Iterator[None]:
        """Bench time passes without the idle hooks (the safe stop must not fail on a dead
        load bench's watchdog refresh)."""
        saved, self._idle = self._idle, []
        try:
            yield
        finally:
            self._idle = saved

    def _run_cycle(self) -> None:
        for fn in list(self._cycle):
            fn()

    def idle(self, force: bool = False) -> None:
        now = time.monotonic()
        if force or now - self._last_idle >= IDLE_S:
            self._last_idle = now
            for fn in list(self._idle):
                fn()

    @abstractmethod
    def now(self) -> float:
        """Bench time, s."""

    @abstractmethod
    def advance(self, seconds: float) -> None:
        """Lets this much bench time pass."""

    def wait(self, done: Callable[[], bool], timeout_s: float, what: str,
             step_s: float = 0.005) -> float:
        """Advances in steps until done(); the bench time it took. BenchTimeout after
        timeout_s of bench time."""
        t0 = self.now()
        while not done():
            if self.now() - t0 >= timeout_s:
                raise BenchTimeout(f"{what}: not within {timeout_s:g} s of bench time")
            self.advance(step_s)
        return self.now() - t0


class WallClock(BenchClock):
    mode = "wall"

    def __init__(self, link: BusLink) -> None:
        super().__init__(link)
        self._t0 = time.monotonic()
        self._next_cycle = self._t0

    def now(self) -> float:
        return time.monotonic() - self._t0

    def advance(self, seconds: float) -> None:
        end = time.monotonic() + max(seconds, 0.0)
        while True:
            now = time.monotonic()
            if now >= self._next_cycle:
                self._run_cycle()
                # keep the cadence; after a stall start afresh instead of bursting
                self._next_cycle += CYCLE_S
                if self._next_cycle <= now:
                    self._next_cycle = now + CYCLE_S
            if now >= end:
                break
            self.link.pump(max(0.0, min(end, self._next_cycle) - now))
            self.idle()


class GrantClock(BenchClock):
    """Bench time in grants of whole periods: the frames of the cyclic hooks, then the
    bench runs to the grant's end."""

    def __init__(self, link: BusLink, *, grant_s: float) -> None:
        super().__init__(link)
        self.grant_max = max(1, round(grant_s / TS))
        self.period = 0  # the next period the bench simulates
        self.granted = 0  # the end of the last grant
        self.grants = 0

    def now(self) -> float:
        return self.period * TS

    def advance(self, seconds: float) -> None:
        target = self.period + max(1, round(seconds / TS))
        while self.period < target:
            self.grant(min(target, self.period + self.grant_max))

    def grant(self, run_until: int) -> None:
        """Runs the bench from ``period`` to ``run_until`` (exclusive)."""
        self.link.at(self.period)
        self._run_cycle()
        self.granted = run_until
        self.grants += 1
        self._run(run_until)
        self.period = run_until

    @abstractmethod
    def _run(self, run_until: int) -> None:
        """The bench runs up to run_until (the grant's frames are out)."""


class LockstepClock(GrantClock):
    mode = "lockstep"

    def __init__(self, link: BusLink, *, grant_s: float = 0.05, stall_s: float = STALL_S,
                 progress: PlantProgress | None = None) -> None:
        super().__init__(link, grant_s=grant_s)
        self.stall_s = stall_s
        self.progress = progress if progress is not None else PlantProgress(link)
        self._seq = 0
        self.resends = 0

    def sync(self, timeout_s: float = 2.0) -> int:
        """Learns the plant's period from its BENCH_PROGRESS (sent every 100 ms)."""
        deadline = time.monotonic() + timeout_s
        while self.progress.period is None:
            if time.monotonic() > deadline:
                raise BenchStall(f"{self.link.where}: no BENCH_PROGRESS from the plant within "
                                 f"{timeout_s:g} s (is plant_rt running in lockstep?)")
            self.link.pump(0.05)
            self.idle()
        self.period = self.progress.period
        return self.period

    def advance(self, seconds: float) -> None:
        self.link.pump(0.0)
        if self.progress.period is not None and self.progress.period > self.period:
            self.period = self.progress.period  # an earlier advance was aborted after its grant
        super().advance(seconds)

    def _run(self, run_until: int) -> None:
        self._seq = (self._seq + 1) % 256
        self.progress.granted(self._seq, run_until)
        self.link.send("BENCH_STEP", {"run_until": run_until, "seq": self._seq})
        progress = self.progress
        last_seen = progress.period
        last_change = last_resend = time.monotonic()
        while not progress.reached(run_until):
            self.link.pump(PUMP_S, until=lambda: progress.reached(run_until))
            self.idle()
            if progress.reached(run_until):
                return
            now = time.monotonic()
            if progress.period != last_seen:
                last_seen, last_change = progress.period, now
            if (now - last_change > RESEND_S and now - last_resend > RESEND_S
                    and (progress.waiting or progress.frames == 0)):
                # the plant waits for a grant it should have: the frame was lost (a full
                # receiver), send the grant's frames again, byte for byte
                self.link.resend()
                self.resends += 1
                last_resend = now
            if now - last_change > self.stall_s:
                raise BenchStall(f"{self.link.where}: lockstep stalled: plant at period "
                                 f"{progress.period}, granted {run_until}, no progress for "
                                 f"{self.stall_s:g} s")


class InprocClock(GrantClock):
    """Lockstep on the in-process bench: its port takes the grant's frames, then the bench
    runs (``sil.SilBench.run_until``); the idle hooks run between grants."""

    mode = "lockstep"

    def __init__(self, link: BusLink, bench: sil.SilBench, *, grant_s: float = 0.05) -> None:
        super().__init__(link, grant_s=grant_s)
        self.bench = bench

    def _run(self, run_until: int) -> None:
        try:
            self.bench.run_until(run_until)
        except sil.BenchError as exc:
            raise BenchStall(str(exc)) from exc
        self.idle()
