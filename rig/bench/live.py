"""The virtual bench free-running on the wall clock (``rig up``), the way a real bench is:
plant_rt and fw_host paced in real time (``--realtime``: SCHED_FIFO where the kernel grants
it), the Modbus load bench, on a channel of the bench's own unless one is named.

Nothing paces it: the drive sends its telemetry at its own rate and takes commands at any
moment, so every real-bench command (``rig console``, ``rig param``, ``rig commission``,
``rig drive``) runs against it through the bench file it writes (``bench.toml``: a real
bench's description, no ``[virtual]`` section, ``clock.mode = "wall"``).

Pacing (``pace``): ``realtime`` (the default) is plant_rt's own real-time mode: a period
that ends late slips the grid and the firmware may lose ADC frames, as a real drive whose
interrupt is late would. ``wall`` is for a machine that cannot hold 10 kHz real time (a
loaded or virtual machine): the programs run in lockstep and this process grants them bench
time as the wall clock passes (``GRANT_S`` at a time), so nothing is lost; when the machine
falls behind by more than ``MAX_LAG_S`` the bench time pauses (the grid slips, counted as
slipped periods) instead of racing to catch up. To every client the bench is free-running in
both: telemetry at its own rate, commands at any moment, wall-clock time-outs.

Its health comes from the plant's BENCH_COUNTERS and BENCH_PROGRESS (every 100 ms): overruns
(periods that ended after the next one's start), periods slipped (the grid moved on by
whole periods: wall time minus simulated time, in periods, estimated from BENCH_PROGRESS;
plant_rt's exit counters give the exact figure), late commands (periods that started
without their VIO_PWM frame) and frames dropped (the plant's transmit drops, and this
monitor's own receive overflows). In real time the monitor is on the channel only while it
takes a sample (a health line), as a Python node that falls behind costs the plant waits.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import tomlkit

from rig import bus as rigbus
from rig import outputs, protocols
from rig.bench import virtual
from rig.bench.description import BenchDescription
from rig.data import capture
from rig.link.bus import BusLink, ForeignNodes, Signals
from rig.link.clock import LockstepClock
from rig.supervisor import ChildFailed, StopReport
from rig.supervisor import tail as supervisor_tail

OWN = "up"  # the bench's own unixcan channel: up-<pid>
PACES = ("realtime", "wall")
GRANT_S = 0.01  # wall pacing: bench time granted at a time (a command acts within it)
WALL_PRIORITY = 10  # wall pacing: SCHED_FIFO of the bench's processes (0: none)
SAMPLE_CEILING_S = 1.0  # real time: a health sample's ceiling (the frames come every 100 ms)
MAX_LAG_S = 0.02  # wall pacing: behind the wall clock by more, the bench time pauses (a
# bench that raced to catch up would run ahead of its clients: a master starved for a moment
# would see its command time-out pass faster than on the wall clock)
BENCH_FILE = "bench.toml"
TS = capture.TS  # PWM period (docs/interfaces.md)

Log = Callable[[str], None]


class BenchRefused(RuntimeError):
    """The channel is not the bench's to take (another run of the rig holds it, or a node
    sends there): nothing was started."""


@dataclass(frozen=True)
class Address:
    """How to reach the running bench."""

    transport: str
    channel: str
    console: str  # fw_host's pseudo-terminal (a link to /dev/pts/N)
    modbus_host: str
    modbus_port: int
    bench_file: Path


@dataclass(frozen=True)
class Health:
    """The bench's health since it started."""

    uptime_s: float
    period: int | None  # the plant's next period (None: no BENCH_PROGRESS yet)
    overruns: int
    slipped: int | None  # ≈ periods the grid slipped (None: too early to tell)
    late_cmds: int
    plant_tx_drops: int
    monitor_rx_drops: int
    drive_state: str
    slipped_exact: bool = False  # counted by the pacer (wall), else estimated (realtime)

    def line(self) -> str:
        slipped = ("?" if self.slipped is None
                   else f"{'' if self.slipped_exact else '≈'}{self.slipped}")
        if self.slipped is not None and self.uptime_s > 0.0:  # the rate real time is judged by
            slipped += f" ({self.slipped * 60.0 / self.uptime_s:.0f}/min)"
        period = "?" if self.period is None else str(self.period)
        return (f"up {self.uptime_s:6.0f} s  period {period}"
                f"  drive {self.drive_state}  overruns {self.overruns}  slipped {slipped}"
                f"  late commands {self.late_cmds}  frames dropped "
                f"{self.plant_tx_drops + self.monitor_rx_drops}")


def scheduling(pid: int) -> str:
    """The scheduling policy the kernel gives ``pid`` (what plant_rt / fw_host were granted)."""
    try:
        policy = os.sched_getscheduler(pid)
        prio = os.sched_getparam(pid).sched_priority
    except OSError as exc:
        return f"unknown ({exc.strerror})"
    names = {os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_RR: "SCHED_RR", os.SCHED_OTHER: "SCHED_OTHER"}
    name = names.get(policy, str(policy))
    return f"{name} {prio}" if policy in (os.SCHED_FIFO, os.SCHED_RR) else name


def make_fifo(pid: int, priority: int) -> bool:
    """Every thread of ``pid`` at SCHED_FIFO ``priority``; False where the kernel refuses."""
    try:
        tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return False
    ok = True
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        except OSError:
            ok = False
    return ok


class LiveBench:
    """Brings the free-running virtual bench up (``start``), watches it (``health``) and
    takes it down with everything it made (``stop``)."""

    def __init__(self, desc: BenchDescription, *, folder: Path | None = None,
                 rt_priority: int | None = None, pace: str = "realtime",
                 log: Log | None = None, bitrate: int | None = None) -> None:
        if desc.virtual is None:
            raise ValueError(f"{desc.name}: not a virtual bench (no [virtual] section)")
        self.desc = desc
        self.log: Log = log or (lambda _m: None)
        self._own_folder = folder is None
        self.dir = Path(folder) if folder is not None else Path(
            tempfile.mkdtemp(prefix=f"hil-up-{os.getpid()}-"))
        if pace not in PACES:
            raise ValueError(f"pace {pace!r}: one of {', '.join(PACES)}")
        self.pace = pace
        self.rt_priority = rt_priority
        self.bitrate = bitrate  # a bit clock on the channel (rig.bus.arbiter), or None
        self.bit_clock_summary = ""  # its last line, once stopped
        # (in real time the programs take it themselves; paced by the wall clock the pacer
        # gives it to every process of the bench once they are up)
        prio = () if rt_priority is None or pace != "realtime" else (
            "--rt-priority", str(rt_priority))
        self.programs = replace(virtual.from_description(desc), lockstep=pace == "wall",
                                extra_plant_args=prio, extra_fw_args=prio)
        self.clock: LockstepClock | None = None
        self._grid0 = 0.0  # wall pacing: when the bench's period 0 of the grid was due
        self._period0 = 0
        self.slipped_wall = 0  # wall pacing: periods the grid slipped
        self.bench: virtual.VirtualBench | None = None
        self.link: BusLink | None = None
        self.address: Address | None = None
        self._claim: rigbus.ChannelClaim | None = None
        self._channel = ""
        self._t0 = time.monotonic()
        self._progress0: tuple[float, int] | None = None  # (wall, period) of the first report
        self._progress: tuple[float, int] | None = None
        self._transport = ""
        self._sampled: dict[str, Signals] = {}  # real time: the last health sample's frames
        self._sample_overflows = 0

    # -- up -----------------------------------------------------------------------------
    def start(self) -> Address:
        """Channel held and checked quiet, programs started and ready, bench file written.
        BenchRefused when the channel is not the bench's; ChildFailed when a program does not
        come up (``stop`` cleans up either way)."""
        d = self.desc
        transport, channel = rigbus.select_transport(d.can.transport, d.can.channel or None,
                                                     own=OWN)
        self._channel = channel
        try:
            self._claim = rigbus.claim_channel(transport, channel)
        except rigbus.ChannelInUse as exc:
            raise BenchRefused(str(exc)) from exc
        # wall pacing grants the bench its time: the pacer loses no frame (lockstep), as the
        # rig's node of a lockstep run does not
        link = BusLink.open(transport, channel, lossless=self.pace == "wall")
        self.link = link
        try:
            link.check_channel()
        except ForeignNodes as exc:
            raise BenchRefused(f"foreign traffic: {exc}") from exc
        link.on("BENCH_PROGRESS", self._heard_progress)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.bench = virtual.VirtualBench(self.programs, self.dir, log_dir=self.dir / "logs")
        assert d.virtual is not None
        ends = self.bench.start(transport, channel, ready_timeout_s=d.virtual.ready_timeout_s)
        if self.pace == "wall":
            self.clock = LockstepClock(link, grant_s=GRANT_S)
            self.clock.on_idle(self.bench.check)
            self._period0 = self.clock.sync(timeout_s=d.virtual.ready_timeout_s)
            # the bench's processes (the pacer's threads too) ahead of the machine's other
            # work, below the real-time mode's priority: they block between grants, so they
            # take only the time the bench needs, and the bench keeps up with the wall clock
            prio = WALL_PRIORITY if self.rt_priority is None else self.rt_priority
            if prio > 0:
                for child in self.bench.sup.children.values():
                    make_fifo(child.pid, prio)
                make_fifo(os.getpid(), prio)
            self._grid0 = time.monotonic()
        if self.bitrate is not None:
            self._start_bit_clock(transport, channel, d.virtual.ready_timeout_s)
        assert ends.console_port is not None and ends.modbus_port is not None
        self.address = Address(transport, channel, ends.console_port, d.modbus.host,
                               ends.modbus_port, self.dir / BENCH_FILE)
        outputs.write_text(self.address.bench_file, self.bench_file_text())
        if self.clock is None:
            # in real time nothing needs this node between health samples, and a Python node
            # that falls behind the virtual wires' frames makes the plant wait for it
            link.close()
            self.link = None
        self._transport = transport
        self._t0 = time.monotonic()
        return self.address

    def _start_bit_clock(self, transport: str, channel: str, timeout_s: float) -> None:
        """``rig bus arbiter`` on the bench's channel, at the bench's priority (the plant's
        in real time), ready once its socket is there."""
        from rig.bus import arbiter

        assert self.bench is not None
        if transport != "unixcan":
            raise BenchRefused("a bit clock (--bitrate) is the fallback bus's: SocketCAN's "
                               "vcan delivers at once and has no bit timing")
        child = self.bench.sup.start("arbiter", [
            sys.executable, "-m", "rig", "bus", "arbiter", "--channel", channel,
            "--bitrate", str(self.bitrate)])
        deadline = time.monotonic() + timeout_s
        while not arbiter.socket_path(channel).exists():
            self.bench.sup.check()
            if time.monotonic() > deadline:
                raise ChildFailed("arbiter", f"no bit clock on {channel} within {timeout_s:g} s",
                                  child.log_tail())
            time.sleep(0.02)
        if self.pace == "wall":
            prio = WALL_PRIORITY if self.rt_priority is None else self.rt_priority
        else:
            plant = self.bench.sup.children.get("plant_rt")
            try:
                prio = os.sched_getparam(plant.pid).sched_priority if plant else 0
            except OSError:
                prio = 0
        if prio > 0:
            make_fifo(child.pid, prio)

    def bench_file_text(self) -> str:
        """The running bench as a real bench's description: every real-bench command takes
        it with ``--bench FILE``."""
        a = self.address
        assert a is not None
        d = self.desc
        doc = tomlkit.document()
        doc.add(tomlkit.comment(f"written by `rig up` (pid {os.getpid()}): the virtual bench, "
                                "free-running on the wall clock; gone when it stops"))
        doc["name"] = f"up-{os.getpid()}"
        doc["description"] = (f"virtual bench ({d.virtual.profile if d.virtual else '?'} "
                              f"profile) free-running on {a.transport} channel {a.channel}")
        doc["can"] = {"transport": a.transport, "channel": a.channel}
        doc["console"] = {"port": a.console, "baudrate": d.console.baudrate,
                          "timeout_s": d.console.timeout_s}
        m = d.modbus
        doc["modbus"] = {"kind": "tcp", "host": a.modbus_host, "port": a.modbus_port,
                         "unit": m.unit, "timeout_s": m.timeout_s,
                         "watchdog_timeout_ms": m.watchdog_timeout_ms}
        doc["clock"] = {"mode": "wall"}
        if d.commissioning:
            doc["commissioning"] = dict(d.commissioning)
        return tomlkit.dumps(doc)

    def scheduling(self) -> dict[str, str]:
        """What the kernel granted the bench's processes (in real time plant_rt and fw_host;
        paced by the wall clock every one, this pacer too)."""
        assert self.bench is not None
        names = ((virtual.PLANT, virtual.FIRMWARE) if self.clock is None
                 else (virtual.PLANT, virtual.FIRMWARE, virtual.LOADBENCH))
        out = {name: scheduling(child.pid)
               for name, child in self.bench.sup.children.items() if name in names}
        if self.clock is not None:
            out["pacer"] = scheduling(os.getpid())
        return out

    # -- running ------------------------------------------------------------------------
    def _heard_progress(self, v: Signals) -> None:
        now = (time.monotonic(), int(v["period"]))
        if self._progress0 is None:
            self._progress0 = now
        self._progress = now

    def watch(self, seconds: float) -> None:
        """Takes the bench's frames for this long, watching the programs (ChildFailed when
        one exits)."""
        assert self.bench is not None
        end = time.monotonic() + seconds
        while True:
            self.bench.check()
            now = time.monotonic()
            left = end - now
            if left <= 0:
                return
            if self.clock is None or self.link is None:
                time.sleep(min(left, 0.05))
                continue
            clock = self.clock
            due = self._period0 + int((now - self._grid0) / TS)  # the period the wall is at
            lag = due - clock.period
            if lag * TS > MAX_LAG_S:  # too far behind: the bench time pauses, the grid slips
                self.slipped_wall += lag
                self._grid0 += lag * TS
                lag = 0
            if lag > 0:
                clock.grant(min(due, clock.period + clock.grant_max))
            else:
                wait = (clock.period + 1 - self._period0) * TS + self._grid0 - now
                self.link.pump(min(left, max(wait, 0.0)))

    def _sample(self) -> dict[str, Signals]:
        """Real time: the bench's housekeeping frames (every 100 ms), heard on a node that
        is on the channel only for this."""
        wanted = ("BENCH_COUNTERS", "BENCH_PROGRESS", "DRIVE_STATUS")
        link = BusLink.open(self._transport, self._channel)
        try:
            link.on("BENCH_PROGRESS", self._heard_progress)
            deadline = time.monotonic() + SAMPLE_CEILING_S
            while (not all(n in link.latest for n in wanted)
                   and time.monotonic() < deadline):
                link.pump(0.05)
            self._sample_overflows += int(getattr(link.bus, "stats", {}).get("rx_overflows", 0))
            return dict(link.latest)
        finally:
            link.close()

    def health(self) -> Health:
        if self.link is not None:
            latest: dict[str, Signals] = self.link.latest
            overflows = int(getattr(self.link.bus, "stats", {}).get("rx_overflows", 0))
        else:
            latest = self._sampled = self._sample()
            overflows = self._sample_overflows
        c: dict[str, Any] = latest.get("BENCH_COUNTERS", {})
        slipped = None
        period = None
        if self.clock is not None:
            period = self.clock.period
            slipped = self.slipped_wall
        elif self._progress0 is not None and self._progress is not None:
            (w0, p0), (w1, p1) = self._progress0, self._progress
            period = p1
            if w1 > w0:
                slipped = max(0, round((w1 - w0) / TS) - (p1 - p0))
        status = latest.get("DRIVE_STATUS")
        state = "?" if status is None else protocols.named_value(
            "drive", "DRIVE_STATUS", "state", status["state"])
        return Health(time.monotonic() - self._t0, period, int(c.get("overruns", 0)), slipped,
                      int(c.get("late_cmds", 0)), int(c.get("tx_drops", 0)), overflows,
                      state, self.clock is not None)

    # -- down ---------------------------------------------------------------------------
    def stop(self) -> dict[str, StopReport]:
        """Programs stopped, channel released, the bench's folder removed (unless it was
        named). Never raises."""
        reports: dict[str, StopReport] = {}
        if self.address is not None:
            with contextlib.suppress(OSError):
                self.address.bench_file.unlink()
        if self.bench is not None:
            reports = self.bench.stop()
            if "arbiter" in reports:  # its figures: the last line it printed
                lines = supervisor_tail(self.bench.sup.children["arbiter"].stdout_log)
                self.bit_clock_summary = (lines.strip().splitlines() or [""])[-1]
        if self.link is not None:
            with contextlib.suppress(Exception):
                self.link.close()
            self.link = None
        if self._claim is not None:
            self._claim.release()
            self._claim = None
        if self._channel:
            rigbus.release_own_channel(self._channel)
        if self._own_folder:
            shutil.rmtree(self.dir, ignore_errors=True)
        return reports
