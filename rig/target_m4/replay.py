"""A core journal replayed on the Cortex-M4F image, every output compared with the host's.

Per window of the journal (from ``fw_core_init`` and the parameters when it starts at the
first ISR, else from the host's state at its start): every command and limit with its
status, every ISR with its ADC data (or none), and after each ISR the PWM of the next period
(compares, SOC count and instants, gate enable) and a CRC of the whole core state compared
with what the host build produced from the same inputs.

A replay is *identical* when every output and state matches the host's to the bit. A build
that rounds differently (another compiler, fused multiply-add on one side) cannot be; it still
takes *the host's path* when its periods end in the host's state machine state, with the
host's gate enable and number of conversions, and every compare and conversion instant within
``PATH_TICKS`` timer ticks of the host's, all but a few (``OFF_PATH_SHARE`` of them, at least
``OFF_PATH_MIN``: a decision whose threshold the last bits moved by a period). The ISRs then
did the host's work on the host's inputs, so their instruction counts are the cost of that
computation (rig.target_m4.cost); a target that faults, or decides otherwise, leaves it."""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

from rig import protocols
from rig.target_m4.emulator import M4Core
from rig.target_m4.journal import Journal, Pwm

STATE_NAMES = protocols.names("drive", "DRIVE_STATUS", "state")
PATH_TICKS = 2  # timer ticks a compare or conversion instant may differ by on the same path
OFF_PATH_SHARE = 0.01  # the share of periods that may leave it (a decision a period apart)
OFF_PATH_MIN = 2


@dataclass
class IsrCost:
    """Instructions of one ISR on the target, with what tells its path."""

    isr: int
    state: str  # the core's state when the ISR began (DRIVE_STATUS.state's name)
    slow: bool  # the 1 kHz tasks ran in it
    instructions: int
    fp: int = 0  # floating-point instructions among them
    div_sqrt: int = 0  # VDIV.F32 and VSQRT.F32 among those (14 cycles each on the M4F)
    steps: tuple[int, ...] = ()  # the instructions by step of fw_core_isr (Comparison.steps)


@dataclass
class Comparison:
    name: str
    windows: int = 0
    periods: int = 0  # ISRs compared
    commands: int = 0  # commands and limits compared (status)
    init_identical: bool | None = None  # state after init + parameters equal to the host's
    pwm_differences: int = 0
    first_pwm_difference: int | None = None
    max_tick_difference: int = 0  # over compares and SOC instants of differing periods
    state_differences: int = 0  # periods whose core state CRC differs from the host's
    first_state_difference: int | None = None
    status_differences: int = 0
    fsm_differences: int = 0  # periods ending in another state machine state than the host's
    shape_differences: int = 0  # periods with another gate enable or number of conversions
    off_path: int = 0  # periods of another state, shape, or compares beyond PATH_TICKS
    off_path_examples: list[str] = field(default_factory=list)
    examples: list[str] = field(default_factory=list)
    costs: list[IsrCost] = field(default_factory=list)
    steps: tuple[str, ...] = ()  # the names of IsrCost.steps (counted replays)

    @property
    def identical(self) -> bool:
        return (self.pwm_differences == 0 and self.state_differences == 0
                and self.fsm_differences == 0 and self.status_differences == 0
                and self.init_identical is not False)

    @property
    def same_path(self) -> bool:
        """The periods took the host's path, their outputs within ``PATH_TICKS`` ticks, all
        but ``OFF_PATH_SHARE`` of them (the last bits of a differently rounding build;
        ``identical`` implies it)."""
        allowed = max(OFF_PATH_MIN, int(OFF_PATH_SHARE * self.periods))
        return self.status_differences == 0 and self.off_path <= allowed

    def summary(self) -> dict[str, Any]:
        return {"journal": self.name, "windows": self.windows, "periods": self.periods,
                "commands": self.commands, "init_identical": self.init_identical,
                "pwm_differences": self.pwm_differences,
                "first_pwm_difference": self.first_pwm_difference,
                "max_tick_difference": self.max_tick_difference,
                "state_differences": self.state_differences,
                "first_state_difference": self.first_state_difference,
                "status_differences": self.status_differences,
                "fsm_differences": self.fsm_differences,
                "shape_differences": self.shape_differences, "off_path": self.off_path,
                "identical": self.identical, "same_path": self.same_path,
                "examples": self.examples[:5]}


def _tick_difference(a: Pwm, b: Pwm) -> int:
    pairs = list(zip(a.cmp_up + a.cmp_dn, b.cmp_up + b.cmp_dn, strict=True))
    if a.n_soc == b.n_soc:
        pairs += list(zip(a.soc, b.soc, strict=True))
    return max(abs(x - y) for x, y in pairs)


def _apply_parameters(m4: M4Core, params: list[tuple[int, float]]) -> list[int]:
    """The journal's parameters on the target core, retried in table order while a
    cross-check refuses one (as the host's parameter file does); the ids never taken."""
    pending = list(params)
    while pending:
        left = []
        for pid, value in pending:
            m4.write("m4_param_id", struct.pack("<H", pid))
            m4.write("m4_arg", struct.pack("<f", value))
            m4.call("m4_param_set")
            if struct.unpack("<h", m4.read("m4_ret"))[0] != 0:
                left.append((pid, value))
        if len(left) == len(pending):
            return [pid for pid, _ in left]
        pending = left
    return []


def replay(journal: Journal, m4: M4Core, name: str = "", max_examples: int = 5) -> Comparison:
    sizes = journal.sizes
    if sizes != m4.sizes:
        raise ValueError(f"struct sizes differ: host {sizes}, target {m4.sizes} "
                         "(fw_core_t, fw_adc_t, fw_pwm_t, fw_cmd_t, fw_status_t)")
    core_size = journal.size("fw_core_t")
    divider = protocols.timebase().speed_loop_divider
    out = Comparison(name or journal.path.name, steps=m4.step_names)
    params: list[tuple[int, float]] = []
    state = 0

    def note(text: str) -> None:
        if len(out.examples) < max_examples:
            out.examples.append(text)

    for rec in journal.records():
        if rec.tag == "P":
            pid, value = struct.unpack("<If", rec.payload)
            params.append((pid, value))
        elif rec.tag == "S":
            out.windows += 1
            host_state = rec.payload[:core_size]
            if rec.isr == 0:
                m4.call("m4_init")
                refused = _apply_parameters(m4, params)
                if refused:
                    raise ValueError(f"the target refused parameters {refused}")
                out.init_identical = m4.read("m4_core", core_size) == host_state
                if not out.init_identical:
                    note("state after init and parameters differs from the host's")
            else:
                m4.write("m4_core", host_state)
            state = struct.unpack_from("<h", host_state, _state_offset(m4))[0]
        elif rec.tag in "CL":
            if rec.tag == "C":
                n = journal.size("fw_cmd_t")
                m4.write("m4_cmd", rec.payload[:n])
                m4.call("m4_command")
                host_status = struct.unpack_from("<i", rec.payload, (n + 3) & ~3)[0]
            else:
                m4.write("m4_arg", rec.payload[:12])
                m4.call("m4_limits")
                host_status = struct.unpack_from("<i", rec.payload, 12)[0]
            out.commands += 1
            target_status = struct.unpack("<h", m4.read("m4_ret"))[0]
            if target_status != host_status:
                out.status_differences += 1
                note(f"ISR {rec.isr}: {rec.tag} status host {host_status} target "
                     f"{target_status}")
        elif rec.tag == "I":
            isr = journal.isr(rec)
            if isr.has_adc:
                m4.write("m4_adc", isr.adc)
                m4.call("m4_isr")
            else:
                m4.call("m4_isr_no_data")
            out.periods += 1
            count = m4.read_words("m4_isr_count", 1)[0]
            out.costs.append(IsrCost(rec.isr, STATE_NAMES.get(state, str(state)),
                                     count % divider == 0, m4.last_instructions, m4.last_fp,
                                     m4.last_div_sqrt, tuple(m4.last_steps)))
            state = isr.state
            host_pwm, target_pwm = Pwm.unpack(isr.pwm), Pwm.unpack(m4.read("m4_pwm"))
            off: list[str] = []
            if host_pwm != target_pwm:
                out.pwm_differences += 1
                if (host_pwm.n_soc != target_pwm.n_soc
                        or host_pwm.gate_enable != target_pwm.gate_enable):
                    out.shape_differences += 1
                    off.append("another gate enable or number of conversions")
                d = _tick_difference(host_pwm, target_pwm)
                if d > PATH_TICKS:
                    off.append(f"compares {d} ticks off")
                out.max_tick_difference = max(out.max_tick_difference, d)
                if out.first_pwm_difference is None:
                    out.first_pwm_difference = rec.isr
                note(f"ISR {rec.isr}: PWM host {host_pwm} target {target_pwm}")
            target_core = m4.read("m4_core", core_size)
            target_state = struct.unpack_from("<h", target_core, _state_offset(m4))[0]
            if target_state != isr.state:
                out.fsm_differences += 1
                off.append(f"state machine in {STATE_NAMES.get(target_state, str(target_state))}"
                           f", the host's in {STATE_NAMES.get(isr.state, str(isr.state))}")
            if off:
                out.off_path += 1
                if len(out.off_path_examples) < max_examples:
                    out.off_path_examples.append(f"ISR {rec.isr}: " + "; ".join(off))
            if zlib.crc32(target_core) != isr.crc:
                out.state_differences += 1
                if out.first_state_difference is None:
                    out.first_state_difference = rec.isr
                    note(f"ISR {rec.isr}: core state differs from the host's")
    return out


_STATE_OFFSET: int | None = None


def _state_offset(m4: M4Core) -> int:
    """Offset of fw_core_t.state: found on the target by the status it reports."""
    global _STATE_OFFSET
    if _STATE_OFFSET is None:
        _STATE_OFFSET = m4.read_words("m4_state_offset", 1)[0]
    return _STATE_OFFSET
