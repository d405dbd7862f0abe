"""``rig bench plant`` prints its figures with the machine's load beside them (issue 41.4):
a short run on the fallback bus, its JSON read back."""

from __future__ import annotations

import json

import pytest

from rig import cli


def test_bench_plant_reports_load_and_every_profile(capsys: pytest.CaptureFixture[str]) -> None:
    rc = cli.main(["bench", "plant", "--periods", "300", "--lockstep-periods", "300",
                   "--transport", "unixcan"])
    assert rc == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("load_average", "load_average_after"):
        load = report[key]
        assert len(load) == 3 and all(isinstance(x, float) and x >= 0.0 for x in load), load
    assert set(report["compute"]) == {"ideal", "paper", "harsh"}
    for name, figures in report["compute"].items():
        assert figures["median_us"] > 0.0 and figures["rhs_per_period"] > 10.0, name
    assert report["lockstep"]["unixcan"]["periods"] == 300
