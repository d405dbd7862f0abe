"""The control core's Cortex-M images (``firmware_c2000/target_m4``) under emulation.

Unicorn (QEMU's CPU models as a library) runs an image as its CPU: ``cortex-m4f``
(``fw_core_m4.elf``, the ``cortex-m4`` CPU with its single-precision FPU) or ``cortex-m3``
(``fw_core_m3.elf``, no FPU: the core's float arithmetic in libgcc's soft-float routines);
the harness maps flash and RAM as the linker script lays them out, runs the reset handler
(``.data``, ``.bss``, FPU on) and then calls the image's entry points (``target_entry.c``: no
arguments, inputs and outputs in RAM mailboxes), each until it returns to a stop address.
With ``count=True`` every executed basic block adds its instructions (Thumb-2: a halfword
starting with 0b11101, 0b11110 or 0b11111 opens a 32-bit instruction), so
``last_instructions`` is what the call executed, the C library's math included, and
``last_steps`` the same instructions by the step of ``fw_core_isr`` they ran for
(``rig.target_m4.steps``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from unicorn import UC_ARCH_ARM, UC_HOOK_BLOCK, UC_MODE_MCLASS, UC_MODE_THUMB, Uc
from unicorn import arm_const as A

from rig import _paths
from rig.target_m4 import elf, steps


@dataclass(frozen=True)
class Target:
    name: str
    image: str  # the image's file name in rig/_bin
    cpu: int  # unicorn's CPU model
    what: str


TARGETS = {t.name: t for t in (
    Target("cortex-m4f", "fw_core_m4.elf", A.UC_CPU_ARM_CORTEX_M4,
           "Cortex-M4F, single-precision FPU (hard float)"),
    Target("cortex-m3", "fw_core_m3.elf", A.UC_CPU_ARM_CORTEX_M3,
           "Cortex-M3, no FPU (soft float: libgcc's routines)"),
)}
DEFAULT_TARGET = "cortex-m4f"
ELF_NAME = TARGETS[DEFAULT_TARGET].image
FLASH = (0x0000_0000, 512 * 1024)
RAM = (0x2000_0000, 128 * 1024)
SCS = (0xE000_E000, 0x1000)  # system control space: the reset handler writes CPACR there
STOP = FLASH[0] + FLASH[1] - 0x10  # return address of every call: emulation stops there
CALL_LIMIT = 50_000_000  # instructions: a call that runs longer is a hang, not a slow ISR
# (the soft-float image's fw_core_init takes several million)


def image_path(target: str = DEFAULT_TARGET) -> Path:
    """The built image (``./hil install`` builds it when arm-none-eabi-gcc is installed)."""
    return _paths.binary(TARGETS[target].image)


def thumb_instructions(code: bytes) -> int:
    """Instructions in a run of Thumb-2 code (16- and 32-bit encodings)."""
    return thumb_mix(code)[0]


def thumb_mix(code: bytes) -> tuple[int, int, int]:
    """(instructions, floating-point instructions, divisions and square roots) in a run of
    Thumb-2 code. Floating point: the coprocessor 10/11 encodings (VFP: 0xEC../0xED../0xEE..
    with bits 11:9 of the second halfword 0b101); VDIV.F32 and VSQRT.F32 take 14 cycles on
    the Cortex-M4F, the rest one or two."""
    n = fp = slow = i = 0
    while i + 1 < len(code):
        hw1 = code[i] | code[i + 1] << 8
        if hw1 >> 11 in (0b11101, 0b11110, 0b11111) and i + 3 < len(code):
            hw2 = code[i + 2] | code[i + 3] << 8
            if hw1 & 0xEC00 == 0xEC00 and hw1 >> 13 == 0b111 and (hw2 >> 9) & 0x7 == 0b101:
                fp += 1
                is_div = hw1 & 0xFFB0 == 0xEE80 and hw2 & 0x0F50 == 0x0A00
                is_sqrt = hw1 & 0xFFBF == 0xEEB1 and hw2 & 0x0FD0 == 0x0AC0
                slow += is_div or is_sqrt
            i += 4
        else:
            i += 2
        n += 1
    return n, fp, slow


def thumb_starts(code: bytes) -> list[int]:
    """The offsets of the instructions in a run of Thumb-2 code."""
    out = []
    i = 0
    while i + 1 < len(code):
        out.append(i)
        hw1 = code[i] | code[i + 1] << 8
        i += 4 if hw1 >> 11 in (0b11101, 0b11110, 0b11111) and i + 3 < len(code) else 2
    return out


class M4Core:
    """One emulated Cortex-M CPU with the core's image loaded and reset (the name stays from
    when the M4F was the only target)."""

    def __init__(self, path: Path | None = None, count: bool = False,
                 target: str = DEFAULT_TARGET) -> None:
        self.target = TARGETS[target]
        path = path or image_path(target)
        self.image = elf.read(path)
        self.sym = self.image.symbols
        uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(self.target.cpu)
        for base, size in (FLASH, RAM, SCS):
            uc.mem_map(base, size)
        for seg in self.image.segments:
            uc.mem_write(seg.paddr, seg.data)
        self.uc = uc
        self.stack_top = self.sym["_estack"].value
        self.instructions = 0  # over every call
        self.last_instructions = 0
        self.last_fp = 0  # floating-point instructions of the last call
        self.last_div_sqrt = 0  # of them VDIV.F32 and VSQRT.F32
        self.step_map: steps.StepMap | None = None
        self.last_steps: list[int] = []  # the last call's instructions by step (count=True)
        self._step = 0  # the step the instructions running now are for
        # per basic block: instructions, FP, VDIV/VSQRT, and for fw_core_isr's own code its
        # (step, instructions) parts and the step of its last instruction
        self._blocks: dict[tuple[int, int],
                           tuple[int, int, int, tuple[tuple[int, int], ...] | None, int]] = {}
        if count:
            functions = {n: (s.value & ~1, (s.value & ~1) + s.size)
                         for n, s in self.sym.items() if s.size > 0}
            self.step_map = steps.read(path, functions)
            self.last_steps = [0] * len(self.step_map.names)
            uc.hook_add(UC_HOOK_BLOCK, self._on_block)
        self.call("m4_reset_handler")
        # the mailboxes and the state: address and size from the symbol table
        self.sizes = self.read_words("m4_sizes", 5)

    @property
    def step_names(self) -> tuple[str, ...]:
        return self.step_map.names if self.step_map is not None else ()

    def _decode(self, uc: Uc, address: int, size: int
                ) -> tuple[int, int, int, tuple[tuple[int, int], ...] | None, int]:
        code = bytes(uc.mem_read(address, size))
        cost, fp, slow = thumb_mix(code)
        parts: tuple[tuple[int, int], ...] | None = None
        last = 0
        assert self.step_map is not None
        owners = [self.step_map.owner(address + off) for off in thumb_starts(code)]
        if any(o is not None for o in owners):
            counts: dict[int, int] = {}
            for o in owners:
                last = o if o is not None else last
                counts[last] = counts.get(last, 0) + 1
            parts = tuple(counts.items())
        blk = (cost, fp, slow, parts, last)
        self._blocks[(address, size)] = blk
        return blk

    def _on_block(self, uc: Uc, address: int, size: int, _user: object) -> None:
        blk = self._blocks.get((address, size))
        if blk is None:
            blk = self._decode(uc, address, size)
        cost, fp, slow, parts, last = blk
        self.last_instructions += cost
        self.last_fp += fp
        self.last_div_sqrt += slow
        if parts is None:  # a callee: for the step that called it
            self.last_steps[self._step] += cost
        else:
            for step, n in parts:
                self.last_steps[step] += n
            self._step = last

    def call(self, function: str) -> None:
        """Runs one entry point (``void f(void)``) to its return."""
        uc = self.uc
        uc.reg_write(A.UC_ARM_REG_SP, self.stack_top)
        uc.reg_write(A.UC_ARM_REG_LR, STOP | 1)
        self.last_instructions = self.last_fp = self.last_div_sqrt = 0
        if self.last_steps:
            self.last_steps = [0] * len(self.last_steps)
            self._step = 0
        uc.emu_start(self.sym[function].value | 1, STOP, count=CALL_LIMIT)
        pc = uc.reg_read(A.UC_ARM_REG_PC)
        if pc != STOP:
            raise RuntimeError(f"{function} did not return within {CALL_LIMIT} instructions "
                               f"(pc {pc:#x})")
        self.instructions += self.last_instructions

    def address(self, name: str) -> int:
        return self.sym[name].value

    def read(self, name: str, size: int | None = None) -> bytes:
        s = self.sym[name]
        return bytes(self.uc.mem_read(s.value, size if size is not None else s.size))

    def write(self, name: str, data: bytes) -> None:
        self.uc.mem_write(self.sym[name].value, data)

    def read_words(self, name: str, n: int) -> list[int]:
        raw = self.read(name, 4 * n)
        return [int.from_bytes(raw[4 * i:4 * i + 4], "little") for i in range(n)]


class Profile:
    """Instructions per function of the image (a block is counted to the function whose
    symbol covers its first address), for finding where an ISR spends them."""

    def __init__(self, m4: M4Core) -> None:
        funcs = sorted((s.value & ~1, s.size, name) for name, s in m4.sym.items()
                       if s.size > 0 and s.value < FLASH[0] + FLASH[1])
        self._starts = [f[0] for f in funcs]
        self._funcs = funcs
        self.by_function: dict[str, int] = {}
        m4.uc.hook_add(UC_HOOK_BLOCK, self._on_block)
        self._m4 = m4

    def _on_block(self, uc: Uc, address: int, size: int, _user: object) -> None:
        import bisect

        i = bisect.bisect_right(self._starts, address) - 1
        name = self._funcs[i][2] if i >= 0 and address < self._starts[i] + self._funcs[i][1] \
            else f"{address:#x}"
        blk = self._m4._blocks.get((address, size))
        cost = blk[0] if blk is not None else thumb_instructions(
            bytes(uc.mem_read(address, size)))
        self.by_function[name] = self.by_function.get(name, 0) + cost
