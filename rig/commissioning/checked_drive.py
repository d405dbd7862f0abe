"""The commissioning scripts' hand on the drive: every change checked.

DRIVE_CMD (``rig.link.drive_master``) goes out on every clock cycle (before each lockstep grant,
or every 10 ms) once the scripts command the drive, which keeps the firmware's command
time-out alive; changes go out at once. Every change is read back: the modes and the
command status from DRIVE_STATUS, the references from the console's ``status`` line
(``speed_ref``, ``iq_ref_cmd``, ``enable``, ``owner``) when a console is open, the limits
from the parameters they write (PARAM_REQ reads).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any

from rig import protocols
from rig.drive.console import ConsoleClient
from rig.drive.params import ParamClient
from rig.link.clock import BenchClock, BenchTimeout
from rig.link.drive_master import CTRL_MODES, FW_MODES, DriveLimits, DriveMaster, quantize

READBACK_WALL_S = 1.0
# A state change is sent at once and again every DRIVE_STATUS cycle (100 ms); the frame on
# change can be lost on a full receiver, so a wait for a new state spans three cycles (one
# cycle was the limit: a disable after the xsat step failed once in ~10 loaded test runs)
STATE_WAIT_S = 3 * protocols.cycle_s("drive", "DRIVE_STATUS")
CMD_STATUS = protocols.names("drive", "PARAM_RESP", "status")


class DriveError(RuntimeError):
    """The drive did not do what it was told (fault, refused command, no read-back)."""


class CheckedDrive:
    def __init__(self, master: DriveMaster, clock: BenchClock, params: ParamClient,
                 console: ConsoleClient | None = None) -> None:
        self.master = master
        self.link = master.link
        self.clock = clock
        self.params = params
        self.console = console
        self.in_command = False  # True once the scripts have commanded the drive
        clock.on_cycle(self.cyclic)

    def cyclic(self) -> None:
        if self.in_command:
            self.master.send_command()

    # -- status ------------------------------------------------------------------------
    @property
    def status(self) -> dict[str, Any]:
        return self.master.status

    @property
    def state(self) -> str:
        return self.master.state

    def fault_text(self) -> str:
        st = self.status
        code = int(st.get("fault_code", 0))
        name = ""
        if self.console is not None:
            try:
                name = self.console.status().get("fault_name", "")
            except Exception:  # the fault text is a courtesy; the code is what counts
                name = ""
        return f"fault {code}{f' ({name})' if name else ''}"

    def check_no_fault(self, what: str) -> None:
        if self.state == "FAULT":
            raise DriveError(f"{what}: the drive is in FAULT, {self.fault_text()}")

    # -- commands ----------------------------------------------------------------------
    def command(self, **changes: Any) -> None:
        """Changes fields of the drive command, sends it at once and reads it back."""
        self.master.cmd = replace(self.master.cmd, **changes)
        self.in_command = True
        self.master.send_command()
        self.readback()

    def send_stop(self, times: int = 3) -> None:
        """Enable 0 and zero references, sent at once and without read-back (the safe
        stop: the drive may not answer)."""
        self.master.cmd = replace(self.master.cmd, enable=0, speed_ref=0.0, iq_ref=0.0)
        self.in_command = True
        for _ in range(times):
            self.master.send_command()

    def readback(self) -> None:
        """DRIVE_STATUS: modes and command status; console status: references and enable."""
        want = self.master.cmd
        deadline = time.monotonic() + READBACK_WALL_S
        while True:
            self.link.pump(0.01)
            st = self.status
            ok_status = bool(st) and int(st["ctrl_mode"]) == CTRL_MODES[want.ctrl_mode] and \
                int(st["fw_mode"]) == FW_MODES[want.fw_mode] and int(st["cmd_status"]) == 0
            ok_console = True
            detail = ""
            if self.console is not None:
                cs = self.console.status()
                ok_console = (cs.get("owner") == "can" and int(cs["enable"]) == want.enable
                              and math.isclose(float(cs["speed_ref"]),
                                               quantize("speed_ref", want.speed_ref),
                                               abs_tol=2e-3)
                              and math.isclose(float(cs["iq_ref_cmd"]),
                                               quantize("iq_ref", want.iq_ref), abs_tol=2e-3))
                detail = (f"console: owner={cs.get('owner')} enable={cs.get('enable')} "
                          f"speed_ref={cs.get('speed_ref')} iq_ref_cmd={cs.get('iq_ref_cmd')}")
            if ok_status and ok_console:
                return
            if time.monotonic() > deadline:
                why = ""
                if st and int(st["cmd_status"]) != 0:
                    why = (" - the drive refused it: "
                           f"{CMD_STATUS.get(int(st['cmd_status']), st['cmd_status'])}")
                raise DriveError(f"drive command {want} not read back within "
                                 f"{READBACK_WALL_S:g} s{why} (DRIVE_STATUS {st}; {detail})")

    def set_limits(self, i_max: float, speed_max: float, accel: float) -> None:
        """DRIVE_LIMITS, read back through the parameters they set."""
        self.master.send_limits(DriveLimits(i_max, speed_max, accel))
        for name, want in (("i_max_a", i_max), ("speed_max_rpm", speed_max),
                           ("accel_rpm_s", accel)):
            got = self.params.get(name)
            if not math.isclose(got, want, rel_tol=1e-4, abs_tol=0.06):
                raise DriveError(f"DRIVE_LIMITS not applied: {name} reads {got:g}, sent "
                                 f"{want:g} (refused by the drive?)")

    def enable(self, *, ctrl_mode: str, fw_mode: str, speed_ref: float = 0.0,
               iq_ref: float = 0.0, timeout_s: float = 1.0) -> float:
        """Enables the drive (polarity detection, then RUN); the bench time it took."""
        self.check_no_fault("enable")
        if self.master.cmd.enable:
            self.command(enable=0)
            self.clock.advance(0.002)
        self.command(enable=1, ctrl_mode=ctrl_mode, fw_mode=fw_mode, speed_ref=speed_ref,
                     iq_ref=iq_ref, fault_reset=0)
        try:
            return self.clock.wait(lambda: self.state in ("RUN", "FAULT"), timeout_s,
                                   "drive start (polarity detection, then RUN)")
        finally:
            self.check_no_fault("start-up")

    def reset_fault(self, timeout_s: float = STATE_WAIT_S) -> None:
        """fault_reset edge with enable 0; the drive goes back to IDLE."""
        self.command(enable=0, fault_reset=1, speed_ref=0.0, iq_ref=0.0)
        try:
            self.clock.wait(lambda: self.state == "IDLE", timeout_s, "fault reset")
        finally:
            self.command(fault_reset=0)

    def disable(self, timeout_s: float = STATE_WAIT_S) -> None:
        self.command(enable=0, speed_ref=0.0, iq_ref=0.0)
        try:
            self.clock.wait(lambda: self.state in ("IDLE", "FAULT"), timeout_s, "drive disable")
        except BenchTimeout as exc:
            raise DriveError(f"the drive did not go IDLE after disable ({self.state})") from exc

    def require_idle(self, what: str) -> None:
        self.link.pump(0.0)
        self.check_no_fault(what)
        if self.state not in ("IDLE", "INIT", "UNKNOWN"):
            raise DriveError(f"{what}: the drive is {self.state}; it must be disabled first")
