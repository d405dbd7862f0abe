"""The ``rig`` command line reads its arguments the same way on every command (rig.cliargs):
a shared option before or after the command, the command's own usage on a usage error with
the nearest spelling suggested, values checked where they are read (exit 2), and the
failures a shell user meets: an environment error printed once, ``rig list | head``, and
``python -m rig`` run by a Python without the rig's packages."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from rig import cli

ROOT = Path(__file__).resolve().parents[3]


def parse(argv: list[str]) -> dict[str, object]:
    from rig import cliargs

    ns = cliargs.finish(cli.build_parser().parse_args(argv))
    return {k: v for k, v in vars(ns).items() if k != "func"}


def usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert cli.main(argv) == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["param", "list", "--bus", "unixcan", "--channel", "c1", "--timeout", "0.5"],
    ["param", "--bus", "unixcan", "--channel", "c1", "list", "--timeout", "0.5"],
    ["--bus", "unixcan", "--channel", "c1", "--timeout", "0.5", "param", "list"],
    ["--channel", "c1", "param", "--timeout", "0.5", "list", "--bus", "unixcan"],
])
def test_a_shared_option_is_taken_before_or_after_the_command(argv: list[str]) -> None:
    got = parse(argv)
    assert (got["bus"], got["channel"], got["timeout"], got["bench"]) == ("unixcan", "c1",
                                                                          0.5, None)


def test_each_command_keeps_its_own_defaults_and_choices(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert parse(["param", "list"])["timeout"] == 1.0
    assert parse(["run", "smoke"])["timeout"] is None
    assert parse(["sweep", "smoke", "--param", "rs=1,2"])["bus"] == "inproc"
    assert parse(["--bus", "inproc", "run", "smoke"])["bus"] == "inproc"
    err = usage_error(["--bus", "inproc", "param", "list"], capsys)  # no in-process drive
    assert "rig param list: error: argument --bus: invalid choice: 'inproc'" in err
    err = usage_error(["--bus", "unixcan", "list"], capsys)
    assert "rig list: error: --bus does not apply to this command" in err


def test_bus_status_takes_channel_as_an_option() -> None:
    assert parse(["bus", "status", "--channel", "c2"])["channel"] == "c2"
    assert parse(["--channel", "c2", "bus", "up"])["channel"] == "c2"
    assert parse(["bus", "status", "c2"])["channel_arg"] == "c2"  # the older spelling


def test_a_usage_error_is_the_command_s_own_with_the_nearest_spelling(
        capsys: pytest.CaptureFixture[str]) -> None:
    err = usage_error(["run", "smoke", "--chanel", "x"], capsys)
    assert err.startswith("usage: rig run ")
    assert "rig run: error: unrecognized arguments: --chanel x (did you mean --channel?)" in err
    err = usage_error(["param", "list", "--buss", "unixcan"], capsys)
    assert err.startswith("usage: rig param list ") and "did you mean --bus?" in err
    err = usage_error(["rnu", "smoke"], capsys)
    assert "invalid choice: 'rnu'" in err and "(did you mean run?)" in err
    err = usage_error(["bus", "stats"], capsys)
    assert "(did you mean status?)" in err


def test_a_misspelt_scenario_or_profile_names_the_nearest(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "smok", "--bus", "inproc", "--out", str(tmp_path / "a")]) == 2
    assert "no scenario or suite 'smok'" in capsys.readouterr().err
    assert cli.main(["run", "smok", "--bus", "inproc", "--out", str(tmp_path / "a")]) == 2
    assert "did you mean smoke?" in capsys.readouterr().err
    assert cli.main(["run", "smoke@papr", "--bus", "inproc", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "smoke.toml: smoke@papr: unknown profile 'papr'" in err
    assert "did you mean smoke@paper?" in err
    assert not (tmp_path / "result.json").exists()


@pytest.mark.parametrize(("argv", "message"), [
    (["run", "smoke", "--channel", "bad/name"], "argument --channel: 'bad/name' is not a "
     "channel name"),
    (["run", "smoke", "--channel", ""], "argument --channel: '' is not a channel name"),
    (["--channel", "-x", "bus", "status"], "argument --channel: expected one argument"),
    (["--channel", ".x", "param", "list"], "argument --channel: '.x' is not a channel name"),
    (["run", "smoke", "--timeout", "-5"], "argument --timeout: -5 s is out of range: it must "
     "be > 0"),
    (["run", "smoke", "--timeout", "nan"], "argument --timeout: 'nan' is not a finite number"),
    (["--timeout", "inf", "run", "smoke"], "argument --timeout: 'inf' is not a finite number"),
    (["sweep", "smoke", "--param", "rs=1,2", "--random", "-5"], "argument --random: -5 is out "
     "of range: it must be >= 1"),
    (["sweep", "smoke", "--param", "rs=1,2", "--window", "5,1"], "argument --window: '5,1': "
     "the window must end after it starts"),
    (["sweep", "smoke", "--param", "rs=1,2", "--window", "0,nan"], "not a finite number"),
    (["sweep", "smoke", "--param", "rs=1,2", "--workers", "0"], "argument --workers"),
    (["view", "x", "--web", "--web-port", "70000"], "argument --web-port: 70000 is out of "
     "range"),
    (["run", "smoke", "--stall-s", "0"], "argument --stall-s: 0 is out of range"),
])
def test_bad_values_are_usage_errors(argv: list[str], message: str,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert message in usage_error(argv, capsys)


def test_an_invalid_channel_from_the_environment_is_a_usage_error(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("HIL_CHANNEL", "no/such")
    assert "argument HIL_CHANNEL: 'no/such' is not a channel name" in usage_error(
        ["run", "smoke", "--bus", "unixcan"], capsys)


@pytest.mark.parametrize("argv", [["run", "smoke"], ["bus", "status"], ["param", "list"],
                                  ["loadbench", "serve"]])
def test_an_unknown_bus_from_the_environment_is_a_usage_error(
        argv: list[str], monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("HIL_BUS", "bogus")
    err = usage_error(argv, capsys)
    assert "argument HIL_BUS: invalid choice: 'bogus'" in err and "Traceback" not in err


def test_sweep_values_and_sizes_are_checked_before_anything_runs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"
    assert cli.main(["sweep", "smoke", "--param", "speed_scale=nan", "--out", str(out)]) == 2
    assert "speed_scale: 'nan' is not a finite number" in capsys.readouterr().err
    assert cli.main(["sweep", "smoke", "--param", "rs=1,2", "--window", "0.1,9",
                     "--out", str(out)]) == 2
    assert "smoke lasts 0.5 s" in capsys.readouterr().err
    # 9 M points: refused from the axes' sizes, before a point is built
    assert cli.main(["sweep", "smoke", "--param", "rs=1:2:300", "--param", "lq=0.02:0.03:300",
                     "--param", "noise=0:0.1:100", "--out", str(out)]) == 2
    assert "has 9,000,000 points, more than the 100,000" in capsys.readouterr().err
    assert cli.main(["sweep", "smoke", "--param", "rs=1:2:1000000000", "--out", str(out)]) == 2
    assert "N must be in 1 .. 100000" in capsys.readouterr().err
    assert not out.exists()


def test_an_environment_error_is_printed_once(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    bus_dir = tmp_path / "file"
    bus_dir.write_text("not a folder")
    env_unixcan = {"UNIXCAN_DIR": str(bus_dir)}
    r = subprocess.run([sys.executable, "-m", "rig", "run", "smoke", "--bus", "unixcan",
                        "--channel", "once", "--quiet", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120, check=False,
                       env={**_env(), **env_unixcan})
    assert r.returncode == 3, r.stderr
    assert r.stderr.count(str(bus_dir)) == 1, r.stderr  # the failure, not once per criterion
    assert r.stderr.count("(see above)") == 4


def test_rig_list_into_head_has_no_traceback() -> None:
    r = subprocess.run(f"{sys.executable} -m rig list | head -1", shell=True,
                       capture_output=True, text=True, timeout=120, check=False, env=_env())
    assert r.stdout.startswith("NAME") and r.stdout.count("\n") == 1
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr, r.stderr


def test_python_m_rig_outside_its_environment_names_hil_install() -> None:
    # -S: no site-packages, as the system's Python in the checkout: the rig is found, its
    # packages are not
    r = subprocess.run([sys.executable, "-S", "-m", "rig", "list"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 3
    assert "Traceback" not in r.stderr
    assert "./hil install" in r.stderr and "lacks the rig's package" in r.stderr


def _env() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if k not in ("HIL_CHANNEL", "HIL_BUS")}


def test_the_stall_ceiling_reaches_the_run_s_options() -> None:
    from rig.link.clock import STALL_S
    from rig.run.options import RunOptions

    args = cli.build_parser().parse_args(["run", "smoke", "--stall-s", "60"])
    assert args.stall_s == 60.0
    assert RunOptions(out=Path("x")).stall_s == STALL_S  # the default when not given
