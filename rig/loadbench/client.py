"""The load bench over Modbus: the register map (protocols/modbus_load_bench.json) and the
rig's client, ``LoadBench`` (pymodbus, TCP or RTU, from a bench description).

Every write is read back: the client reads the field again after the server acknowledged the
write and raises :class:`ReadbackError` when the value differs. A Modbus exception response
raises :class:`ModbusExceptionError` with the code (1 illegal function, 2 illegal data
address, 3 illegal data value, 4 server device failure); no answer within the time-out or a
peer that cannot be reached raises :class:`LoadBenchError` naming the endpoint.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import math
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, Literal

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.client.mixin import ModbusClientMixin
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType
from pymodbus.pdu import ExceptionResponse

from rig._paths import data_dir
from rig.bench.description import ModbusSpec

MAP_FILE = "modbus_load_bench.json"
Table = Literal["holding", "input"]
_DT = ModbusClientMixin.DATATYPE
_TYPES: dict[str, tuple[Any, int]] = {
    "uint16": (_DT.UINT16, 1), "int16": (_DT.INT16, 1), "uint32": (_DT.UINT32, 2),
    "int32": (_DT.INT32, 2), "float32": (_DT.FLOAT32, 2),
}
EXCEPTION_NAMES = {1: "ILLEGAL FUNCTION", 2: "ILLEGAL DATA ADDRESS", 3: "ILLEGAL DATA VALUE",
                   4: "SERVER DEVICE FAILURE", 5: "ACKNOWLEDGE", 6: "SERVER DEVICE BUSY",
                   10: "GATEWAY PATH UNAVAILABLE", 11: "GATEWAY TARGET FAILED TO RESPOND"}

# pymodbus logs every failed attempt at warning/error level; the client raises instead
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


# --------------------------------------------------------------------------------------
# The register map


@dataclass(frozen=True)
class Field:
    """One value of the map (1 or 2 registers)."""

    name: str
    table: Table
    address: int
    type: str
    access: str = "ro"
    unit: str = "-"
    default: float = 0.0
    minimum: float | None = None
    maximum: float | None = None
    enum: Mapping[str, int] = field(default_factory=dict)
    enum_load_cmd: Mapping[int, str] = field(default_factory=dict)
    bits: Mapping[str, int] = field(default_factory=dict)
    description: str = ""

    @property
    def count(self) -> int:
        return _TYPES[self.type][1]

    @property
    def is_float(self) -> bool:
        return self.type == "float32"

    def encode(self, value: float, word_order: Literal["big", "little"] = "big") -> list[int]:
        v: float | int = float(value) if self.is_float else int(value)
        return ModbusClientMixin.convert_to_registers(v, _TYPES[self.type][0], word_order)

    def decode(self, regs: Sequence[int], word_order: Literal["big", "little"] = "big"
               ) -> float | int:
        out = ModbusClientMixin.convert_from_registers(list(regs), _TYPES[self.type][0],
                                                       word_order)
        assert isinstance(out, int | float)
        return out

    def problem(self, value: float) -> str | None:
        """Why a value may not be written to this field, or None."""
        if not math.isfinite(value):
            return f"{self.name}: {value} is not finite"
        if not self.is_float and value != int(value):
            return f"{self.name}: {value} is not a whole number"
        if self.enum and int(value) not in self.enum.values():
            return f"{self.name}: {value:g} is not one of {dict(self.enum)}"
        if self.minimum is not None and value < self.minimum:
            return f"{self.name}: {value:g} below {self.minimum:g} {self.unit}"
        if self.maximum is not None and value > self.maximum:
            return f"{self.name}: {value:g} above {self.maximum:g} {self.unit}"
        if self.bits and int(value) & ~sum(1 << b for b in self.bits.values()):
            return f"{self.name}: undefined bits set in {int(value):#06x}"
        return None


@dataclass(frozen=True)
class RegisterMap:
    version: int
    word_order: Literal["big", "little"]
    holding: Mapping[str, Field]
    input: Mapping[str, Field]
    path: Path
    function_codes: tuple[int, ...]  # the Modbus function codes the device answers

    def table(self, table: Table) -> Mapping[str, Field]:
        return self.holding if table == "holding" else self.input

    def span(self, table: Table) -> tuple[int, int]:
        """(first address, register count) of a table (contiguous by construction)."""
        fs = list(self.table(table).values())
        first = min(f.address for f in fs)
        return first, max(f.address + f.count for f in fs) - first

    def decode_table(self, table: Table, regs: Sequence[int], first: int = 0
                     ) -> dict[str, float | int]:
        out: dict[str, float | int] = {}
        for f in self.table(table).values():
            lo = f.address - first
            if lo >= 0 and lo + f.count <= len(regs):
                out[f.name] = f.decode(regs[lo:lo + f.count], self.word_order)
        return out

    def fields_touched(self, table: Table, address: int, count: int) -> list[Field]:
        return [f for f in self.table(table).values()
                if f.address < address + count and address < f.address + f.count]

    def mode_value(self, name: str) -> int:
        return int(self.holding["mode"].enum[name])

    def mode_name(self, value: int) -> str:
        for name, v in self.holding["mode"].enum.items():
            if v == value:
                return name
        return f"unknown({value})"


def _field(table: Table, raw: Mapping[str, Any]) -> Field:
    enum = {str(e["name"]): int(e["value"]) for e in raw.get("enum", [])}
    load_cmd = {int(e["value"]): str(e["load_cmd"]) for e in raw.get("enum", [])
                if "load_cmd" in e}
    bits = {str(b["name"]): int(b["bit"]) for b in raw.get("bits", [])}
    if raw["type"] not in _TYPES:
        raise ValueError(f"{raw['name']}: unknown type {raw['type']!r}")
    return Field(
        name=str(raw["name"]), table=table, address=int(raw["address"]), type=str(raw["type"]),
        access=str(raw.get("access", "ro" if table == "input" else "rw")),
        unit=str(raw.get("unit", "-")), default=float(raw.get("default", 0.0)),
        minimum=None if raw.get("min") is None else float(raw["min"]),
        maximum=None if raw.get("max") is None else float(raw["max"]),
        enum=enum, enum_load_cmd=load_cmd, bits=bits, description=str(raw.get("description", "")),
    )


@cache
def register_map(path: Path | None = None) -> RegisterMap:
    """The load bench register map (checked: no overlaps, no gaps, known types)."""
    p = path or data_dir("protocols") / MAP_FILE
    data = json.loads(p.read_text())
    order = data["encoding"]["word_order"]
    if order not in ("big", "little"):
        raise ValueError(f"{p}: encoding.word_order must be big or little")
    tables: dict[str, dict[str, Field]] = {}
    for table in ("holding", "input"):
        fs = [_field(table, raw) for raw in data[table]]  # type: ignore[arg-type]
        fs.sort(key=lambda f: f.address)
        for a, b in itertools.pairwise(fs):
            if a.address + a.count != b.address:
                raise ValueError(f"{p}: {table} registers {a.name} and {b.name} overlap or "
                                 "leave a gap (the table must be contiguous)")
        tables[table] = {f.name: f for f in fs}
    fcs = tuple(sorted(int(fc) for fc in data["function_codes"]))
    return RegisterMap(int(data["version"]), order, tables["holding"], tables["input"], p, fcs)


# --------------------------------------------------------------------------------------
# The client


@contextlib.contextmanager
def _pymodbus_errors() -> Iterator[list[str]]:
    """Collects what pymodbus logs as errors meanwhile (its connect() only returns False)."""
    found: list[str] = []

    class Catch(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            found.append(record.getMessage())

    logger = logging.getLogger("pymodbus")
    handler = Catch(logging.ERROR)
    old = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.ERROR)
    try:
        yield found
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)


class LoadBenchError(RuntimeError):
    """The load bench cannot be reached or did not answer in time."""


class ModbusExceptionError(LoadBenchError):
    """The load bench answered with a Modbus exception response."""

    def __init__(self, what: str, code: int) -> None:
        self.code = code
        self.exception_name = EXCEPTION_NAMES.get(code, "unknown exception")
        super().__init__(f"{what}: Modbus exception {code} ({self.exception_name})")


class ReadbackError(LoadBenchError):
    """A written value did not read back as written."""


@dataclass(frozen=True)
class BenchMeasurement:
    shaft_torque: float
    speed_rpm: float
    load_torque: float
    sample_counter: int
    status: Mapping[str, bool]
    faults: Mapping[str, bool]
    raw: Mapping[str, float | int]


class LoadBench:
    """The rig's Modbus client of the load bench. Use as a context manager."""

    def __init__(self, spec: ModbusSpec, regmap: RegisterMap | None = None) -> None:
        self.spec = spec
        self.map = regmap or register_map()
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._wd_value = 0
        self._wd_sent = 0.0
        self.writes = 0
        self.reads = 0

    # -- connection --------------------------------------------------------------------
    @property
    def endpoint(self) -> str:
        return self.spec.endpoint()

    def open(self) -> LoadBench:
        s = self.spec
        if s.kind == "tcp":
            client: ModbusTcpClient | ModbusSerialClient = ModbusTcpClient(
                s.host, port=s.port, timeout=s.timeout_s, retries=0, reconnect_delay=0.0)
        else:
            client = ModbusSerialClient(
                s.device, framer=FramerType.RTU, baudrate=s.baudrate, bytesize=8,
                parity=s.parity, stopbits=s.stopbits, timeout=s.timeout_s, retries=0,
                reconnect_delay=0.0)
        t0 = time.monotonic()
        with _pymodbus_errors() as why:
            try:
                ok = client.connect()
            except Exception as exc:  # pyserial / socket errors surface with various types
                raise LoadBenchError(f"{self.endpoint}: cannot connect: {exc}") from exc
        if not ok:
            client.close()
            reason = f": {why[-1]}" if why else " (no server there?)"
            raise LoadBenchError(f"{self.endpoint}: cannot connect{reason}; gave up after "
                                 f"{time.monotonic() - t0:.2f} s")
        self._client = client
        try:
            version = int(self.read("holding", "map_version"))
        except LoadBenchError:
            self.close()  # release the port (a serial port is locked while open)
            raise
        if version != self.map.version:
            self.close()
            raise LoadBenchError(f"{self.endpoint}: register map version {version}, the rig "
                                 f"speaks version {self.map.version} ({self.map.path.name})")
        return self

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    def __enter__(self) -> LoadBench:
        return self.open() if self._client is None else self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- raw access --------------------------------------------------------------------
    def _call(self, what: str, fn: Any, *args: Any, **kwargs: Any) -> Any:
        if self._client is None:
            raise LoadBenchError(f"{self.endpoint}: not connected")
        t0 = time.monotonic()
        try:
            rr = fn(*args, device_id=self.spec.unit, **kwargs)
        except ModbusException as exc:
            raise LoadBenchError(f"{self.endpoint}: {what}: no valid answer within "
                                 f"{self.spec.timeout_s:g} s ({time.monotonic() - t0:.2f} s "
                                 f"elapsed): {exc}") from exc
        except OSError as exc:
            raise LoadBenchError(f"{self.endpoint}: {what}: {exc}") from exc
        if isinstance(rr, ExceptionResponse):
            raise ModbusExceptionError(f"{self.endpoint}: {what}", int(rr.exception_code))
        if rr.isError():
            raise LoadBenchError(f"{self.endpoint}: {what}: error response {rr}")
        return rr

    def read_registers(self, table: Table, address: int, count: int) -> list[int]:
        c = self._client
        if c is None:
            raise LoadBenchError(f"{self.endpoint}: not connected")
        fn = c.read_holding_registers if table == "holding" else c.read_input_registers
        rr = self._call(f"read {table} {address}+{count}", fn, address, count=count)
        self.reads += 1
        return list(rr.registers)

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        c = self._client
        if c is None:
            raise LoadBenchError(f"{self.endpoint}: not connected")
        self._call(f"write holding {address}+{len(values)}", c.write_registers, address,
                   list(values))
        self.writes += 1

    # -- fields ------------------------------------------------------------------------
    def read(self, table: Table, name: str) -> float | int:
        f = self.map.table(table)[name]
        return f.decode(self.read_registers(table, f.address, f.count), self.map.word_order)

    def read_table(self, table: Table) -> dict[str, float | int]:
        first, count = self.map.span(table)
        return self.map.decode_table(table, self.read_registers(table, first, count), first)

    def write(self, name: str, value: float, *, verify: bool = True) -> float | int:
        """Writes one holding field and reads it back (the value the bench holds now)."""
        f = self.map.holding[name]
        self.write_registers(f.address, f.encode(value, self.map.word_order))
        if not verify:
            return value
        got = self.read("holding", name)
        want = f.decode(f.encode(value, self.map.word_order), self.map.word_order)
        if got != want:
            raise ReadbackError(f"{self.endpoint}: {name} written {want!r}, read back {got!r}")
        return got

    # -- the load ----------------------------------------------------------------------
    def off(self) -> None:
        """Load machine off and torque setpoint 0 (both read back)."""
        self.write("mode", self.map.mode_value("off"))
        self.write("torque_setpoint", 0.0)

    def torque_mode(self, torque_nm: float, k_speed: float = 0.0) -> None:
        self.write("k_speed", k_speed)
        self.write("torque_setpoint", torque_nm)
        self._activate("torque")

    def set_torque(self, torque_nm: float) -> None:
        self.write("torque_setpoint", torque_nm)

    def speed_hold(self, speed_rpm: float) -> None:
        self.write("speed_setpoint", speed_rpm)
        self._activate("speed_hold")

    def set_speed(self, speed_rpm: float) -> None:
        self.write("speed_setpoint", speed_rpm)

    def _activate(self, mode: str) -> None:
        want = self.map.mode_value(mode)
        if int(self.read("holding", "mode")) != want:
            self.refresh_watchdog(force=True)
            self.write("mode", want)

    def reset_faults(self) -> None:
        bit = self.map.holding["control"].bits["fault_reset"]
        self.write_registers(self.map.holding["control"].address, [1 << bit])
        if self.faults():
            raise ReadbackError(f"{self.endpoint}: faults still latched after fault_reset: "
                                f"{self.faults()}")

    def refresh_watchdog(self, force: bool = False) -> None:
        """Writes a new watchdog value (at most every quarter time-out unless forced)."""
        now = time.monotonic()
        if not force and now - self._wd_sent < self.spec.watchdog_timeout_ms / 4000.0:
            return
        self._wd_value = (self._wd_value + 1) % 65536
        self.write("watchdog", self._wd_value)
        self._wd_sent = now

    def set_watchdog_timeout(self, ms: int) -> None:
        self.write("watchdog_timeout_ms", ms)

    # -- measurements ------------------------------------------------------------------
    def _bits(self, field_name: str, value: int) -> dict[str, bool]:
        f = self.map.input[field_name]
        return {name: bool(value >> bit & 1) for name, bit in f.bits.items()}

    def measure(self) -> BenchMeasurement:
        raw = self.read_table("input")
        return BenchMeasurement(
            shaft_torque=float(raw["shaft_torque"]), speed_rpm=float(raw["speed"]),
            load_torque=float(raw["load_torque"]), sample_counter=int(raw["sample_counter"]),
            status=self._bits("status", int(raw["status"])),
            faults=self._bits("fault", int(raw["fault"])), raw=raw)

    def faults(self) -> list[str]:
        value = int(self.read("input", "fault"))
        return [name for name, on in self._bits("fault", value).items() if on]
