"""The little of ELF32 (little-endian) the emulator needs: loadable segments and symbols."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

PT_LOAD = 1
SHT_SYMTAB = 2


@dataclass(frozen=True)
class Segment:
    paddr: int  # where the image holds it (flash: .data's initial values sit there)
    vaddr: int
    data: bytes
    memsz: int


@dataclass(frozen=True)
class Symbol:
    value: int
    size: int


@dataclass(frozen=True)
class Elf:
    entry: int
    segments: list[Segment]
    symbols: dict[str, Symbol]


def read(path: Path) -> Elf:
    raw = path.read_bytes()
    if raw[:4] != b"\x7fELF" or raw[4] != 1 or raw[5] != 1:
        raise ValueError(f"{path}: not a little-endian ELF32 file")
    (entry, phoff, shoff) = struct.unpack_from("<III", raw, 24)
    (phentsize, phnum, shentsize, shnum) = struct.unpack_from("<HHHH", raw, 42)
    segments = []
    for i in range(phnum):
        p_type, p_offset, p_vaddr, p_paddr, p_filesz, p_memsz = struct.unpack_from(
            "<IIIIII", raw, phoff + i * phentsize)
        if p_type == PT_LOAD and p_filesz > 0:
            segments.append(Segment(p_paddr, p_vaddr, raw[p_offset:p_offset + p_filesz],
                                    p_memsz))
    sections = [struct.unpack_from("<IIIIIIIIII", raw, shoff + i * shentsize)
                for i in range(shnum)]
    symbols: dict[str, Symbol] = {}
    for sh in sections:
        if sh[1] != SHT_SYMTAB:
            continue
        strtab = sections[sh[6]]
        names = raw[strtab[4]:strtab[4] + strtab[5]]
        for off in range(sh[4], sh[4] + sh[5], 16):
            st_name, st_value, st_size = struct.unpack_from("<III", raw, off)
            if st_name:
                name = names[st_name:names.index(b"\0", st_name)].decode()
                symbols[name] = Symbol(st_value, st_size)
    return Elf(entry, segments, symbols)
