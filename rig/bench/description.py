"""Bench description files (TOML): where the drive, its console and the load bench are.

One file describes one bench, virtual or real, so the same commissioning scripts run on both:

    name = "lab"                        # free text
    description = "..."

    [can]                               # the drive protocol (protocols/drive.dbc)
    transport = "socketcan"             # auto | socketcan | unixcan
    channel = "can0"                    # default: none named (the virtual bench: a unixcan
                                        # channel of the session's own; else $HIL_CHANNEL,
                                        # else vcan0)

    [console]                           # the drive's SCI console (protocols/console.md)
    port = "/dev/ttyUSB0"               # device, pty path or pyserial URL (rfc2217://, socket://)
    baudrate = 115200
    timeout_s = 2.0                     # per reply

    [modbus]                            # the load bench (protocols/modbus_load_bench.json)
    kind = "tcp"                        # tcp | rtu
    host = "192.168.10.20"              # tcp
    port = 502                          # tcp
    device = "/dev/ttyUSB1"             # rtu (serial device)
    baudrate = 19200                    # rtu
    parity = "E"                        # rtu: N | E | O
    stopbits = 1                        # rtu
    unit = 1
    timeout_s = 1.0
    watchdog_timeout_ms = 1000

    [clock]
    mode = "wall"                       # wall (real bench) | lockstep (virtual: BENCH_STEP)
    grant_s = 0.05                      # lockstep: longest grant

    [virtual]                           # only for the emulated bench: what the rig starts
    profile = "paper"                   # plant_rt fidelity profile (name or file)
    programs = ["plant_rt", "fw_host", "loadbench"]
    ready_timeout_s = 120.0                # a ceiling for the programs to be ready
    truth_every = 10                    # plant: BENCH_TRUTH on the bus every N periods
    trace = false                       # plant.trace / fw.trace in the run folder
    [virtual.plant]                     # plant_rt --set KEY=VALUE (quoted dotted keys)
    "initial.theta_e_deg" = 0.0
    [virtual.firmware]                  # fw_host --set NAME=VALUE
    cmd_timeout_ms = 200

    [commissioning]                     # test levels of the scripts (see rig.commissioning.config)
    i_max_a = 4.0

Every field has a default except what a real bench must state. Unknown sections or keys are
errors (a typo must not silently fall back to a default). ``--set section.key=value`` on the
command line overrides any field (``virtual.plant.KEY`` and ``virtual.firmware.KEY`` take the
rest of the dotted name as the key).
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

BENCHES_DIR = Path(__file__).resolve().parents[1] / "benches"
PROGRAMS = ("plant_rt", "fw_host", "loadbench")


class BenchDescriptionError(ValueError):
    """A bench description that cannot be used: names the file and the field."""


@dataclass(frozen=True)
class CanSpec:
    transport: str = "auto"
    # "" names none: the virtual bench's session then gets a unixcan channel of its own
    # (rig.bus.own_channel), a real bench $HIL_CHANNEL, else vcan0
    channel: str = ""


@dataclass(frozen=True)
class ConsoleSpec:
    port: str = ""
    baudrate: int = 115200
    timeout_s: float = 2.0


@dataclass(frozen=True)
class ModbusSpec:
    kind: str = "tcp"
    host: str = "127.0.0.1"
    port: int = 5020
    device: str = ""
    baudrate: int = 19200
    parity: str = "E"
    stopbits: int = 1
    unit: int = 1
    timeout_s: float = 1.0
    watchdog_timeout_ms: int = 1000

    def endpoint(self) -> str:
        if self.kind == "tcp":
            return f"modbus tcp {self.host}:{self.port} unit {self.unit}"
        return (f"modbus rtu {self.device} {self.baudrate} 8{self.parity}{self.stopbits} "
                f"unit {self.unit}")


@dataclass(frozen=True)
class ClockSpec:
    mode: str = "wall"
    grant_s: float = 0.05


@dataclass(frozen=True)
class VirtualSpec:
    profile: str = "paper"
    programs: tuple[str, ...] = PROGRAMS
    ready_timeout_s: float = 120.0  # a ceiling for the programs to be ready (VM, loaded)
    truth_every: int = 10
    trace: bool = False
    plant: Mapping[str, Any] = field(default_factory=dict)
    firmware: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class BenchDescription:
    name: str
    file: Path | None
    description: str = ""
    can: CanSpec = field(default_factory=CanSpec)
    console: ConsoleSpec = field(default_factory=ConsoleSpec)
    modbus: ModbusSpec = field(default_factory=ModbusSpec)
    clock: ClockSpec = field(default_factory=ClockSpec)
    virtual: VirtualSpec | None = None
    commissioning: Mapping[str, Any] = field(default_factory=dict)

    @property
    def lockstep(self) -> bool:
        return self.clock.mode == "lockstep"

    def starts(self, program: str) -> bool:
        """True when the rig starts this program of the virtual bench."""
        return self.virtual is not None and program in self.virtual.programs


_SECTIONS: dict[str, type] = {"can": CanSpec, "console": ConsoleSpec, "modbus": ModbusSpec,
                              "clock": ClockSpec, "virtual": VirtualSpec}
_TOP = {"name", "description", *(_SECTIONS), "commissioning"}
_CHOICES = {("can", "transport"): ("auto", "socketcan", "unixcan"),
            ("modbus", "kind"): ("tcp", "rtu"), ("modbus", "parity"): ("N", "E", "O"),
            ("clock", "mode"): ("wall", "lockstep")}


def resolve(name_or_path: str | Path) -> Path:
    """A bench file: a path, or the name of a shipped description (rig/benches/NAME.toml)."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    shipped = BENCHES_DIR / f"{name_or_path}.toml"
    if shipped.is_file():
        return shipped
    names = ", ".join(sorted(x.stem for x in BENCHES_DIR.glob("*.toml")))
    raise BenchDescriptionError(f"{name_or_path}: no such bench file (shipped: {names})")


def load(name_or_path: str | Path, overrides: Sequence[str] = ()) -> BenchDescription:
    """Reads and checks a bench description; ``overrides`` are ``section.key=value`` strings."""
    path = resolve(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise BenchDescriptionError(f"{path}: {exc}") from exc
    for item in overrides:
        apply_override(data, item, str(path))
    return from_mapping(data, path)


def apply_override(data: dict[str, Any], item: str, where: str = "--set") -> None:
    key, sep, raw = item.partition("=")
    if not sep or not key.strip():
        raise BenchDescriptionError(f"{where}: override {item!r} is not section.key=value")
    parts = key.strip().split(".")
    if parts[:2] in (["virtual", "plant"], ["virtual", "firmware"]) and len(parts) > 2:
        parts = [*parts[:2], ".".join(parts[2:])]
    value = parse_value(raw.strip())
    target = data
    for p in parts[:-1]:
        nxt = target.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise BenchDescriptionError(f"{where}: {key}: {p} is not a table")
        target = nxt
    target[parts[-1]] = value


def parse_value(raw: str) -> Any:
    """A TOML value (number, boolean, string, array); a bare word is a string."""
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw


def from_mapping(data: Mapping[str, Any], path: Path | None = None) -> BenchDescription:
    where = str(path) if path else "<bench>"
    unknown = set(data) - _TOP
    if unknown:
        raise BenchDescriptionError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} "
                                    f"(allowed: {', '.join(sorted(_TOP))})")
    built: dict[str, Any] = {}
    for section, cls in _SECTIONS.items():
        if section not in data:
            continue
        raw = data[section]
        if not isinstance(raw, Mapping):
            raise BenchDescriptionError(f"{where}: [{section}] must be a table")
        built[section] = _section(cls, section, raw, where)
    commissioning = data.get("commissioning", {})
    if not isinstance(commissioning, Mapping):
        raise BenchDescriptionError(f"{where}: [commissioning] must be a table")
    name = data.get("name", path.stem if path else "bench")
    desc = BenchDescription(name=str(name), file=path, description=str(data.get("description", "")),
                            commissioning=dict(commissioning), **built)
    _cross_checks(desc, where)
    return desc


def _section(cls: type, section: str, raw: Mapping[str, Any], where: str) -> Any:
    known = {f.name: f for f in fields(cls)}
    unknown = set(raw) - set(known)
    if unknown:
        raise BenchDescriptionError(f"{where}: [{section}] unknown key(s) "
                                    f"{', '.join(sorted(unknown))} (allowed: "
                                    f"{', '.join(sorted(known))})")
    defaults = cls()
    values: dict[str, Any] = {}
    for key, value in raw.items():
        default = getattr(defaults, key)
        values[key] = _coerce(value, default, f"{where}: {section}.{key}")
        choices = _CHOICES.get((section, key))
        if choices and values[key] not in choices:
            raise BenchDescriptionError(f"{where}: {section}.{key} = {value!r}: one of "
                                        f"{', '.join(choices)}")
    return replace(defaults, **values)


def _coerce(value: Any, default: Any, what: str) -> Any:
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise BenchDescriptionError(f"{what}: expected true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise BenchDescriptionError(f"{what}: expected a whole number, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise BenchDescriptionError(f"{what}: expected a number, got {value!r}")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise BenchDescriptionError(f"{what}: expected a string, got {value!r}")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise BenchDescriptionError(f"{what}: expected a list of strings, got {value!r}")
        return tuple(value)
    if isinstance(default, Mapping):
        if not isinstance(value, Mapping):
            raise BenchDescriptionError(f"{what}: expected a table, got {value!r}")
        return dict(value)
    return value


def _cross_checks(desc: BenchDescription, where: str) -> None:
    m = desc.modbus
    if m.kind == "rtu" and not m.device:
        raise BenchDescriptionError(f"{where}: modbus.kind = 'rtu' needs modbus.device")
    if not 0 <= m.unit <= 247:
        raise BenchDescriptionError(f"{where}: modbus.unit = {m.unit}: 0 … 247")
    if not 0 <= m.port <= 65535:
        raise BenchDescriptionError(f"{where}: modbus.port = {m.port}: 0 … 65535")
    if m.timeout_s <= 0 or desc.console.timeout_s <= 0:
        raise BenchDescriptionError(f"{where}: time-outs must be positive")
    if not 100 <= m.watchdog_timeout_ms <= 60000:
        raise BenchDescriptionError(f"{where}: modbus.watchdog_timeout_ms: 100 … 60000")
    if desc.clock.grant_s <= 0:
        raise BenchDescriptionError(f"{where}: clock.grant_s must be positive")
    v = desc.virtual
    if v is None:
        if desc.lockstep:
            raise BenchDescriptionError(f"{where}: clock.mode = 'lockstep' needs a [virtual] "
                                        "bench (a real bench runs on the wall clock)")
        if not desc.console.port:
            raise BenchDescriptionError(f"{where}: console.port is required for a real bench")
        return
    bad = [p for p in v.programs if p not in PROGRAMS]
    if bad:
        raise BenchDescriptionError(f"{where}: virtual.programs: unknown {', '.join(bad)} "
                                    f"(known: {', '.join(PROGRAMS)})")
    if "loadbench" in v.programs and (m.kind != "tcp" or m.host != "127.0.0.1"):
        raise BenchDescriptionError(f"{where}: the virtual load bench serves Modbus TCP on "
                                    "127.0.0.1 only (modbus.kind = 'tcp', host = '127.0.0.1')")
    if not desc.console.port and "fw_host" not in v.programs:
        raise BenchDescriptionError(f"{where}: console.port is required when the rig does not "
                                    "start fw_host")
    if v.truth_every < 0:
        raise BenchDescriptionError(f"{where}: virtual.truth_every must be ≥ 0")
