"""Reader of the core journal a bench writes (``bench/include/core_journal.h``): every call
into the control core with its inputs and the host build's outputs."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

MAGIC = b"FWJ1"
VERSION = 1
SIZE_NAMES = ("fw_core_t", "fw_adc_t", "fw_pwm_t", "fw_cmd_t", "fw_status_t")
PWM = struct.Struct("<I3H3Hh16Hh")  # fw_pwm_t: period, cmp_up, cmp_dn, n_soc, soc, gate_enable


def _pad(n: int) -> int:
    return (n + 3) & ~3


@dataclass(frozen=True)
class Pwm:
    """The fields of fw_pwm_t that reach the inverter and the ADC (SOCs past n_soc do not)."""

    period: int
    cmp_up: tuple[int, ...]
    cmp_dn: tuple[int, ...]
    n_soc: int
    soc: tuple[int, ...]
    gate_enable: int

    @classmethod
    def unpack(cls, raw: bytes) -> Pwm:
        v = PWM.unpack_from(raw)
        n_soc = v[7]
        return cls(v[0], v[1:4], v[4:7], n_soc, v[8:8 + max(0, min(16, n_soc))], v[24])


@dataclass(frozen=True)
class Record:
    tag: str  # P, S, C, L, I
    isr: int  # fw_core_isr calls before this one
    payload: bytes


@dataclass(frozen=True)
class Isr:
    has_adc: bool
    adc: bytes
    pwm: bytes
    crc: int
    state: int


class Journal:
    def __init__(self, path: Path) -> None:
        raw = path.read_bytes()
        if raw[:4] != MAGIC:
            raise ValueError(f"{path}: not a core journal")
        version = struct.unpack_from("<I", raw, 4)[0]
        if version != VERSION:
            raise ValueError(f"{path}: journal version {version}, this reader knows {VERSION}")
        self.sizes = list(struct.unpack_from("<5I", raw, 8))
        self.path = path
        self._raw = raw

    def size(self, name: str) -> int:
        return self.sizes[SIZE_NAMES.index(name)]

    def _payload_size(self, tag: str) -> int:
        core, adc, pwm, cmd, _status = self.sizes
        return {"P": 8, "S": _pad(core), "C": _pad(cmd) + 4, "L": 16,
                "I": 4 + _pad(adc) + _pad(pwm) + 8}[tag]

    def records(self) -> Iterator[Record]:
        raw, off = self._raw, 28
        while off < len(raw):
            tag_code, isr = struct.unpack_from("<II", raw, off)
            tag = chr(tag_code)
            n = self._payload_size(tag)
            if off + 8 + n > len(raw):
                raise ValueError(f"{self.path}: truncated record {tag!r} at byte {off}")
            yield Record(tag, isr, raw[off + 8:off + 8 + n])
            off += 8 + n

    def isr(self, rec: Record) -> Isr:
        adc, pwm = _pad(self.size("fw_adc_t")), _pad(self.size("fw_pwm_t"))
        p = rec.payload
        has = struct.unpack_from("<I", p)[0]
        crc, state = struct.unpack_from("<Ii", p, 4 + adc + pwm)
        return Isr(bool(has), p[4:4 + self.size("fw_adc_t")],
                   p[4 + adc:4 + adc + self.size("fw_pwm_t")], crc, state)
