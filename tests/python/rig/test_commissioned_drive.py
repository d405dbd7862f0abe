"""rig/commissioned/<profile>.toml: the drive as commissioning left it on a virtual bench,
applied to every scenario run on that profile (after the hardware from the profile, before
the scenario's own [firmware])."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from rig import _paths
from rig.drive import commissioned, params
from rig.run.errors import EnvironmentProblem
from rig.run.single import bench_configuration
from rig.scenario import load as load_scenario


def test_every_shipped_file_names_writable_parameters_in_range() -> None:
    table = params.table()
    files = sorted(commissioned.FOLDER.glob("*.toml"))
    assert files, "no commissioned drive shipped"
    for f in files:
        assert (_paths.data_dir("profiles") / f.name).is_file(), f"{f.name}: no such profile"
        values = commissioned.parameters(f.stem)
        assert values, f
        for name, v in values.items():
            info = table.lookup(name)
            assert info.writable and info.minimum <= v <= info.maximum, (f.name, name, v)


def test_harsh_scenarios_run_the_commissioned_drive_and_the_scenario_wins() -> None:
    sc = load_scenario("table2_0001rpm_2nm")
    assert sc.profile == "paper"
    k = commissioned.parameters("harsh")["xsat_ldq_per_a"]
    sets = bench_configuration(sc.with_profile("harsh")).fw_sets
    assert [float(s.split("=")[1]) for s in sets if s.startswith("xsat_ldq_per_a=")] == [k]
    assert not any(s.startswith("xsat_ldq_per_a=") for s in bench_configuration(sc).fw_sets)
    own = dataclasses.replace(sc.with_profile("harsh"), firmware={"xsat_ldq_per_a": 0.0})
    assert [s for s in bench_configuration(own).fw_sets if s.startswith("xsat")] == \
        ["xsat_ldq_per_a=0"]


@pytest.mark.parametrize("text, message", [
    ("[firmware]\nxsat_ldq_per_a = 'x'\n", "not a number"),
    ("[firmware]\nxsat_ldq_per_a = true\n", "not a number"),
    ("[plant]\nrs = 1\n", "only a [firmware] table"),
    ("[firmware\n", "Expected"),
    ("[firmware]\nno_such_parameter = 1\n", "no parameter named"),
    ("[firmware]\nxsat_ldq_per_a = 1.0\n", "outside"),
    ("[firmware]\nfw_version = 2\n", "read-only"),
])
def test_a_bad_file_is_an_error_naming_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                          text: str, message: str) -> None:
    (tmp_path / "bench.toml").write_text(text)
    monkeypatch.setattr(commissioned, "FOLDER", tmp_path)
    with pytest.raises(commissioned.CommissionedError) as info:
        commissioned.parameters("bench")
    assert "bench.toml" in str(info.value) and message in str(info.value)


def test_a_profile_path_or_an_unknown_profile_has_none() -> None:
    assert commissioned.parameters("no_such_profile") == {}
    assert commissioned.parameters("plant_rt/profiles/harsh.toml") == {}


def test_a_broken_commissioned_drive_stops_the_run_before_it_starts(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "harsh.toml").write_text("[firmware]\nxsat_ldq_per_a = 1.0\n")
    monkeypatch.setattr(commissioned, "FOLDER", tmp_path)
    sc = load_scenario("table2_0001rpm_2nm").with_profile("harsh")
    with pytest.raises(EnvironmentProblem, match="outside"):
        bench_configuration(sc)


def test_render_writes_toml_that_reads_back_and_keeps_a_reviewers_comments(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import tomllib

    text = commissioned.render({"xsat_ldq_per_a": -0.000177312345, "spd_kp": 0.5}, "harsh",
                               ["rig", "commission", "standstill", "xsat"])
    assert tomllib.loads(text) == {"firmware": {"spd_kp": 0.5, "xsat_ldq_per_a": -0.000177312}}
    path = tmp_path / "harsh.toml"
    path.write_text(text)
    assert commissioned.is_saved_file(path)
    monkeypatch.setattr(commissioned, "FOLDER", tmp_path)
    assert commissioned.parameters("harsh") == {"spd_kp": 0.5, "xsat_ldq_per_a": -0.000177312}
    # a reviewer's comments stay with the parameters still identified
    reviewed = text.replace("xsat_ldq_per_a = ", "# reviewed: 7 start angles, 2 seeds\n"
                            "xsat_ldq_per_a = ").replace("-0.000177312", "-0.000177312  # +-3 %")
    again = commissioned.render({"xsat_ldq_per_a": -0.0002}, "harsh", ["rig"], reviewed)
    assert "# reviewed: 7 start angles, 2 seeds\nxsat_ldq_per_a = -0.0002  # +-3 %" in again
    assert tomllib.loads(again) == {"firmware": {"xsat_ldq_per_a": -0.0002}}  # spd_kp gone
    assert again.startswith(commissioned.HEADER)
