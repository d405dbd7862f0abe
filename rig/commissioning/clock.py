"""Bench time: how a commissioning script lets time pass on the bench.

A script says ``clock.advance(0.2)`` ("let 200 ms of bench time pass") and never sleeps:

* ``WallClock`` (a real bench, or a virtual one in real time): the wall clock; the link is
  pumped meanwhile and the cyclic hooks (the drive command, every 10 ms as drive.dbc asks)
  run on time.
* ``LockstepClock`` (a virtual bench in lockstep): time passes only by BENCH_STEP grants
  (rig.runner's pacing). Before each grant the cyclic hooks run (so the DRIVE_CMD of that
  grant reaches the firmware before its first period, per-sender order), then the clock
  waits for BENCH_PROGRESS, re-sends a grant the plant did not take, and reports a stall.

Both call the idle hooks (load-bench watchdog, child-process watch) every ``IDLE_S`` of wall
time while waiting, so a slow lockstep run still refreshes the Modbus watchdog.
"""

from __future__ import annotations

import contextlib
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator

from rig import protocols
from rig.commissioning.link import CanLink, Signals

TS = protocols.timebase().ts  # PWM period of the bench (docs/interfaces.md)
CYCLE_S = 0.01  # DRIVE_CMD cycle (drive.dbc GenMsgCycleTime)
IDLE_S = 0.1
RESEND_S = 1.0


class BenchTimeout(TimeoutError):
    """A condition was not met within its bench-time limit."""


class BenchStall(RuntimeError):
    """Lockstep: the plant stopped taking grants."""


Hook = Callable[[], None]


class BenchClock(ABC):
    mode = "abstract"

    def __init__(self, link: CanLink) -> None:
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

    def __init__(self, link: CanLink) -> None:
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


class LockstepClock(BenchClock):
    mode = "lockstep"

    def __init__(self, link: CanLink, *, grant_s: float = 0.05, stall_s: float = 10.0) -> None:
        super().__init__(link)
        self.grant_max = max(1, round(grant_s / TS))
        self.stall_s = stall_s
        self.period = 0  # next period the plant simulates
        self.progress: int | None = None
        self.waiting = False
        self._seq = 0
        self.grants = 0
        self.resends = 0
        link.on("BENCH_PROGRESS", self._progress)

    def _progress(self, v: Signals) -> None:
        p = int(v["period"])
        self.progress = p if self.progress is None else max(self.progress, p)
        self.waiting = int(v["state"]) == 0

    def sync(self, timeout_s: float = 2.0) -> int:
        """Learns the plant's period from its BENCH_PROGRESS (sent every 100 ms)."""
        deadline = time.monotonic() + timeout_s
        while self.progress is None:
            if time.monotonic() > deadline:
                raise BenchStall(f"{self.link.where}: no BENCH_PROGRESS from the plant within "
                                 f"{timeout_s:g} s (is plant_rt running in lockstep?)")
            self.link.pump(0.05)
            self.idle()
        self.period = self.progress
        return self.period

    def now(self) -> float:
        return self.period * TS

    def advance(self, seconds: float) -> None:
        self.link.pump(0.0)
        if self.progress is not None and self.progress > self.period:
            self.period = self.progress  # an earlier advance was aborted after its grant
        target = self.period + max(1, round(seconds / TS))
        while self.period < target:
            until = min(target, self.period + self.grant_max)
            self._run_cycle()
            self._seq = (self._seq + 1) % 256
            self.link.send("BENCH_STEP", {"run_until": until, "seq": self._seq})
            self.grants += 1
            self._await(until)
            self.period = until

    def _await(self, until: int) -> None:
        last_seen = self.progress
        last_change = last_resend = time.monotonic()
        while self.progress is None or self.progress < until:
            self.link.pump(0.02)
            self.idle()
            now = time.monotonic()
            if self.progress != last_seen:
                last_seen, last_change = self.progress, now
            if now - last_change > RESEND_S and now - last_resend > RESEND_S:
                # the grant frame was lost (a full receiver): send it again, same seq
                self._run_cycle()
                self.link.send("BENCH_STEP", {"run_until": until, "seq": self._seq})
                self.resends += 1
                last_resend = now
            if now - last_change > self.stall_s:
                raise BenchStall(f"{self.link.where}: lockstep stalled at period "
                                 f"{self.progress} (granted {until}), no progress for "
                                 f"{self.stall_s:g} s")
