"""One commissioning session on a bench: programs (virtual bench), CAN link, bench clock,
parameters, drive master, console and load bench, and the safe stop.

``safe_stop()`` runs on every way out (normal end, failed check, time-out, lost link,
Ctrl-C, SIGTERM): DRIVE_CMD enable 0 (CAN), console ``disable``, load machine off and
torque 0 over Modbus (read back), then a little bench time so the commands act, then a
read-back of the drive state. Each part is tried even when another fails; what happened is
listed in the report.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from rig import bus as rigbus
from rig.bench import virtual
from rig.bench.description import BenchDescription
from rig.commissioning.checked_drive import CheckedDrive
from rig.commissioning.config import CommissioningConfig
from rig.commissioning.truth import plant_truth
from rig.drive.console import ConsoleClient
from rig.drive.params import ParamClient
from rig.link.bus import BusLink, ForeignNodes, LinkError
from rig.link.clock import BenchClock, LockstepClock, WallClock
from rig.link.drive_master import DriveMaster
from rig.loadbench.client import LoadBench

Log = Callable[[str], None]
SAFE_STOP_STALL_S = 2.0  # a dead plant must not hold the safe stop for the full stall time
OWN = "commission"  # a virtual bench session's own unixcan channel: commission-<pid>


class ChannelRefused(RuntimeError):
    """The channel of a virtual bench session is not its own: another run of the rig holds
    it, or a node sends there (the session starts nothing: exit 3)."""


class BenchSession:
    def __init__(self, desc: BenchDescription, run_dir: Path, log: Log | None = None) -> None:
        self.desc = desc
        self.dir = Path(run_dir)
        self.log: Log = log or (lambda _m: None)
        self.config = CommissioningConfig.from_mapping(desc.commissioning)
        self.virtual: virtual.VirtualBench | None = None
        self.endpoints = virtual.Endpoints(None, None)
        self._link: BusLink | None = None
        self._clock: BenchClock | None = None
        self._params: ParamClient | None = None
        self._drive: CheckedDrive | None = None
        self.console: ConsoleClient | None = None
        self.load: LoadBench | None = None
        self.identified: dict[str, float] = {}
        self.channel_own = False  # the session's own unixcan channel (none was named)
        self._claim: rigbus.ChannelClaim | None = None
        self._channel = ""
        # drive parameters a step wrote as its result (``rig commission --save-params``)
        self.written: dict[str, float] = {}
        self.safety: list[str] = []
        self.truth: dict[str, float] | None = None

    # -- parts (raise when used before start()) ------------------------------------------
    @property
    def link(self) -> BusLink:
        assert self._link is not None, "session not started"
        return self._link

    @property
    def clock(self) -> BenchClock:
        assert self._clock is not None, "session not started"
        return self._clock

    @property
    def params(self) -> ParamClient:
        assert self._params is not None, "session not started"
        return self._params

    @property
    def drive(self) -> CheckedDrive:
        assert self._drive is not None, "session not started"
        return self._drive

    @property
    def started(self) -> bool:
        return self._link is not None

    @property
    def recording(self) -> Path:
        return self.dir / "bus.log"

    # -- opening -----------------------------------------------------------------------
    def start(self) -> None:
        """Programs of a virtual bench, the CAN link, the clock, parameters, drive master.
        A virtual bench session that names no channel gets a unixcan channel of its own; its
        channel is held for the session and checked for foreign traffic before anything
        starts, as a run's is (ChannelRefused). A real bench's drive is there already: its
        channel is the description's (else $HIL_CHANNEL, else vcan0)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        d = self.desc
        starts_nodes = d.virtual is not None and bool(d.virtual.programs)
        transport, channel = rigbus.select_transport(d.can.transport, d.can.channel or None,
                                                     own=OWN if starts_nodes else None)
        self._channel = channel
        self.channel_own = starts_nodes and rigbus.is_own_channel(channel)
        if starts_nodes:
            try:
                self._claim = rigbus.claim_channel(transport, channel)
            except rigbus.ChannelInUse as exc:
                raise ChannelRefused(str(exc)) from exc
        try:
            # in lockstep the rig's node loses no frame, as the programs' do (unixcan)
            link = BusLink.open(transport, channel, record=self.recording,
                                lossless=d.lockstep)
        except BaseException:
            self._release_channel()
            raise
        if starts_nodes:
            try:
                link.check_channel()
            except BaseException as exc:
                link.close()
                self._release_channel()
                if isinstance(exc, ForeignNodes):  # (ForeignTraffic too): nothing started
                    raise ChannelRefused(f"foreign traffic: {exc}") from exc
                if isinstance(exc, RuntimeError | FileNotFoundError | OSError):
                    raise LinkError(str(exc)) from exc  # hilbus_tool
                raise
        self._link = link
        if d.virtual is not None:
            self.truth = plant_truth(d)
            if d.virtual.programs:
                self.virtual = virtual.VirtualBench(virtual.from_description(d), self.dir,
                                                  log_dir=self.dir / "logs")
                own = " (the session's own)" if self.channel_own else ""
                self.log(f"starting the virtual bench ({', '.join(d.virtual.programs)}) on "
                         f"{transport} channel {channel}{own}")
                self.endpoints = self.virtual.start(transport, channel,
                                                    ready_timeout_s=d.virtual.ready_timeout_s)
        if d.lockstep:
            clock: BenchClock = LockstepClock(self._link, grant_s=d.clock.grant_s)
        else:
            clock = WallClock(self._link)
        self._clock = clock
        if self.virtual is not None:
            clock.on_idle(self.virtual.check)
        if isinstance(clock, LockstepClock):
            clock.sync()
        self._params = ParamClient(self._link)
        self._drive = CheckedDrive(DriveMaster(self._link), clock, self._params)

    def open_console(self) -> ConsoleClient:
        if self.console is None:
            port = self.desc.console.port or self.endpoints.console_port
            if not port:
                raise RuntimeError("no console port in the bench description")
            con = ConsoleClient(port, timeout_s=self.desc.console.timeout_s,
                                baudrate=self.desc.console.baudrate)
            con.open()
            self.console = con
            self.drive.console = con
        return self.console

    def open_load(self) -> LoadBench:
        if self.load is None:
            spec = self.desc.modbus
            if self.endpoints.modbus_port is not None:
                spec = replace(spec, port=self.endpoints.modbus_port)
            lb = LoadBench(spec)
            lb.open()
            lb.set_watchdog_timeout(spec.watchdog_timeout_ms)
            self.load = lb
            self.clock.on_idle(lb.refresh_watchdog)
        return self.load

    def require(self) -> tuple[ConsoleClient, LoadBench]:
        return self.open_console(), self.open_load()

    # -- leaving -----------------------------------------------------------------------
    def safe_stop(self) -> list[str]:
        """Drive disabled, load zeroed; every part tried; returns what happened."""
        notes: list[str] = []
        if self._drive is not None:
            try:
                self._drive.send_stop()
                notes.append("CAN: DRIVE_CMD enable 0 sent")
            except Exception as exc:
                notes.append(f"CAN: DRIVE_CMD enable 0 FAILED: {exc}")
        if self.console is not None:
            try:
                self.console.disable()
                notes.append("console: disable → OK")
            except Exception as exc:
                notes.append(f"console: disable FAILED: {exc}")
        if self.load is not None:
            try:
                self.load.off()
                notes.append("load bench: mode off, torque 0 (read back)")
            except Exception as exc:
                notes.append(f"load bench: zeroing FAILED: {exc}")
        if self._clock is not None:
            clock = self._clock
            lockstep = clock if isinstance(clock, LockstepClock) else None
            stall = lockstep.stall_s if lockstep is not None else 0.0
            try:
                if lockstep is not None:
                    lockstep.stall_s = min(stall, SAFE_STOP_STALL_S)
                with clock.without_idle_hooks():
                    clock.advance(0.01)
                    if self._drive is not None:
                        drv = self._drive
                        clock.wait(lambda: drv.state in ("IDLE", "FAULT", "UNKNOWN"),
                                   0.2, "drive disabled", step_s=0.01)
            except Exception as exc:
                notes.append(f"bench clock: could not advance after the stop: {exc}")
            finally:
                if lockstep is not None:
                    lockstep.stall_s = stall
        notes.append(f"drive state afterwards: {self._state_after()}")
        self.safety = notes
        return notes

    def _state_after(self) -> str:
        parts = []
        if self._drive is not None:
            with contextlib.suppress(Exception):
                self.link.pump(0.15)
                parts.append(f"DRIVE_STATUS {self._drive.state}")
        if self.console is not None:
            with contextlib.suppress(Exception):
                st = self.console.status()
                parts.append(f"console enable={st['enable']} state={st['state']}")
        return ", ".join(parts) or "unknown (no link to the drive)"

    def close(self) -> dict[str, object]:
        stopped: dict[str, object] = {}
        for part in (self.console, self.load):
            if part is not None:
                with contextlib.suppress(Exception):
                    part.close()
        if self._link is not None:
            self._link.close()
        if self.virtual is not None:
            stopped = {name: {"exit": rep.returncode, "clean": rep.clean}
                       for name, rep in self.virtual.stop().items()}
        self._release_channel()
        return stopped

    def _release_channel(self) -> None:
        if self._claim is not None:
            self._claim.release()
            self._claim = None
        if self.channel_own:
            rigbus.release_own_channel(self._channel)

    def elapsed(self) -> Callable[[], tuple[float, float]]:
        """A stopwatch of (bench s, wall s) from now."""
        b0, w0 = self.clock.now(), time.monotonic()
        return lambda: (self.clock.now() - b0, time.monotonic() - w0)
