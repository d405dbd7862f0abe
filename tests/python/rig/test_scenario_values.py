"""Issue 16.6 / 15.4: every value a scenario hands to the programs is checked at load time
against the one source of its range (the plant's profile schema in plant_rt, the firmware's
protocols/parameters.csv), with file:line:field and exit 2, never a program crash later."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_scenario import GOOD, _write, schema_error

from rig import scenario as sc
from rig.cli import main as rig_main

BASE = 'description = "t"\nprofile = "paper"\nduration = 1.0\n'

CASES = [
    # [overrides]: the plant's schema (unknown field, range, integer, cross-field, type)
    (BASE + '[overrides]\n"machine.rs_ohm" = -5\n', 5, "overrides.machine.rs_ohm",
     "outside"),
    (BASE + "[overrides.machine]\nrs_ohm = 1.0\nnonsense = 3\n", 6,
     "overrides.machine.nonsense", "unknown field"),
    (BASE + "[overrides.adc]\nbits = 12.5\n", 5, "overrides.adc.bits", "integer"),
    (BASE + "[overrides.magnetics]\nld_sat_h = 0.5\n", 5, "overrides.magnetics.ld_sat_h",
     "must not exceed magnetics.ld_h"),
    (BASE + '[overrides]\n"inverter.vdc_v" = "high"\n', 5, "overrides.inverter.vdc_v",
     "number"),
    (BASE + "[overrides.inverter]\ndead_time_s = 1.5e-9\n", 5,
     "overrides.inverter.dead_time_s", "TBCLK"),
    # [firmware]: protocols/parameters.csv (unknown, range, read-only)
    (BASE + "[firmware]\nno_such_param = 1\n", 5, "firmware.no_such_param", "unknown"),
    (BASE + "[firmware]\nrs_ohm = -1\n", 5, "firmware.rs_ohm", "outside"),
    (BASE + "[firmware]\nfw_version = 3\n", 5, "firmware.fw_version", "read-only"),
    # bounds the campaign found missing
    (BASE.replace("duration = 1.0", "duration = 1e7"), 3, "duration", "<="),
    (BASE + "[run]\nready_timeout_s = 1e300\n", 5, "run.ready_timeout_s", "<="),
    (BASE + "[run]\ntimeout_s = 1e300\n", 5, "run.timeout_s", "<="),
]


@pytest.mark.parametrize("text, line, field, fragment", CASES)
def test_bad_values_name_file_line_and_field(tmp_path: Path, text: str, line: int,
                                             field: str, fragment: str) -> None:
    schema_error(tmp_path, text, line, field, fragment)


def test_good_overrides_and_firmware_values_load(tmp_path: Path) -> None:
    path = _write(tmp_path, BASE + '[overrides]\n"machine.rs_ohm" = 2.5\n'
                  "[overrides.adc]\nbits = 16\n[firmware]\nrs_ohm = 2.0\n")
    s = sc.load_scenario(path)
    assert s.overrides == {"machine.rs_ohm": 2.5, "adc.bits": 16}
    assert s.firmware == {"rs_ohm": 2.0}


def test_overrides_are_checked_on_the_profile_a_suite_entry_names(tmp_path: Path) -> None:
    # Ld = 10 mH is fine on paper (saturated Ld 8 mH) but below ideal's 15 mH saturated Ld
    path = _write(tmp_path, BASE + "[overrides.magnetics]\nld_h = 0.010\n")
    s = sc.load_scenario(path)
    assert s.with_profile("harsh").profile == "harsh"
    with pytest.raises(sc.ScenarioError) as info:
        s.with_profile("ideal")
    assert "overrides.magnetics.ld_h" in str(info.value) or "ld_sat_h" in str(info.value)
    assert f"{path}:5:" in str(info.value)


def test_a_file_that_is_not_utf8_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / "latin.toml"
    path.write_bytes(BASE.encode() + b'# caf\xe9\n')
    with pytest.raises(sc.ScenarioError) as info:
        sc.load_scenario(path)
    assert f"{path}:4: " in str(info.value) and "UTF-8" in str(info.value)


def test_cli_exits_2_before_starting_anything(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    bad = _write(tmp_path, GOOD + '\n[overrides]\n"machine.rs_ohm" = -5\n', "bad")
    assert rig_main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:" in err and "overrides.machine.rs_ohm" in err
    assert not (tmp_path / "o").exists()
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b'description = "caf\xe9"\n')
    assert rig_main(["run", str(latin), "--out", str(tmp_path / "o")]) == 2
    assert "UTF-8" in capsys.readouterr().err


def test_a_shaft_turning_at_the_start_is_commanded_its_speed(tmp_path: Path) -> None:
    """[initial] speed_rpm with a first hold segment: the drive gets the initial speed as its
    reference at t = 0 (a hold commands nothing), which is the reference the rig expects."""
    from rig.scenario import load_scenario

    path = tmp_path / "fly.toml"
    path.write_text('description = "fly"\nprofile = "paper"\nduration = 0.5\n'
                    '[initial]\nspeed_rpm = 800.0\n'
                    '[[speed]]\nkind = "hold"\nduration = 0.2\n'
                    '[[speed]]\nkind = "ramp"\nto = 400.0\nduration = 0.3\n')
    sc = load_scenario(path)
    cmds = sc.speed_commands(3000.0)
    assert (cmds[0].t, cmds[0].target) == (0.0, 800.0)
    assert sc.speed_reference([0.0, 0.1, 0.2], 3000.0).tolist() == [800.0, 800.0, 800.0]
    assert cmds[-1].target == 400.0
