"""Client of the drive's SCI console (protocols/console.md), over pyserial.

The grammar (commands, arguments, error codes, line limits) is read from
protocols/console.json, the single source of truth; nothing here re-types the command table.
``serial.serial_for_url`` opens the port, so a device (``/dev/ttyUSB0``), a pseudo-terminal
path (fw_host's ``--pty-link``), ``rfc2217://host:port`` or ``socket://host:port`` all work;
115200 8N1, no flow control.

    with ConsoleClient("/dev/ttyUSB0") as con:
        con.ping()
        print(con.version())
        con.set("rs_ohm", 2.1)           # range-checked by the drive, read back
        reply = con.request("speed 300")  # raw line -> Reply (OK/ERR, data lines)

``request`` sends a line as it is and returns the drive's reply; ``call`` checks the command
and its arguments against the grammar first (``ConsoleUsageError``, nothing sent) and raises
``ConsoleError`` on an ERR reply. No reply within the time-out raises ``ConsoleTimeout``.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import serial  # type: ignore[import-untyped]

from rig._paths import data_dir

GRAMMAR_FILE = "console.json"
NUMBER_RE = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?")
MEASURED_SPECIAL = {"nan": float("nan"), "inf": float("inf"), "-inf": float("-inf")}


# --------------------------------------------------------------------------------------
# The grammar


@dataclass(frozen=True)
class Argument:
    name: str
    type: str  # param | number | choice
    choices: tuple[str, ...] = ()


@dataclass(frozen=True)
class Command:
    name: str
    args: tuple[Argument, ...]
    summary: str
    reply: str

    @property
    def usage(self) -> str:
        return " ".join([self.name, *(a.name for a in self.args)])


@dataclass(frozen=True)
class Grammar:
    version: int
    max_line: int
    data_prefix: str
    errors: Mapping[int, str]
    commands: Mapping[str, Command]
    path: Path

    def command(self, name: str) -> Command:
        try:
            return self.commands[name]
        except KeyError:
            raise ConsoleUsageError(f"'{name}' is not a console command "
                                    f"(console.json: {', '.join(self.commands)})") from None

    def check(self, name: str, args: Sequence[str]) -> Command:
        """The command, after checking the arguments' count and syntax (not parameter names:
        the drive knows its table)."""
        cmd = self.command(name)
        if len(args) != len(cmd.args):
            raise ConsoleUsageError(f"usage: {cmd.usage}")
        for spec, value in zip(cmd.args, args, strict=True):
            if spec.type == "number" and not NUMBER_RE.fullmatch(value):
                raise ConsoleUsageError(f"{cmd.name}: {spec.name} = {value!r} is not a NUMBER")
            if spec.type == "choice" and value not in spec.choices:
                raise ConsoleUsageError(f"{cmd.name}: {spec.name} must be one of "
                                        f"{', '.join(spec.choices)}")
            if spec.type == "param" and not re.fullmatch(r"[a-z0-9_]+", value):
                raise ConsoleUsageError(f"{cmd.name}: {value!r} is not a parameter name")
        return cmd


@cache
def grammar(path: Path | None = None) -> Grammar:
    p = path or data_dir("protocols") / GRAMMAR_FILE
    data = json.loads(p.read_text())
    commands = {}
    for c in data["commands"]:
        args = tuple(Argument(str(a["name"]), str(a["type"]), tuple(a.get("choices", ())))
                     for a in c["args"])
        commands[str(c["name"])] = Command(str(c["name"]), args, str(c["summary"]),
                                           str(c["reply"]))
    return Grammar(int(data["version"]), int(data["max_line"]), str(data["data_prefix"]),
                   {int(e["code"]): str(e["name"]) for e in data["errors"]}, commands, p)


# --------------------------------------------------------------------------------------
# Replies and errors


class ConsoleUsageError(ValueError):
    """A command line that does not fit the grammar (never sent)."""


class ConsoleLinkError(RuntimeError):
    """The port cannot be opened, or it broke."""


class ConsoleTimeout(ConsoleLinkError):
    """No complete reply within the time-out."""


class ConsoleProtocolError(ConsoleLinkError):
    """A reply line that is not a data line or a final line of the grammar."""


@dataclass(frozen=True)
class Reply:
    line: str
    ok: bool
    payload: str = ""
    code: int = 0
    error_name: str = ""
    message: str = ""
    data: tuple[str, ...] = ()

    def fields(self) -> dict[str, str]:
        """KEY=VALUE words of an OK payload."""
        out = {}
        for word in self.payload.split():
            key, sep, value = word.partition("=")
            if not sep:
                raise ConsoleProtocolError(f"'{self.line}': {word!r} is not KEY=VALUE")
            out[key] = value
        return out

    def number(self) -> float:
        return parse_number(self.payload)

    def lines(self, prefix: str = "- ") -> list[str]:
        """The reply as the drive wrote it (without line ends)."""
        return [*(prefix + d for d in self.data), self.final]

    @property
    def final(self) -> str:
        if self.ok:
            return "OK" + (f" {self.payload}" if self.payload else "")
        return f"ERR {self.code} {self.message}"


class ConsoleError(RuntimeError):
    """The drive answered ERR: ``code`` and ``name`` from the grammar."""

    def __init__(self, line: str, reply: Reply) -> None:
        self.code = reply.code
        self.name = reply.error_name
        self.reply = reply
        super().__init__(f"'{line}': ERR {reply.code} {reply.error_name}: {reply.message}")


def parse_number(text: str) -> float:
    """A NUMBER of the grammar, or nan/inf/-inf for measured values."""
    if text in MEASURED_SPECIAL:
        return MEASURED_SPECIAL[text]
    if not NUMBER_RE.fullmatch(text):
        raise ConsoleProtocolError(f"{text!r} is not a NUMBER")
    return float(text)


def format_number(value: float) -> str:
    """The shortest NUMBER that reads back as the same float32."""
    v = np.float32(value)
    text = np.format_float_positional(v, unique=True, trim="-")
    if len(text) > 14:
        text = np.format_float_scientific(v, unique=True, trim="-")
    return text


# --------------------------------------------------------------------------------------
# The client


@dataclass
class ConsoleClient:
    """One session on the drive's console."""

    port: str
    timeout_s: float = 2.0
    baudrate: int = 115200
    grammar: Grammar = field(default_factory=grammar)
    _ser: Any = None
    lines_sent: int = 0

    def open(self) -> ConsoleClient:
        try:
            self._ser = serial.serial_for_url(
                self.port, baudrate=self.baudrate, bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE, xonxoff=False,
                rtscts=False, timeout=min(0.1, self.timeout_s), write_timeout=self.timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConsoleLinkError(f"console {self.port}: cannot open: {exc}") from exc
        return self

    def close(self) -> None:
        if self._ser is not None:
            self._ser.close()
            self._ser = None

    def __enter__(self) -> ConsoleClient:
        return self.open() if self._ser is None else self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- lines -------------------------------------------------------------------------
    def write_raw(self, data: bytes) -> None:
        if self._ser is None:
            raise ConsoleLinkError(f"console {self.port}: not open")
        try:
            self._ser.write(data)
            self._ser.flush()
        except (serial.SerialException, OSError) as exc:
            raise ConsoleLinkError(f"console {self.port}: write failed: {exc}") from exc

    def read_reply(self, what: str = "the last line") -> Reply:
        """Data lines up to and including the final OK / ERR line."""
        deadline = time.monotonic() + self.timeout_s
        data: list[str] = []
        buf = b""
        prefix = self.grammar.data_prefix
        while True:
            if time.monotonic() > deadline:
                got = f" (received so far: {buf!r})" if buf or data else ""
                raise ConsoleTimeout(f"console {self.port}: no reply to {what} within "
                                     f"{self.timeout_s:g} s{got}; is the drive powered and "
                                     "the port right?")
            try:
                chunk = self._ser.readline()
            except (serial.SerialException, OSError) as exc:
                raise ConsoleLinkError(f"console {self.port}: read failed: {exc}") from exc
            buf += chunk
            if not buf.endswith(b"\n"):
                continue
            raw, buf = buf, b""
            if not raw.endswith(b"\r\n"):
                raise ConsoleProtocolError(f"console {self.port}: line without CR LF: {raw!r}")
            text = raw[:-2].decode("ascii", errors="replace")
            if text.startswith(prefix):
                data.append(text[len(prefix):])
                continue
            return self._final(text, tuple(data))

    def _final(self, text: str, data: tuple[str, ...]) -> Reply:
        if text == "OK" or text.startswith("OK "):
            return Reply(text, True, payload=text[3:], data=data)
        m = re.fullmatch(r"ERR (\d+) (.*)", text)
        if m:
            code = int(m.group(1))
            return Reply(text, False, code=code, error_name=self.grammar.errors.get(
                code, "UNKNOWN"), message=m.group(2), data=data)
        raise ConsoleProtocolError(f"console {self.port}: unexpected line {text!r}")

    def request(self, line: str) -> Reply:
        """Sends one line as it is (CR LF appended) and returns the reply."""
        if self._ser is None:
            self.open()
        self._ser.reset_input_buffer()  # a late reply to a timed-out request is stale
        self.write_raw(line.encode("ascii", errors="strict") + b"\r\n")
        self.lines_sent += 1
        return self.read_reply(f"'{line}'")

    def call(self, name: str, *args: object) -> Reply:
        """A grammar-checked command; ERR raises ConsoleError."""
        words = [format_number(a) if isinstance(a, float) else str(a) for a in args]
        self.grammar.check(name, words)
        line = " ".join([name, *words])
        if len(line) > self.grammar.max_line:
            raise ConsoleUsageError(f"'{line}' is longer than {self.grammar.max_line} characters")
        reply = self.request(line)
        if not reply.ok:
            raise ConsoleError(line, reply)
        return reply

    # -- typed helpers (each checked against the grammar by call()) ----------------------
    def ping(self) -> None:
        self.call("ping")

    def help(self) -> list[str]:
        return list(self.call("help").data)

    def version(self) -> dict[str, str]:
        return self.call("version").fields()

    def status(self) -> dict[str, str]:
        return self.call("status").fields()

    def counters(self) -> dict[str, str]:
        return self.call("counters").fields()

    def params(self) -> list[dict[str, str]]:
        rows = []
        for line in self.call("params").data:
            rows.append(Reply(line, True, payload=line).fields())
        return rows

    def get(self, name: str) -> float:
        return self.call("get", name).number()

    def set(self, name: str, value: float) -> float:
        """Writes a parameter; the reply's value and a second read must match float32(value)."""
        echoed = self.call("set", name, float(value)).number()
        again = self.get(name)
        want = float(np.float32(value))
        if echoed != again or not _same_float32(again, want):
            raise ConsoleProtocolError(f"set {name} {value}: the drive echoed {echoed}, "
                                       f"reads back {again}")
        return again

    def enable(self) -> None:
        self.call("enable")

    def disable(self) -> None:
        self.call("disable")

    def reset(self) -> None:
        self.call("reset")

    def speed(self, rpm: float) -> float:
        return self.call("speed", float(rpm)).number()

    def iq(self, amps: float) -> float:
        return self.call("iq", float(amps)).number()

    def mode(self, mode: str) -> str:
        return self.call("mode", mode).payload

    def fwmode(self, mode: str) -> str:
        return self.call("fwmode", mode).payload

    def save(self) -> int:
        return int(self.call("save").number())

    def load(self) -> int:
        return int(self.call("load").number())


def _same_float32(a: float, b: float) -> bool:
    return bool(np.float32(a) == np.float32(b))
