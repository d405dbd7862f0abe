"""The wire definitions in protocols/ (DBC files), loaded once per process."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import cantools
from cantools.database.can import Database

from rig._paths import data_dir

DATABASES = ("drive", "vio", "bench")


def path(name: str) -> Path:
    if name not in DATABASES:
        raise ValueError(f"unknown protocol {name!r}; one of {', '.join(DATABASES)}")
    return data_dir("protocols") / f"{name}.dbc"


@cache
def database(name: str) -> Database:
    db = cantools.database.load_file(str(path(name)), strict=True)
    assert isinstance(db, Database)
    return db


@cache
def choices(db: str, message: str, signal: str) -> dict[str, int]:
    """A signal's value table (the DBC's ``VAL_``): lower-case name -> raw value."""
    sig = database(db).get_message_by_name(message).get_signal_by_name(signal)
    return {str(name).lower(): int(value) for value, name in (sig.choices or {}).items()}


def names(db: str, message: str, signal: str) -> dict[int, str]:
    """The inverse of ``choices``: raw value -> the DBC's name (as the DBC spells it)."""
    sig = database(db).get_message_by_name(message).get_signal_by_name(signal)
    return {int(value): str(name) for value, name in (sig.choices or {}).items()}


def value_name(db: str, message: str, signal: str, value: float | None) -> str | None:
    """The DBC's name of one raw value of a signal (``RUN`` for DRIVE_STATUS.state 3); None
    when the value is not a whole number its value table names."""
    if value is None or value != value or value in (float("inf"), float("-inf")):
        return None
    if float(value) != int(value):
        return None
    return names(db, message, signal).get(int(value))


def named_value(db: str, message: str, signal: str, value: float | None) -> str:
    """A value of an enumerated signal as a person reads it: its DBC name with the number
    beside it (``RUN (3)``), the number alone where the table has no name for it."""
    name = value_name(db, message, signal, value)
    number = "n/a" if value is None else f"{value:g}"
    return f"{name} ({number})" if name is not None else number


def spelled(db: str, message: str, signal: str) -> dict[str, int]:
    """A signal's value table keyed as the DBC spells the names (``IDLE``, as the generated C
    constants are): the inverse of ``names``."""
    return {name: value for value, name in names(db, message, signal).items()}


def cycle_s(db: str, message: str) -> float:
    """A cyclic message's period (the DBC's ``GenMsgCycleTime``), s."""
    ms = database(db).get_message_by_name(message).cycle_time
    if not ms:
        raise ValueError(f"protocols/{db}.dbc: {message} has no GenMsgCycleTime")
    return ms / 1000.0


def quantize(db: str, message: str, signal: str, value: float) -> float:
    """The physical value a signal actually carries for `value` (nearest raw step)."""
    sig = database(db).get_message_by_name(message).get_signal_by_name(signal)
    raw = round((value - float(sig.offset)) / float(sig.scale))
    return raw * float(sig.scale) + float(sig.offset)


@dataclass(frozen=True)
class TimeBase:
    """The PWM time base every program shares (docs/interfaces.md): defined once, as database
    attributes of the DBC files (vio.dbc ``HilTbclkHz``, ``HilTbprd``; drive.dbc
    ``HilSpeedLoopDivider``), from which the C programs get theirs generated at build time
    (firmware_c2000/tools/gen_wire.py, which also checks the ranges that follow from it)."""

    tbclk_hz: int  # ticks per second
    tbprd: int  # up-down count half period, ticks
    speed_loop_divider: int  # PWM periods per speed-loop (and telemetry) period

    @property
    def period_ticks(self) -> int:
        return 2 * self.tbprd

    @property
    def ts(self) -> float:
        """One PWM period, s."""
        return self.period_ticks / self.tbclk_hz

    @property
    def period_ns(self) -> int:
        return self.period_ticks * 1_000_000_000 // self.tbclk_hz


def _attribute(db: str, name: str) -> int:
    dbc = database(db).dbc
    attr = dbc.attributes.get(name) if dbc is not None else None
    if attr is None or not isinstance(attr.value, int):
        raise ValueError(f"protocols/{db}.dbc: database attribute {name} missing")
    return attr.value


@cache
def timebase() -> TimeBase:
    return TimeBase(_attribute("vio", "HilTbclkHz"), _attribute("vio", "HilTbprd"),
                    _attribute("drive", "HilSpeedLoopDivider"))



def id_range(db: str) -> tuple[int, int]:
    """The 11-bit CAN IDs a database owns, (first, last) both included: its attributes
    ``HilIdFirst``, ``HilIdLast`` (the C programs get theirs generated into hil_wire.h)."""
    return _attribute(db, "HilIdFirst"), _attribute(db, "HilIdLast")
