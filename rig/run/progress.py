"""One progress display for everything that runs scenarios: a run, a suite (in one process or
on worker processes), a sweep, ``rig baseline record``, a mutation campaign.

On a terminal it is one line, redrawn in place with rich (imported on its first drawing,
after a run's loop has started, so it costs nothing before the first grant)::

    paper 12/69 scenarios ━━━━━━━╸━━━━━━━━━━━━  elapsed 0:42  ETA 3:20  fig09_load_step:
    t=1.200/2.0 s, 3.10x real time, 980 r/min

k of N items done, the elapsed time, the time left (from the work done so far: the items'
simulated seconds where they are known, so a long scenario counts for what it costs; "ETA
--" until anything is done), and the item running now: its simulated time, its speed against
real time and the shaft's speed. Lines said meanwhile (``say``: a scenario's verdict as it
ends) go above it. Where stderr is not a terminal (CI logs, pipes) the display is quiet and
only the said lines are printed.

The API::

    with Display("paper", n, work=[durations], unit="scenario") as display:
        for sc in scenarios:
            with item(sc.name, sc.duration):   # the run reports its simulated time to it
                ...
            display.done(sc.name, passed)

``item()`` reports into the display that is active in this process, or shows one of its own
for a lone run. A campaign whose items run elsewhere (worker processes, a Dask cluster, a
rebuilt tree) calls ``start`` and ``done`` only.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Iterator, Sequence
from typing import Any, TextIO

REDRAW_S = 0.2  # at most this often on a terminal
_ACTIVE: list[Display] = []  # the displays open in this process, innermost last


def clock(seconds: float) -> str:
    """``0:42``, ``1:03:20``."""
    s = max(0, round(seconds))
    h, rest = divmod(s, 3600)
    m, sec = divmod(rest, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


class Display:
    """k of N items, elapsed, ETA, the current item's simulated time and speed."""

    def __init__(self, label: str, total: int, *, work: Sequence[float] | None = None,
                 unit: str = "scenario", enabled: bool = True, stream: TextIO | None = None,
                 terminal: bool | None = None) -> None:
        self.label, self.total, self.unit = label, max(0, total), unit
        self.work = [max(float(w), 0.0) for w in work] if work is not None else None
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.terminal = terminal if terminal is not None else bool(
            getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.monotonic()
        self.done_items = 0
        self.failed = 0
        self.work_done = 0.0
        self.current: str | None = None
        self.current_work = 0.0
        self.sim_total: float | None = None
        self.sim_s = 0.0
        self.item_t0 = self.t0
        self.rpm: float | None = None
        self.err_deg: float | None = None
        self._last = -math.inf
        self._live: Any = None  # the rich Progress, once drawn
        self._task: Any = None

    # -- what the caller tells ----------------------------------------------------------
    def start(self, name: str, sim_total_s: float | None = None) -> None:
        """An item starts (its simulated length, when it has one)."""
        self.current, self.sim_total, self.sim_s = name, sim_total_s, 0.0
        self.rpm = self.err_deg = None
        self.item_t0 = time.monotonic()
        self.current_work = self._weight(self.done_items, sim_total_s)
        self._draw(force=True)

    def at(self, sim_s: float, speed_rpm: float | None = None, err_deg: float | None = None,
           *, force: bool = False) -> None:
        """Where the current item is: simulated seconds, shaft speed, position error."""
        self.sim_s = sim_s
        if speed_rpm is not None and math.isfinite(speed_rpm):
            self.rpm = speed_rpm
        if err_deg is not None and math.isfinite(err_deg):
            self.err_deg = err_deg
        self._draw(force=force)

    def done(self, name: str = "", passed: bool | None = None, line: str = "") -> None:
        """An item ended (``line``: said above the display)."""
        self.work_done += self.current_work if self.current is not None \
            else self._weight(self.done_items, None)
        self.done_items += 1
        self.failed += passed is False
        self.current, self.sim_total = None, None
        if line:
            self.say(line)
        self._draw(force=True)

    def say(self, text: str) -> None:
        """A line above the display (printed as it is where there is no display)."""
        if not self.enabled:
            return
        if self._live is not None:
            self._live.console.print(text, markup=False, highlight=False, soft_wrap=True)
        else:
            self.stream.write(text + "\n")
            self.stream.flush()

    def close(self) -> None:
        if self._live is not None:
            self._live.stop()
            self._live = None

    def __enter__(self) -> Display:
        _ACTIVE.append(self)
        return self

    def __exit__(self, *exc: object) -> None:
        if self in _ACTIVE:
            _ACTIVE.remove(self)
        self.close()

    # -- what it shows ------------------------------------------------------------------
    def _weight(self, index: int, sim_total: float | None) -> float:
        if self.work is not None and index < len(self.work):
            return self.work[index] or 1e-9
        return 1.0 if self.work is None else (sim_total or 1e-9)

    def fraction(self) -> float:
        """The share of the work done, the current item's part included."""
        if self.work is not None:
            total = sum(self.work) or 1.0
        else:
            total = float(self.total or 1)
        now = 0.0
        if self.current is not None and self.sim_total:
            now = self.current_work * min(1.0, self.sim_s / self.sim_total)
        return min(1.0, (self.work_done + now) / total)

    def eta_s(self) -> float | None:
        """Seconds left at the pace so far; None until there is a pace to go by."""
        f = self.fraction()
        elapsed = time.monotonic() - self.t0
        if f <= 0.0 or elapsed <= 0.0:
            return None
        return elapsed * (1.0 - f) / f

    def text(self) -> str:
        """The display's line (without the bar)."""
        elapsed = time.monotonic() - self.t0
        eta = self.eta_s()
        parts = [f"elapsed {clock(elapsed)}", f"ETA {clock(eta) if eta is not None else '--'}"]
        if self.failed:
            parts.append(f"{self.failed} not passed")
        if self.current is not None:
            now = [f"t={self.sim_s:.3f}/{self.sim_total:g} s" if self.sim_total
                   else f"t={self.sim_s:.3f} s"]
            wall = time.monotonic() - self.item_t0
            if wall > 0 and self.sim_s > 0:
                now.append(f"{self.sim_s / wall:.2f}x real time")
            if self.rpm is not None:
                now.append(f"{self.rpm:.0f} r/min")
            if self.err_deg is not None:
                now.append(f"err {self.err_deg:+.2f}°")
            parts.append(f"{self.current}: {', '.join(now)}")
        return "  ".join(parts)

    def head(self) -> str:
        if self.total <= 1 and self.current is not None:
            return self.label
        return f"{self.label} {self.done_items}/{self.total} {self.unit}s"

    def _draw(self, force: bool = False) -> None:
        if not (self.enabled and self.terminal):
            return  # quiet where nobody watches
        now = time.monotonic()
        if not force and now - self._last < REDRAW_S:
            return
        self._last = now
        if self._live is None:
            self._start_live()
        self._live.update(self._task, completed=self.fraction(), description=self.head(),
                          tail=self.text())
        self._live.refresh()

    def _start_live(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn

        self._live = Progress(TextColumn("{task.description}"), BarColumn(bar_width=24),
                              TextColumn("{task.fields[tail]}"),
                              console=Console(file=self.stream, force_terminal=True),
                              auto_refresh=False, transient=True, redirect_stdout=False,
                              redirect_stderr=False)
        self._task = self._live.add_task(self.head(), total=1.0, tail="")
        self._live.start()


def active() -> Display | None:
    """The display open in this process (innermost), if any."""
    return _ACTIVE[-1] if _ACTIVE else None


@contextlib.contextmanager
def item(name: str, sim_total_s: float | None = None, *, enabled: bool = True
         ) -> Iterator[Display]:
    """One run as an item: of the active display (a suite's), else of a display of its own
    (shown when ``enabled`` and on a terminal)."""
    outer = active()
    if outer is not None:
        outer.start(name, sim_total_s)
        yield outer
        return
    with Display(name, 1, work=[sim_total_s or 1.0], enabled=enabled) as own:
        own.start(name, sim_total_s)
        yield own
