"""The progress line of a run on stderr: rewritten in place on a TTY, periodic otherwise."""

from __future__ import annotations

import math
import sys
import time
from typing import TextIO


class Progress:
    """``update()`` as often as convenient; output is rate-limited."""

    def __init__(
        self,
        label: str,
        total_s: float,
        stream: TextIO | None = None,
        *,
        enabled: bool = True,
        tty_interval_s: float = 0.2,
        plain_interval_s: float = 5.0,
    ) -> None:
        self.label = label
        self.total_s = total_s
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = tty_interval_s if self.tty else plain_interval_s
        self.t_start = time.monotonic()
        self._last = -math.inf
        self._width = 0
        self.err_max = 0.0
        self._latest: tuple[float, float | None, float | None] | None = None
        self._printed: tuple[float, float | None, float | None] | None = None

    def line(self, sim_s: float, speed_rpm: float | None, err_deg: float | None) -> str:
        wall = time.monotonic() - self.t_start
        if err_deg is not None and math.isfinite(err_deg):
            self.err_max = max(self.err_max, abs(err_deg))
        parts = [f"{self.label}: t={sim_s:7.3f}/{self.total_s:g} s"]
        if speed_rpm is not None and math.isfinite(speed_rpm):
            parts.append(f"speed {speed_rpm:8.1f} r/min")
        if err_deg is not None and math.isfinite(err_deg):
            parts.append(f"err {err_deg:+6.2f}° (max {self.err_max:.2f}°)")
        if wall > 0:
            parts.append(f"{sim_s / wall:5.2f}x real time")
        return "  ".join(parts)

    def update(
        self,
        sim_s: float,
        speed_rpm: float | None = None,
        err_deg: float | None = None,
        *,
        force: bool = False,
    ) -> None:
        if err_deg is not None and math.isfinite(err_deg):
            self.err_max = max(self.err_max, abs(err_deg))
        self._latest = (sim_s, speed_rpm, err_deg)
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < self.interval:
            return
        self._last = now
        self._printed = self._latest
        text = self.line(sim_s, speed_rpm, err_deg)
        if self.tty:
            pad = max(0, self._width - len(text))
            self.stream.write("\r" + text + " " * pad)
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def finish(self, message: str = "") -> None:
        if not self.enabled:
            return
        if not self.tty and self._latest is not None and self._latest != self._printed:
            self.update(*self._latest, force=True)  # the final state, once
        if self.tty and self._width:
            self.stream.write("\r" + " " * self._width + "\r")
        if message:
            self.stream.write(message + "\n")
        self.stream.flush()
