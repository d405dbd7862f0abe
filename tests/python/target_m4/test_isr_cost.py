"""The ISR's instructions by step of fw_core_isr on the emulated targets (rig.target_m4.steps,
emulator), the soft-float Cortex-M3 image, and the gate's cost values (rig.target_m4.cost):
cached per build and journal, aligned with the capture's periods."""

from __future__ import annotations

import re
import statistics
from pathlib import Path

import numpy as np
import pytest

from rig import _paths, protocols
from rig.target_m4 import cost, elf, emulator, record, run, scenarios, steps

try:
    IMAGES = {t: emulator.image_path(t) for t in emulator.TARGETS}
except FileNotFoundError:
    IMAGES = {}
needs_images = pytest.mark.skipif(len(IMAGES) != len(emulator.TARGETS),
                                  reason="fw_core_m4.elf / fw_core_m3.elf not built "
                                  "(arm-none-eabi-gcc missing when the rig was installed)")
SHORT = scenarios.Case("start", "fault_open_phase", (), duration=0.3)


def _source_steps() -> list[str]:
    """The static functions fw_core_isr calls, in the order its body calls them (read from
    the source, independently of the image's debug information)."""
    src = (_paths.repo_dir() / "firmware_c2000/core/src/fw_core.c").read_text()
    body = src[src.index("void fw_core_isr("):]
    body = body[:body.index("\n}\n")]
    defined = set(re.findall(r"^static \w+ (\w+)\(", src, re.M))
    return [n for n in re.findall(r"\b(\w+)\(c\b", body) if n in defined]


@needs_images
@pytest.mark.parametrize("target", sorted(emulator.TARGETS))
def test_the_steps_are_fw_core_isrs_calls_in_order(target: str) -> None:
    path = IMAGES[target]
    sym = elf.read(path).symbols
    functions = {n: (s.value & ~1, (s.value & ~1) + s.size) for n, s in sym.items() if s.size}
    m = steps.read(path, functions)
    assert list(m.names) == [steps.ENTRY, *_source_steps()]
    assert m.lo == sym["fw_core_isr"].value & ~1
    # every step's code lies in fw_core_isr (all inlined at -O2) and none overlaps another
    assert all(m.lo <= a < b <= m.hi for a, b, _ in m.ranges)
    assert all(r[1] <= s[0] for r, s in zip(m.ranges, m.ranges[1:], strict=False))


@pytest.fixture(scope="module")
def counted(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    out = tmp_path_factory.mktemp("isr-steps")
    return {"m4": run.compare_case(SHORT, out / "m4", count=True),
            "journal": out / "m4" / "core.journal"}


@needs_images
def test_the_steps_add_up_and_move_where_the_source_says(counted: dict[str, object]) -> None:
    """Every ISR's steps sum to its instructions; the 1 kHz tasks (fw_outer_step, in the
    outputs step every tenth RUN period) make `outputs` the step that grows in those
    periods; voltage_mean divides once in ten periods and is otherwise a few instructions."""
    comp = counted["m4"]
    assert isinstance(comp, run.replay.Comparison)
    assert comp.identical
    assert all(sum(c.steps) == c.instructions for c in comp.costs)
    i_vm = comp.steps.index("voltage_mean")
    fast = [c for c in comp.costs if c.state == "RUN" and not c.slow]
    slow = [c for c in comp.costs if c.state == "RUN" and c.slow]
    assert len(slow) >= 10
    growth = {n: statistics.median(c.steps[i] for c in slow)
              - statistics.median(c.steps[i] for c in fast) for i, n in enumerate(comp.steps)}
    assert max(growth, key=lambda n: growth[n]) == "outputs" and growth["outputs"] > 200
    vm = [c.steps[i_vm] for c in comp.costs if c.state == "RUN"]
    low, high = min(vm), max(vm)
    assert high > low + 5
    divider = protocols.timebase().speed_loop_divider
    assert abs(sum(v == high for v in vm) - len(vm) / divider) <= 2


@needs_images
def test_soft_float_m3_same_outputs_many_more_instructions(tmp_path: Path) -> None:
    """The Cortex-M3 image (no FPU) replays the same journal with the host's outputs and
    state, at several times the M4F's instructions (every float operation a call)."""
    from rig.target_m4 import replay
    from rig.target_m4.journal import Journal

    m3 = emulator.M4Core(count=True, target="cortex-m3")
    # the first 0.05 s of the start (the whole short case takes the M3 a minute)
    record.record(SHORT.scenario, tmp_path, [(0, 500)], 0.06)
    short = tmp_path / "core.journal"
    comp3 = replay.replay(Journal(short), m3)
    comp4 = replay.replay(Journal(short), emulator.M4Core(count=True))
    assert comp3.identical and comp4.identical and comp3.periods == comp4.periods == 500
    ratio = statistics.median(a.instructions / b.instructions
                              for a, b in zip(comp3.costs, comp4.costs, strict=True))
    assert ratio > 4


@needs_images
def test_costs_are_cached_per_build_and_journal(counted: dict[str, object],
                                                tmp_path: Path) -> None:
    journal = counted["journal"]
    assert isinstance(journal, Path)
    first = cost.measure(journal, cache=tmp_path)
    again = cost.measure(journal, cache=tmp_path)
    assert not first.cached and again.cached
    assert np.array_equal(first.instructions, again.instructions)
    assert np.array_equal(first.steps, again.steps) and first.step_names == again.step_names
    comp = counted["m4"]
    assert isinstance(comp, run.replay.Comparison)
    assert first.instructions.tolist() == [c.instructions for c in comp.costs]
    assert first.differs == ""  # the same compiler's rounding: identical to the bit


def _isr_state_offsets(path: Path) -> list[int]:
    """The byte offsets of every ISR record's state machine state in a core journal."""
    from rig.target_m4 import journal as jmod

    j = jmod.Journal(path)
    raw = path.read_bytes()
    adc, pwm = jmod._pad(j.size("fw_adc_t")), jmod._pad(j.size("fw_pwm_t"))
    offsets, off = [], 28
    while off < len(raw):
        tag = chr(int.from_bytes(raw[off:off + 4], "little"))
        if tag == "I":
            offsets.append(off + 8 + 4 + adc + pwm + 4)
        off += 8 + j._payload_size(tag)
    return offsets


def _with_states_moved(journal: Path, out: Path, n: int) -> Path:
    """The journal with the host's state machine state of its last n ISRs changed."""
    raw = bytearray(journal.read_bytes())
    for at in _isr_state_offsets(journal)[-n:]:
        state = int.from_bytes(raw[at:at + 4], "little", signed=True)
        raw[at:at + 4] = (state + 1).to_bytes(4, "little", signed=True)
    out.write_bytes(bytes(raw))
    return out


@needs_images
def test_a_target_on_the_hosts_path_is_counted_one_that_left_it_is_not(
        counted: dict[str, object], tmp_path: Path) -> None:
    """A build that rounds differently makes the last bits of the core's state differ from
    the host's while its periods take the host's path (a decision may fall a period apart):
    the counts stand, and say so. A target that ends more than 1 % of its periods in another
    state machine state than the host's did other work: no counts."""
    journal = counted["journal"]
    assert isinstance(journal, Path)
    exact = cost.measure(journal, cache=tmp_path)
    raw = bytearray(journal.read_bytes())
    last_bits = tmp_path / "last-bits.journal"
    crc_changed = bytearray(raw)
    crc_changed[-8] ^= 1  # the last ISR's core-state CRC
    last_bits.write_bytes(bytes(crc_changed))
    counted_anyway = cost.measure(last_bits, cache=tmp_path)
    assert not counted_anyway.cached  # another journal: measured, not the cache's
    assert np.array_equal(counted_anyway.instructions, exact.instructions)
    assert "the core state in 1 of" in counted_anyway.differs
    assert "and 0 period(s) off the path" in counted_anyway.differs
    again = cost.measure(last_bits, cache=tmp_path)
    assert again.cached and again.differs == counted_anyway.differs
    n_isr = len(_isr_state_offsets(journal))
    assert n_isr == len(exact.instructions) > 300
    one_apart = cost.measure(_with_states_moved(journal, tmp_path / "one.journal", 1),
                             cache=tmp_path)
    assert "and 1 period(s) off the path" in one_apart.differs
    many = max(3, n_isr // 100 + 1)
    with pytest.raises(cost.TargetMismatch, match=f"left the host's path: {many} of {n_isr}"):
        cost.measure(_with_states_moved(journal, tmp_path / "many.journal", many),
                     cache=tmp_path)


def test_columns_line_up_with_the_capture() -> None:
    c = cost.IsrCosts(np.array([5, 6, 7]), np.array([100, 110, 120]),
                      np.array([[1, 99], [2, 108], [3, 117]]), ("entry", "estimate"))
    cols = c.columns(first_period=6, n=4)
    assert cols[cost.COLUMN][:2].tolist() == [110, 120]
    assert np.isnan(cols[cost.COLUMN][2:]).all()
    assert cols[cost.STEP_PREFIX + "estimate"][:2].tolist() == [108, 117]


def test_journal_windows_hold_the_criteria_windows() -> None:
    """Each time window's periods, a period more on each side, overlaps merged."""
    got = cost.journal_windows([(0.0, 0.15), (0.1, 0.2), (1.9, 1.95)], duration=2.0)
    assert got == [(0, 2002), (18999, 503)]
    for t0, t1 in ((0.0, 0.15), (1.9, 1.95)):
        p0, p1 = round(t0 / cost.TS), round(t1 / cost.TS)
        assert any(a <= p0 and p1 < a + n for a, n in got)


def test_event_windows_hold_every_change_of_a_scenarios_inputs() -> None:
    """rig bench isr --coverage's reference: the start, 10 ms before to 50 ms after each
    moment the inputs change (enable, speed segments, load events, faults), the end."""
    from rig import scenario
    from rig.target_m4 import coverage

    sc = scenario.load("fault_adc_frame_loss")
    assert isinstance(sc, scenario.Scenario)
    wins = coverage.event_windows(sc)
    moments = [sc.enable_at, 0.3, *(e.at for e in sc.load), *(f.at for f in sc.faults)]
    for m in moments:
        assert any(t0 <= max(0.0, m - 0.01) and m + 0.05 <= t1 + 1e-9 for t0, t1 in wins), m
    assert (0.0, 0.15) in wins and any(t1 == sc.duration for _, t1 in wins)
    assert coverage.sample_windows(sc) == [(0.495, 0.52), (0.495, 0.52)]
