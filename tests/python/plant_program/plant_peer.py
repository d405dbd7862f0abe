"""Helpers of the program-level plant tests: the plant_rt process, a Python peer on the real
bus standing in for the firmware and the rig, and a reader of the binary trace files.

Frames are built and read with the DBC (cantools), never with hand-written layouts, except
where a test has to send what the DBC cannot express (a classic frame, a wrong length).
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
from cantools.database.can import Database, Message
from waits import EVENT_S

from rig import _paths
from rig import bus as rigbus
from rig.protocols import database, timebase

TBPRD = timebase().tbprd
TS = timebase().ts
TRACE_MAGIC = b"HILTRACE"
TRACE_RECORD = struct.Struct("<IBBBB64s")  # struct canfd_frame


def plant_binary() -> str:
    return str(_paths.binary("plant_rt"))


def responder_binary() -> str:
    return str(_paths.binary("pwm_responder"))


# --------------------------------------------------------------------------------------
# the plant_rt process


@dataclass
class Exit:
    returncode: int
    stderr: str
    counters: dict[str, Any]


def last_json(text: str) -> dict[str, Any]:
    for line in reversed(text.splitlines()):
        line = line.strip()
        if line.startswith("{"):
            value = json.loads(line)
            assert isinstance(value, dict)
            return value
    raise AssertionError(f"no JSON line in:\n{text}")


class PlantProcess:
    """plant_rt on the test's bus; started and waited for through its ready file."""

    def __init__(self, transport: str, channel: str, tmp_path: Path, *args: str) -> None:
        self.ready = tmp_path / f"plant-{time.monotonic_ns()}.ready"
        self.argv = [plant_binary(), "--bus", transport, "--channel", channel,
                     "--ready-file", str(self.ready), *args]
        self.proc = subprocess.Popen(self.argv, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + EVENT_S
        while not self.ready.exists():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.proc.kill()
                _, err = self.proc.communicate()
                raise RuntimeError(f"plant_rt did not start ({' '.join(self.argv)}): {err}")
            time.sleep(0.002)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = EVENT_S) -> Exit:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.wait(timeout)

    def wait(self, timeout: float = EVENT_S) -> Exit:
        try:
            _, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
            raise AssertionError(f"plant_rt did not exit within {timeout} s: {err}") from None
        return Exit(self.proc.returncode, err, last_json(err))

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


def run_plant(*args: str, timeout: float = EVENT_S) -> subprocess.CompletedProcess[str]:
    """plant_rt to completion (for start-up failures that never reach the bus)."""
    return subprocess.run([plant_binary(), *args], capture_output=True, text=True,
                          timeout=timeout, check=False)


class Responder:
    """The C stand-in firmware (plant_rt/tools/pwm_responder.c)."""

    def __init__(self, transport: str, channel: str, tmp_path: Path, *args: str) -> None:
        ready = tmp_path / f"responder-{time.monotonic_ns()}.ready"
        self.proc = subprocess.Popen(
            [responder_binary(), "--bus", transport, "--channel", channel,
             "--ready-file", str(ready), *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + EVENT_S
        while not ready.exists():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.proc.kill()
                _, err = self.proc.communicate()
                raise RuntimeError(f"pwm_responder did not start: {err}")
            time.sleep(0.002)

    def stop(self) -> dict[str, Any]:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        out, err = self.proc.communicate(timeout=EVENT_S)
        assert self.proc.returncode == 0, err
        return last_json(out)


# --------------------------------------------------------------------------------------
# the Python peer


@dataclass
class Frame:
    name: str
    signals: dict[str, Any]
    msg: can.Message


def _messages() -> dict[int, tuple[Database, Message]]:
    out: dict[int, tuple[Database, Message]] = {}
    for name in ("vio", "bench"):
        db = database(name)
        for m in db.messages:
            out[m.frame_id] = (db, m)
    return out


@dataclass
class Pwm:
    """One VIO_PWM command (docs/interfaces.md)."""

    period: int
    cmp_up: Sequence[int] = (2500, 2500, 2500)
    cmp_dn: Sequence[int] = (2500, 2500, 2500)
    socs: Sequence[int] = (0,)
    gate_enable: int = 1
    n_soc: int | None = None  # defaults to len(socs)

    def signals(self) -> dict[str, int]:
        s: dict[str, int] = {"period": self.period, "gate_enable": self.gate_enable,
                             "n_soc": len(self.socs) if self.n_soc is None else self.n_soc}
        for x, phase in enumerate("abc"):
            s[f"cmp_{phase}_up"] = self.cmp_up[x]
            s[f"cmp_{phase}_dn"] = self.cmp_dn[x]
        for k in range(16):
            s[f"soc_{k}"] = self.socs[k] if k < len(self.socs) else 0
        return s


@dataclass
class Peer:
    """A python-can node on the test's bus that decodes what the plant sends."""

    transport: str
    channel: str
    bus: can.BusABC = field(init=False)
    by_id: dict[int, tuple[Database, Message]] = field(init=False)
    heard: list[Frame] = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        self.bus = rigbus.open_bus(self.transport, self.channel)
        self.by_id = _messages()

    def close(self) -> None:
        self.bus.shutdown()

    def message(self, name: str) -> Message:
        for _, m in self.by_id.values():
            if m.name == name:
                return m
        raise KeyError(name)

    # -- sending
    def send(self, name: str, values: dict[str, Any], strict: bool = True) -> None:
        m = self.message(name)
        data = m.encode(values, strict=strict)
        self.bus.send(can.Message(arbitration_id=m.frame_id, data=data, is_fd=bool(m.is_fd),
                                  is_extended_id=False, bitrate_switch=False))

    def send_raw(self, can_id: int, data: bytes, is_fd: bool) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_fd=is_fd,
                                  is_extended_id=False))

    def pwm(self, cmd: Pwm, strict: bool = True) -> None:
        self.send("VIO_PWM", cmd.signals(), strict=strict)

    def step(self, run_until: int, seq: int) -> None:
        self.send("BENCH_STEP", {"run_until": run_until, "seq": seq})

    def load(self, mode: int, torque: float = 0.0, speed: float = 0.0, k_speed: float = 0.0,
             seq: int = 0, strict: bool = True) -> None:
        self.send("LOAD_CMD", {"mode": mode, "seq": seq, "torque": torque, "speed": speed,
                               "k_speed": k_speed}, strict=strict)

    # -- receiving
    def recv(self, timeout: float) -> Frame | None:
        msg = self.bus.recv(timeout=timeout)
        if msg is None or msg.is_error_frame:
            return None
        known = self.by_id.get(msg.arbitration_id)
        if known is None:
            return None
        _, m = known
        values = m.decode(bytes(msg.data), decode_choices=False)
        assert isinstance(values, dict)
        frame = Frame(m.name, dict(values), msg)
        self.heard.append(frame)
        return frame

    def wait_for(self, pred: Callable[[Frame], bool], timeout: float = EVENT_S,
                 what: str = "frame") -> Frame:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no {what} within {timeout} s")
            f = self.recv(left)
            if f is not None and pred(f):
                return f

    def adc(self, period: int, timeout: float = EVENT_S) -> Frame:
        """The VIO_ADC frame that completes `period` (all of its SOCs)."""
        while True:
            f = self.wait_for(lambda f: f.name.startswith("VIO_ADC_")
                              and f.signals["period"] == period, timeout, f"ADC({period})")
            n = int(f.signals["n_soc"])
            if int(f.name[-1]) == (n + 6) // 7 - 1:
                return f

    def drain(self, duration: float = 0.2) -> list[Frame]:
        """Everything heard during `duration` seconds."""
        out: list[Frame] = []
        deadline = time.monotonic() + duration
        while (left := deadline - time.monotonic()) > 0:
            if (f := self.recv(left)) is not None:
                out.append(f)
        return out

    def frames(self, name: str) -> list[Frame]:
        return [f for f in self.heard if f.name == name]


def adc_codes(frames: Iterable[Frame], n_soc: int) -> list[tuple[int, int]]:
    """(ia, ib) codes of SOCs 0..n_soc-1 from a period's VIO_ADC frames."""
    by_index: dict[int, tuple[int, int]] = {}
    for f in frames:
        for k in range(16):
            if f"ia_{k}" in f.signals:
                by_index[k] = (int(f.signals[f"ia_{k}"]), int(f.signals[f"ib_{k}"]))
    return [by_index[k] for k in range(n_soc)]


# --------------------------------------------------------------------------------------
# trace files


@dataclass
class Record:
    can_id: int
    name: str
    signals: dict[str, Any]


def read_trace(path: Path) -> list[Record]:
    raw = path.read_bytes()
    assert raw[:8] == TRACE_MAGIC, raw[:16]
    version, size = struct.unpack_from("<II", raw, 8)
    assert (version, size) == (1, 72)
    body = raw[16:]
    assert len(body) % 72 == 0, "trace ends inside a record"
    by_id = _messages()
    out: list[Record] = []
    for off in range(0, len(body), 72):
        can_id, length, _flags, _r0, _r1, data = TRACE_RECORD.unpack_from(body, off)
        _, m = by_id[can_id & 0x7FF]
        values = m.decode(data[:length], decode_choices=False)
        assert isinstance(values, dict)
        out.append(Record(can_id, m.name, dict(values)))
    return out


def wait_file(path: Path, timeout: float = EVENT_S) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} not written"
        time.sleep(0.005)


def env_with(**extra: str) -> dict[str, str]:
    return dict(os.environ, **extra)
