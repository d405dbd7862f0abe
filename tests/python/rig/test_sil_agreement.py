"""The in-process bench (``--bus inproc``) against the bus in lockstep, on a sample of
scenarios and of fault scenarios: the same verdict, the same criterion values, the same trace
files.

Both paths are deterministic in lockstep and hand the plant and the firmware the same frames
(the bench links the bus programs' frame code), so they agree exactly: any difference is a
defect to find, not a tolerance to widen. The sample covers the three fidelity profiles, a
speed ramp and a load step (its event must land on the same period)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rig import scenario
from rig.data import capture
from rig.results.result import RunResult

SAMPLE = ("smoke", "fig09_load_step_realtime", "fig08_flux_600rpm@harsh")


def _first_period(result: RunResult, column: str, level: float) -> int:
    """The first period whose value of ``column`` is at least ``level``."""
    assert result.capture is not None
    values = np.asarray(result.capture[column])
    hits = np.flatnonzero(values >= level)
    assert hits.size, f"{column} never reaches {level}"
    return int(hits[0]) + result.capture.first_period


def _assert_agree(on_bus: RunResult, inproc: RunResult) -> None:
    """The same verdict, criterion outcomes and values, and byte-identical traces."""
    assert on_bus.bus != "inproc" and inproc.bus == "inproc"
    assert (inproc.status, inproc.passed) == (on_bus.status, on_bus.passed), (
        on_bus.explain() + "\n" + inproc.explain())
    by_name = {c["name"]: c for c in on_bus.criteria}
    # the bus run leaves out only the ISR's cost, measured in process alone (left_out)
    left = {x["name"] for x in on_bus.left_out or []}
    assert left == {c["name"] for c in inproc.criteria
                    if str(c["metric"]).startswith("isr_instructions")}
    judged = [c for c in inproc.criteria if c["name"] not in left]
    assert [c["name"] for c in judged] == list(by_name)
    for c in judged:
        ref = by_name[c["name"]]
        assert c["outcome"] == ref["outcome"], c["name"]
        if ref["value"] is None:
            assert c["value"] is None, c["name"]
        else:
            assert math.isclose(c["value"], ref["value"], rel_tol=1e-12, abs_tol=1e-12), (
                c["name"], c["value"], ref["value"])
    a, b = Path(on_bus.out_dir, "fw.trace"), Path(inproc.out_dir, "fw.trace")
    assert a.read_bytes() == b.read_bytes(), "fw.trace differs"
    bus_plant, own_plant = (_by_message(Path(r.out_dir, "plant.trace")) for r in (on_bus, inproc))
    assert set(bus_plant) == set(own_plant)
    for name, records in own_plant.items():
        got = bus_plant[name]
        if name == "VIO_PWM":
            # the frames the plant received: on the bus a grant sent again (a lost or late
            # BENCH_STEP under load) brings the same PWM frame again; each in order, once
            got, records = _without_repeats(got), _without_repeats(records)
        assert got.tobytes() == records.tobytes(), f"plant.trace: {name} differs"
    assert inproc.capture_loss["lost"] == 0


def _by_message(path: Path) -> dict[str, np.ndarray]:
    from rig import protocols
    from rig.data.trace import TraceFile, frame_ids

    records = np.asarray(TraceFile.open(path).records())
    ids = frame_ids(records["can_id"])
    names = {int(m.frame_id): m.name for db in protocols.DATABASES
             for m in protocols.database(db).messages}
    return {names[int(i)]: records[ids == i] for i in np.unique(ids)}


def _without_repeats(records: np.ndarray) -> np.ndarray:
    if not len(records):
        return records
    raw = records.view(np.uint8).reshape(len(records), -1)
    keep = np.concatenate([[True], np.any(raw[1:] != raw[:-1], axis=1)])
    return records[keep]


@pytest.mark.parametrize("name", SAMPLE)
def test_inproc_agrees_with_lockstep_bus(name: str, hil_run) -> None:  # type: ignore[no-untyped-def]
    sc = scenario.load(name)
    assert isinstance(sc, scenario.Scenario)
    # one run of a scenario decided over its own seeds: the paths are compared, not the seeds
    sc = replace(sc, seeds=())
    on_bus = hil_run(sc, record=False)
    inproc = hil_run(sc, record=False, bus="inproc")
    _assert_agree(on_bus, inproc)
    assert inproc.counters["firmware.rx_rejected"] == 0
    assert inproc.counters["plant.rejected"] == 0
    # a load step lands on the period the scenario names, on both paths
    for lc in sc.load_commands():
        if lc.torque > 0:
            want = round(lc.t / capture.TS)
            level = 0.5 * lc.torque
            assert _first_period(inproc, "truth.tl", level) == want
            assert _first_period(on_bus, "truth.tl", level) == want
            break


# Faults (issue 15.1): physical ones in the plant, frame faults on both sides of the virtual
# I/O (the VIO_ADC ones pace every exchange with the VIO_SYNC barrier) and on the rig's own
# frames; the same frames reach the same periods on the bus and in process.
FAULT_SAMPLE = ("fault_open_phase", "fault_adc_frame_corrupt", "fault_pwm_frame_delay",
                "fault_pwm_frame_corrupt", "fault_drive_cmd_corrupt_range")


@pytest.mark.parametrize("name", FAULT_SAMPLE)
def test_faults_agree_between_inproc_and_lockstep_bus(name: str, hil_run) -> None:  # type: ignore[no-untyped-def]
    sc = scenario.load(name)
    assert isinstance(sc, scenario.Scenario) and sc.faults
    on_bus = hil_run(sc, record=False)
    inproc = hil_run(sc, record=False, bus="inproc")
    _assert_agree(on_bus, inproc)
    for key in ("firmware.fault_code", "plant.late_cmds", "plant.faults.frames_dropped",
                "plant.faults.frames_corrupted", "plant.faults.frames_delayed",
                "plant.faults.barriers", "rig.faults.frames_corrupted"):
        assert inproc.counters[key] == on_bus.counters[key], key
