"""End to end with the real programs: the smoke scenario over the best available bus.

Skipped (with the reason) only when plant_rt / fw_host are not built; point HIL_BIN_DIR at a
build's bin/ folder or install the package to run it."""

from __future__ import annotations

import json

import pytest

from rig.results import recording

# Also runs inside the VM on SocketCAN vcan0 (the bus is auto-selected there).
pytestmark = pytest.mark.vcan

# Entities of the paper-figure layout (display series: every 10th period of a short run).
DISPLAY = ("position/theta", "position/error", "speed/rpm", "current/dq", "voltage/dq",
           "params/ld", "params/lq", "params/lambda", "flux/alpha_beta", "torque/nm")


def test_smoke_scenario_passes(hil_run, hil_binaries) -> None:  # type: ignore[no-untyped-def]
    result = hil_run("smoke")
    assert result.passed, result.explain()
    data = json.loads((result.out_dir / "result.json").read_text())
    assert data["capture"]["lost"] == 0 and data["capture"]["duplicates"] == 0
    assert data["capture"]["periods"] >= 4999
    rows = recording.entity_rows(result.out_dir / "recording.rrd")
    for entity in DISPLAY:
        assert rows.get(entity) == -(-data["capture"]["periods"] // 10), entity
    # the criteria's columns at full rate over their windows (polarity from 0.1 s to the end)
    assert rows.get(recording.EVIDENCE_ENTITY) == data["capture"]["periods"] - 1000
    assert rows.get("trajectory/current", 0) > 0 and rows.get("counters/late_cmds", 0) > 0
