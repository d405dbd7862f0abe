"""Which of ``fw_core_isr``'s named steps an instruction of the image belongs to.

``fw_core_isr`` (``firmware_c2000/core/src/fw_core.c``) is a sequence of static functions,
its steps (``take_period``, ``protect``, ``estimate``, ``supervise_estimate``,
``next_state``, ``outputs``, ``torque_model``, ``voltage_mean``), which GCC inlines into it
and interleaves. The image is built with ``-g`` (the same code bytes as without), and its
DWARF says which address ranges of ``fw_core_isr`` are an inlined instance of which step: the
inlined subroutines that are direct children of ``fw_core_isr`` (through lexical blocks).
A step GCC did not inline is a function of its own, called from ``fw_core_isr``'s code: the
call sites name it. Everything of ``fw_core_isr`` outside its steps is ``entry`` (the repeat
check, the ISR count, the copy of the PWM).

An instruction outside ``fw_core_isr`` (a callee: the reconstruction, the modulator, the C
library's ``sqrtf``) belongs to the step that called it: the counter keeps the step of the
last instruction of ``fw_core_isr``'s own code that ran (``StepMap.owner``).
"""

from __future__ import annotations

import bisect
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ISR = "fw_core_isr"
ENTRY = "entry"  # fw_core_isr's own code outside its steps


class StepMapError(ValueError):
    """An image whose debug information does not describe fw_core_isr's steps."""


@dataclass(frozen=True)
class StepMap:
    """fw_core_isr's address range and the steps its addresses belong to."""

    lo: int  # fw_core_isr's first address
    hi: int  # one past its last
    names: tuple[str, ...]  # ENTRY first, then the steps in source order
    # sorted, disjoint (start, end, step index) of the steps' code, inlined or not
    ranges: tuple[tuple[int, int, int], ...]

    def owner(self, address: int) -> int | None:
        """The step index of an instruction of fw_core_isr or of a step function (None: a
        callee, which belongs to the step that called it)."""
        starts = [r[0] for r in self.ranges]
        i = bisect.bisect_right(starts, address) - 1
        if i >= 0 and address < self.ranges[i][1]:
            return self.ranges[i][2]
        if self.lo <= address < self.hi:
            return 0
        return None


def _ranges_of(die: Any, cu: Any, range_lists: Any) -> list[tuple[int, int]]:
    """A DIE's address ranges (low/high pc, or a DWARF 4/5 range list)."""
    attrs = die.attributes
    if "DW_AT_low_pc" in attrs and "DW_AT_high_pc" in attrs:
        lo = attrs["DW_AT_low_pc"].value
        high = attrs["DW_AT_high_pc"]
        hi = high.value if high.form == "DW_FORM_addr" else lo + high.value
        return [(lo, hi)]
    if "DW_AT_ranges" not in attrs:
        return []
    top = cu.get_top_DIE().attributes
    base = top["DW_AT_low_pc"].value if "DW_AT_low_pc" in top else 0
    out = []
    for r in range_lists.get_range_list_at_offset(attrs["DW_AT_ranges"].value, cu=cu):
        if type(r).__name__ == "BaseAddressEntry":
            base = r.base_address
        elif getattr(r, "is_absolute", False):
            out.append((r.begin_offset, r.end_offset))
        else:
            out.append((base + r.begin_offset, base + r.end_offset))
    return [(a, b) for a, b in out if b > a]


def _name(die: Any) -> str:
    origin = die
    for attr in ("DW_AT_abstract_origin", "DW_AT_specification", "DW_AT_call_origin"):
        if attr in origin.attributes:
            origin = origin.get_DIE_from_attribute(attr)
    raw = origin.attributes.get("DW_AT_name")
    return raw.value.decode() if raw is not None else ""


def _external(call: Any) -> bool:
    """Whether a call site's callee is an external function (not a step of fw_core.c)."""
    for attr in ("DW_AT_call_origin", "DW_AT_abstract_origin"):
        if attr in call.attributes:
            origin = call.get_DIE_from_attribute(attr)
            return "DW_AT_external" in origin.attributes
    return True


def _children(die: Any) -> Iterable[Any]:
    """A DIE's children, lexical blocks opened."""
    for ch in die.iter_children():
        if ch.tag == "DW_TAG_lexical_block":
            yield from _children(ch)
        else:
            yield ch


def read(path: Path, functions: dict[str, tuple[int, int]]) -> StepMap:
    """The step map of the image at ``path`` (``functions``: the symbol table's function
    ranges by name, for steps that are functions of their own)."""
    from elftools.elf.elffile import ELFFile

    with path.open("rb") as f:
        e = ELFFile(f)
        if not e.has_dwarf_info():
            raise StepMapError(f"{path}: no debug information (built without -g?)")
        di = e.get_dwarf_info()
        range_lists = di.range_lists()
        for cu in di.iter_CUs():
            for die in cu.iter_DIEs():
                if (die.tag == "DW_TAG_subprogram" and _name(die) == ISR
                        and "DW_AT_low_pc" in die.attributes):
                    return _map(die, cu, range_lists, functions)
    raise StepMapError(f"{path}: no definition of {ISR} in its debug information")


def _map(isr: Any, cu: Any, range_lists: Any, functions: dict[str, tuple[int, int]]
         ) -> StepMap:
    lo, hi = _ranges_of(isr, cu, range_lists)[0]
    order: list[tuple[int, str]] = []  # (source line of the call, step)
    spans: dict[str, list[tuple[int, int]]] = {}
    for ch in _children(isr):
        if ch.tag == "DW_TAG_inlined_subroutine":
            name = _name(ch)
            spans.setdefault(name, []).extend(_ranges_of(ch, cu, range_lists))
        elif ch.tag in ("DW_TAG_call_site", "DW_TAG_GNU_call_site"):
            # a step GCC kept as a function of its own: a static function (the C library's
            # and libgcc's routines, called from the ISR's own code, are external)
            name = _name(ch)
            if name in functions and not _external(ch):
                spans.setdefault(name, []).append(functions[name])
            else:
                continue
        else:
            continue
        line = ch.attributes.get("DW_AT_call_line")
        order.append((line.value if line is not None else 1 << 30, name))
    if not spans:
        raise StepMapError(f"{ISR} has no steps in the image's debug information")
    names = [ENTRY]
    for _, name in sorted(order):
        if name not in names:
            names.append(name)
    ranges = sorted((a, b, names.index(n)) for n, rs in spans.items() for a, b in rs)
    return StepMap(lo, hi, tuple(names), tuple(ranges))
