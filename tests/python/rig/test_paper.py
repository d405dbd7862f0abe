"""The paper's scenarios with the real programs (long: set HIL_PAPER=1 to run them).

Each scenario's own criteria, plus the comparisons the paper draws between two runs:
Fig. 9 (real-time MTPA recovers a load step with a smaller speed drop than the conventional
MTPA) and Fig. 10 (real-time flux weakening reaches a higher speed)."""

from __future__ import annotations

import os

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(os.environ.get("HIL_PAPER") != "1",
                       reason="long closed-loop runs: set HIL_PAPER=1 (and build the programs)"),
]


@pytest.mark.hil_suite("paper")
def test_paper_scenario(hil_scenario_name, hil_run, hil_binaries) -> None:  # type: ignore[no-untyped-def]
    result = hil_run(hil_scenario_name)
    assert result.passed, result.explain()


def test_fig09_realtime_mtpa_beats_conventional(hil_run, hil_binaries) -> None:  # type: ignore[no-untyped-def]
    rt = hil_run("fig09_load_step_realtime")
    conv = hil_run("fig09_load_step_conventional")
    window = (1.0, 2.0)
    drop_rt = rt.metric("speed_drop_pct", window, baseline_s=0.1)
    drop_conv = conv.metric("speed_drop_pct", window, baseline_s=0.1)
    assert drop_rt < drop_conv, (drop_rt, drop_conv)
    rec_rt = rt.metric("recovery_time_s", window, baseline_s=0.1)
    rec_conv = conv.metric("recovery_time_s", window, baseline_s=0.1)
    assert rec_rt <= rec_conv, (rec_rt, rec_conv)


def test_fig10_realtime_flux_weakening_reaches_higher_speed(hil_run, hil_binaries) -> None:  # type: ignore[no-untyped-def]
    rt = hil_run("fig10_fw_3000rpm_realtime")
    conv = hil_run("fig10_fw_3000rpm_conventional")
    top_rt = rt.metric("speed_mean_rpm", (2.6, 3.0))
    top_conv = conv.metric("speed_mean_rpm", (2.6, 3.0))
    assert top_rt > top_conv, (top_rt, top_conv)
