"""Ceilings for the tests' waits, from one place.

A test waits for an event (a ready file, a frame, a reply, a process's exit), never for a
time that assumes the machine's speed. Each wait has a ceiling that only a broken program
reaches: generous (tens of seconds for what normally takes well under one), so that a test's
verdict is the same on a loaded, shared or emulated machine. HIL_TEST_TIMEOUT_SCALE
multiplies every ceiling (e.g. 3 inside a TCG VM); claims about speed are benchmarks
(`rig bench`), not tests.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable


def _scale() -> float:
    raw = os.environ.get("HIL_TEST_TIMEOUT_SCALE", "1")
    try:
        value = float(raw)
    except ValueError:
        raise SystemExit(f"HIL_TEST_TIMEOUT_SCALE={raw!r}: not a number") from None
    if not 0.1 <= value <= 100:
        raise SystemExit(f"HIL_TEST_TIMEOUT_SCALE={raw!r}: 0.1 … 100")
    return value


SCALE = _scale()

# What normally takes well under a second (a reply, a frame, a program getting ready).
EVENT_S = 60.0 * SCALE
# A whole program run or a short scenario (normally seconds).
RUN_S = 300.0 * SCALE


def ceiling(seconds: float) -> float:
    """A ceiling of `seconds` scaled by HIL_TEST_TIMEOUT_SCALE."""
    return seconds * SCALE


def wait_until(cond: Callable[[], bool], what: str, timeout_s: float = EVENT_S,
               poll_s: float = 0.005) -> None:
    """Polls `cond` until it holds; AssertionError naming `what` after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s:.0f} s")
        time.sleep(poll_s)
