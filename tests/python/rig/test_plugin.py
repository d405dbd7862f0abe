"""The pytest plugin, run the way users run it: in a separate pytest, in parallel workers."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import pytest
import scenario_text

from rig.pytest_plugin import channel_for

pytest_plugins = ["pytester"]


def test_channels_are_unique_per_worker() -> None:
    assert channel_for("gw3", "socketcan") == "vcan3"
    assert channel_for("main", "socketcan") == "vcan0"
    a, b = channel_for("gw0", "unixcan"), channel_for("gw1", "unixcan")
    assert a != b and a.startswith("vcan-gw0-")


USER_TESTS = '''
import json
import pytest

TINY = """
''' + scenario_text.scenario(
    "tiny", profile="ideal", duration=0.1, speed=[scenario_text.ramp(100.0, 0.05)],
    criteria=[scenario_text.criterion("position error", "pos_err_max_deg", (0.02, "end"), 1.0)],
) + '''"""


@pytest.fixture
def tiny(tmp_path):
    p = tmp_path / "tiny.toml"
    p.write_text(TINY)
    return p


@pytest.mark.parametrize("k", [1, 2])
def test_run(hil_run, hil_bus, tiny, k):
    result = hil_run(tiny)
    result.assert_passed()
    assert result.metric("pos_err_max_deg", window=(0.02, 0.1)) == pytest.approx(0.5, abs=1e-3)
    print("CHANNEL", result.channel, hil_bus[1])
    assert result.channel == hil_bus[1]


def test_suite_parametrization(hil_scenario_name):
    assert hil_scenario_name.startswith(("table2_", "fig"))


@pytest.mark.hil_scenario("smoke")
def test_marker(hil_result):
    hil_result.assert_passed()
    assert hil_result.scenario == "smoke"
'''


def _plugin_args() -> list[str]:
    """``-p rig.pytest_plugin`` unless the installed package registers it (entry point)."""
    names = {ep.name for ep in metadata.entry_points(group="pytest11")}
    return [] if "hil" in names else ["-p", "rig.pytest_plugin"]


def test_plugin_runs_scenarios_in_parallel_workers(pytester: pytest.Pytester, fake_bin: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    pytester.makepyfile(test_user=USER_TESTS)
    pytester.makeini("[pytest]\n")
    monkeypatch.setenv("HIL_BIN_DIR", str(fake_bin))
    monkeypatch.setenv("HIL_BUS", "unixcan")
    res = pytester.runpytest_subprocess(*_plugin_args(), "-n", "2", "-s", "-q",
                                        "-p", "no:cacheprovider", "--hil-suite", "table2")
    from rig.scenario import SUITE_DIR, load_suite

    n_table2 = len(load_suite(SUITE_DIR / "table2.toml").scenarios)
    res.assert_outcomes(passed=2 + n_table2 + 1)
    channels = {line.split()[1] for line in res.outlines if line.startswith("CHANNEL")}
    assert len(channels) <= 2
