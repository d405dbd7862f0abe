"""Helpers of the fw_host tests: the real program on a real bus, a Python peer standing in
for the plant and the rig (it sends VIO_ADC frames with synthetic codes and drive-protocol
frames, and decodes what fw_host sends with the DBC).

Default parameters make synthetic codes easy: 16-bit current ADC over +-10 A (code 32768 =
0 A) and 16-bit DC link over 400 V (code 32768 = 200 V).
"""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import pytest
from cantools.database.can import Database, Message
from waits import EVENT_S

from rig import _paths, protocols

ZERO_A = 32768
VDC_200V = 32768
READY_TIMEOUT_S = EVENT_S  # a ceiling: sanitizer builds, the VM, a loaded machine
# the DRIVE_STATUS value tables of protocols/drive.dbc
STATE = protocols.spelled("drive", "DRIVE_STATUS", "state")
FAULT = protocols.spelled("drive", "DRIVE_STATUS", "fault_code")
FAULT_CMD_TIMEOUT = FAULT["CMD_TIMEOUT"]
FAULT_ADC_LOSS = FAULT["ADC_LOSS"]


def fw_binary() -> Path:
    try:
        return _paths.binary("fw_host")
    except FileNotFoundError as exc:
        pytest.skip(f"fw_host not built: {exc}")


@dataclass
class FwProcess:
    """A running fw_host and where its stderr goes."""

    proc: subprocess.Popen[bytes]
    stderr_path: Path
    argv: list[str]
    returncode: int | None = None

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def stop(self, sig: int = signal.SIGTERM, timeout: float = EVENT_S) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        self.returncode = self.proc.wait(timeout=timeout)
        return self.returncode

    def counters(self) -> dict[str, Any]:
        """The JSON line fw_host prints on stderr at exit."""
        for line in reversed(self.stderr().splitlines()):
            if line.startswith("{"):
                data: dict[str, Any] = json.loads(line)
                return data
        raise AssertionError(f"no JSON counters on stderr:\n{self.stderr()}")


StartFw = Callable[..., FwProcess]


@dataclass
class Peer:
    """Plant and rig stand-in on the bus: sends what they send, decodes what fw_host sends."""

    bus: can.BusABC
    drive: Database = field(default_factory=lambda: protocols.database("drive"))
    vio: Database = field(default_factory=lambda: protocols.database("vio"))
    alive: int = 0
    seq: int = 0
    log: list[can.Message] = field(default_factory=list)

    def msg(self, name: str) -> Message:
        for db in (self.drive, self.vio):
            try:
                return db.get_message_by_name(name)
            except KeyError:
                continue
        raise KeyError(name)

    # ---------------------------------------------------------------- sending
    def send_raw(self, frame_id: int, data: bytes, *, fd: bool) -> None:
        self.bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False,
                                  is_fd=fd, bitrate_switch=False))

    def send(self, name: str, values: dict[str, float], *, strict: bool = True) -> None:
        m = self.msg(name)
        self.send_raw(m.frame_id, m.encode(values, strict=strict), fd=bool(m.is_fd))

    def adc_frames(self, period: int, n_soc: int, ia: int = ZERO_A, ib: int = ZERO_A,
                   vdc: int = VDC_200V) -> list[tuple[int, bytes]]:
        """The VIO_ADC_0..2 frames the plant sends for one period."""
        out = []
        for index, first, count in ((0, 0, 7), (1, 7, 7), (2, 14, 2)):
            if index > 0 and n_soc <= first:
                break
            m = self.msg(f"VIO_ADC_{index}")
            values: dict[str, float] = {"period": period, "n_soc": n_soc, "vdc_code": vdc}
            for k in range(first, first + count):
                values[f"ia_{k}"] = ia
                values[f"ib_{k}"] = ib
            out.append((m.frame_id, m.encode(values)))
        return out

    def send_adc(self, period: int, n_soc: int, **codes: int) -> None:
        for frame_id, data in self.adc_frames(period, n_soc, **codes):
            self.send_raw(frame_id, data, fd=True)

    def command(self, *, enable: int = 0, fault_reset: int = 0, ctrl_mode: int = 0,
                fw_mode: int = 0, speed_ref: float = 0.0, iq_ref: float = 0.0) -> None:
        self.alive = (self.alive + 1) % 256
        self.send("DRIVE_CMD", {"enable": enable, "fault_reset": fault_reset,
                                "ctrl_mode": ctrl_mode, "fw_mode": fw_mode,
                                "alive": self.alive, "speed_ref": speed_ref, "iq_ref": iq_ref})

    # ---------------------------------------------------------------- receiving
    def recv_until(self, want: Callable[[can.Message], bool], timeout: float = EVENT_S
                   ) -> can.Message | None:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            m = self.bus.recv(timeout=min(left, 0.1))
            if m is None:
                continue
            self.log.append(m)
            if want(m):
                return m

    def expect(self, name: str, pred: Callable[[dict[str, Any]], bool] | None = None,
               timeout: float = EVENT_S) -> dict[str, Any]:
        m = self.msg(name)

        def want(frame: can.Message) -> bool:
            if frame.arbitration_id != m.frame_id:
                return False
            return pred is None or pred(self.decode(frame))

        got = self.recv_until(want, timeout)
        assert got is not None, f"no {name} within {timeout} s"
        return self.decode(got)

    def decode(self, frame: can.Message) -> dict[str, Any]:
        m = self.drive.get_message_by_frame_id(frame.arbitration_id) if \
            frame.arbitration_id >= 0x100 else self.vio.get_message_by_frame_id(
                frame.arbitration_id)
        values = m.decode(bytes(frame.data), decode_choices=False)
        assert isinstance(values, dict)
        return dict(values)

    def decode_data(self, name: str, data: bytes) -> dict[str, Any]:
        values = self.msg(name).decode(data, decode_choices=False)
        assert isinstance(values, dict)
        return dict(values)

    def drain(self, quiet: float = 0.05) -> list[can.Message]:
        """Receives until the bus is quiet for `quiet` seconds."""
        got = []
        while (m := self.bus.recv(timeout=quiet)) is not None:
            self.log.append(m)
            got.append(m)
        return got

    def pwm(self, period: int, timeout: float = EVENT_S) -> dict[str, Any]:
        return self.expect("VIO_PWM", lambda v: v["period"] == period, timeout)

    def status(self, pred: Callable[[dict[str, Any]], bool] | None = None,
               timeout: float = EVENT_S) -> dict[str, Any]:
        return self.expect("DRIVE_STATUS", pred, timeout)

    def step(self, period: int, n_soc: int, **codes: int) -> dict[str, Any]:
        """ADC(period) out, PWM(period + 1) back."""
        self.send_adc(period, n_soc, **codes)
        return self.pwm(period + 1)

    def sync(self, period: int) -> None:
        """The plant's barrier after the ADC frames of a period (VIO_SYNC)."""
        self.sync_seq = getattr(self, "sync_seq", 0) % 255 + 1
        self.send("VIO_SYNC", {"period": period, "seq": self.sync_seq})

    def step_after_loss(self, period: int, n_soc: int, **codes: int) -> dict[str, Any]:
        """ADC(period) after periods the plant skipped, as a plant in lockstep does it: the
        frames of the first skipped period lost to a frame fault, its barrier (VIO_SYNC),
        the plant going on without PWM; fw_host follows skipped periods in lockstep only
        after a barrier (adc_assembly.h). PWM(period + 1) back."""
        self.sync(period - 1)
        self.send_adc(period, n_soc, **codes)
        self.sync(period)
        return self.pwm(period + 1)

    def run(self, first: int, count: int, n_soc: int = 1, **codes: int) -> list[dict[str, Any]]:
        """Lockstep periods first .. first+count-1, each with the SOC count the last PWM asked
        for (like the plant); returns the PWM frames."""
        out = []
        for k in range(first, first + count):
            pwm = self.step(k, n_soc, **codes)
            n_soc = int(pwm["n_soc"])
            out.append(pwm)
        return out

    def param(self, op: int, param_id: int, value: float = 0.0,
              timeout: float = EVENT_S) -> dict[str, Any]:
        """PARAM_REQ -> PARAM_RESP (matched by seq)."""
        self.seq = (self.seq + 1) % 256
        seq = self.seq
        self.send("PARAM_REQ", {"op": op, "seq": seq, "param_id": param_id, "value": value})
        return self.expect("PARAM_RESP", lambda v: v["seq"] == seq, timeout)


def param_ids() -> dict[str, int]:
    """Parameter name -> id, from protocols/parameters.csv."""
    path = protocols.path("drive").parent / "parameters.csv"
    with path.open(newline="") as f:
        return {row["name"]: int(row["id"]) for row in csv.DictReader(f)}
