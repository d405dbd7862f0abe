"""The control core's Cortex-M4F build under emulation against the host build: the same
outputs, period by period, on short stretches of closed-loop runs (``rig target compare``
runs them whole)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from rig import protocols
from rig.target_m4 import elf, emulator, record, replay, run, scenarios
from rig.target_m4.journal import Journal

try:
    IMAGE = emulator.image_path()
except FileNotFoundError:
    IMAGE = None
needs_image = pytest.mark.skipif(IMAGE is None, reason="fw_core_m4.elf not built "
                                 "(arm-none-eabi-gcc missing when the rig was installed)")


def test_isr_period_matches_the_wire_time_base() -> None:
    tb = protocols.timebase()
    assert record.TS == pytest.approx(2 * tb.tbprd / tb.tbclk_hz)


def test_thumb_instruction_count_follows_the_encoding() -> None:
    movs_r0_1 = bytes([0x01, 0x20])  # 16-bit: MOVS r0, #1
    bl = bytes([0x00, 0xF0, 0x00, 0xF8])  # 32-bit: BL (first halfword 0b11110...)
    vadd = bytes([0x30, 0xEE, 0x00, 0x0A])  # 32-bit: VADD.F32 (0b11101...)
    bx_lr = bytes([0x70, 0x47])  # 16-bit: BX lr
    assert emulator.thumb_instructions(movs_r0_1) == 1
    assert emulator.thumb_instructions(bl + vadd) == 2
    assert emulator.thumb_instructions(movs_r0_1 + bl + bx_lr + vadd) == 4
    vdiv = bytes([0x80, 0xEE, 0x81, 0x0A])  # VDIV.F32 s0, s1, s2 (as arm-none-eabi-as encodes it)
    vsqrt = bytes([0xB1, 0xEE, 0xC0, 0x0A])  # VSQRT.F32 s0, s0
    assert emulator.thumb_mix(movs_r0_1 + vadd + vdiv + vsqrt + bl) == (5, 3, 2)


@needs_image
def test_image_computes_in_single_precision_only() -> None:
    """No double-precision routine and none of the C library's trigonometry in the image:
    the FPU has no double (a double would be a software routine), and the core's own sine,
    cosine and atan2 keep it bit-identical with the host."""
    assert IMAGE is not None
    names = set(elf.read(IMAGE).symbols)
    doubles = sorted(n for n in names if n.startswith(("__aeabi_d", "__adddf", "__muldf",
                                                        "__divdf", "__extendsf")))
    libm = sorted(names & {"sin", "cos", "atan2", "sqrt", "floor", "sinf", "cosf", "atan2f"})
    assert doubles == [] and libm == []


@needs_image
@pytest.mark.parametrize("case", scenarios.CASES, ids=lambda c: c.scenario)
def test_target_outputs_equal_the_hosts(case: scenarios.Case, tmp_path: Path) -> None:
    comp = run.compare_case(case, tmp_path / case.scenario)
    expected_periods = sum(n for _, n in scenarios.windows(case))
    assert comp.windows == len(scenarios.windows(case))
    assert comp.periods == expected_periods
    assert comp.init_identical is True
    assert comp.commands > 0
    assert comp.summary()["identical"], comp.summary()
    states = {c.state for c in comp.costs}
    assert {"POLARITY", "RUN"} <= states  # the start window goes through polarity detection
    if case.scenario.startswith("fault_"):
        assert "FAULT" in states


@needs_image
def test_a_changed_input_is_seen(tmp_path: Path) -> None:
    """The comparison can fail: one ADC code changed in the journal the target replays
    makes its outputs or state differ from the host's from that period on."""
    case = scenarios.case("fault_open_phase")
    record.record(case.scenario, tmp_path, scenarios.windows(case), case.duration)
    path = tmp_path / "core.journal"
    j = Journal(path)
    raw = bytearray(path.read_bytes())
    off = 28
    changed_at = None
    for rec in j.records():
        size = 8 + len(rec.payload)
        if rec.tag == "I" and rec.isr >= 1400 and j.isr(rec).has_adc:
            ia0 = off + 8 + 4 + 8  # has_adc, then fw_adc_t: period, n_soc (+2), ia[0]
            code = struct.unpack_from("<i", raw, ia0)[0]
            struct.pack_into("<i", raw, ia0, code + 40)
            changed_at = rec.isr
            break
        off += size
    assert changed_at is not None
    path.write_bytes(bytes(raw))
    comp = replay.replay(Journal(path), emulator.M4Core())
    assert comp.first_state_difference == changed_at


@needs_image
def test_budget_tells_the_paths_apart(tmp_path: Path) -> None:
    """Instructions per ISR by path: the 1 kHz ISRs are every tenth RUN ISR and cost more
    than the 10 kHz ones in the median (they add the speed loop and the references)."""
    case = scenarios.Case("start", "fault_open_phase", (), duration=0.3)
    comp = run.compare_case(case, tmp_path, count=True)
    b = run.budget([comp])["paths"]
    assert {"run_10khz", "run_1khz", "startup_polarity"} <= set(b)
    n_run = b["run_10khz"]["n"] + b["run_1khz"]["n"]
    assert abs(b["run_1khz"]["n"] - n_run / 10) <= 1
    assert b["run_1khz"]["median"] > b["run_10khz"]["median"]
    assert all(b[p]["max"] >= b[p]["p99"] >= b[p]["median"] > 0 for p in b)


def test_budget_names_the_last_isr_with_the_largest_count() -> None:
    """worst_at is the last ISR (over all comparisons, in order) whose count equals the
    path's maximum; the statistics are those of every ISR of the path."""
    def costs(*rows: tuple[int, str, int]) -> list[replay.IsrCost]:
        return [replay.IsrCost(isr, state, False, n) for isr, state, n in rows]

    a, b = replay.Comparison("a"), replay.Comparison("b")
    a.costs = costs((1, "RUN", 500), (2, "RUN", 900), (3, "RUN", 700), (4, "IDLE", 40))
    b.costs = costs((1, "RUN", 900), (2, "RUN", 300), (3, "IDLE", 50), (4, "IDLE", 10))
    paths = run.budget([a, b])["paths"]
    assert paths["run_10khz"]["worst_at"] == "b ISR 1"
    assert paths["run_10khz"]["max"] == 900 and paths["run_10khz"]["n"] == 5
    assert paths["idle"]["worst_at"] == "b ISR 3"
    assert paths["idle"]["median"] == 40

