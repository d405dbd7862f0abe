"""Issue 23.1-3: nothing a user writes is lost to a run's folder.

- runs without --out started in the same second get a folder each (they shared one and the
  run that passed pruned the traces of the others);
- --out into a folder that is not a run of the rig is refused, nothing in it changed; into an
  earlier run's folder only the run's own files are replaced, and no link there is followed;
- rig clean keeps a suite whose scenario folder holds KEEP.

The runs are on the in-process bench (no bus)."""

from __future__ import annotations

import datetime as dt
import json
import os
import subprocess
import sys
import threading
import types
from pathlib import Path

import pytest

from rig import cli, outputs
from rig.cli import main as rig_main

FROZEN = dt.datetime(2026, 3, 1, 12, 0, 0)


class _FrozenClock(dt.datetime):
    """datetime whose now() is one instant: every run starts in the same second."""

    @classmethod
    def now(cls, tz: dt.tzinfo | None = None) -> _FrozenClock:  # type: ignore[override]
        return cls(FROZEN.year, FROZEN.month, FROZEN.day, FROZEN.hour, FROZEN.minute,
                   FROZEN.second)


def test_runs_started_in_the_same_second_get_a_folder_each(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HIL_OUT", str(tmp_path / "out"))
    monkeypatch.setattr(outputs, "dt", types.SimpleNamespace(datetime=_FrozenClock))
    got: list[Path] = []
    lock = threading.Lock()

    def claim() -> None:
        p = outputs.default_out("table2_1000rpm_1nm")
        with lock:
            got.append(p)

    threads = [threading.Thread(target=claim) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(got)) == 8, sorted(map(str, got))
    assert all(p.is_dir() and not any(p.iterdir()) for p in got)  # made, empty, each its own
    names = sorted(p.name for p in got)
    assert names[0] == "table2_1000rpm_1nm-20260301-120000"
    assert all(outputs.AUTO_NAME.fullmatch(n) for n in names)  # rig clean still knows them


def test_parallel_runs_without_out_keep_their_own_data(tmp_path: Path) -> None:
    """The issue's reproduction, on the in-process bench: three `rig run` at once, HIL_OUT
    shared. Each writes its own folder and passes with its traces (--keep-all)."""
    root = tmp_path / "out"
    env = {**os.environ, "HIL_OUT": str(root)}
    procs = [subprocess.Popen([sys.executable, "-m", "rig", "run", "smoke", "--bus", "inproc",
                               "--quiet", "--no-record", "--keep-all"], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for _ in range(3)]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], outs
    folders = sorted(root.iterdir())
    assert len(folders) == 3, folders
    for f in folders:
        assert json.loads((f / "result.json").read_text())["passed"]
        assert (f / "plant.trace").is_file() and (f / "fw.trace").is_file()


def _user_folder(tmp_path: Path) -> Path:
    d = tmp_path / "D"
    (d / "capture").mkdir(parents=True)
    (d / "capture" / "a.csv").write_text("x\n")
    (d / "report.md").write_text("notes\n")
    return d


def test_out_into_a_folder_that_is_not_a_run_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = _user_folder(tmp_path)
    code = rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet"])
    err = capsys.readouterr().err
    assert code == 3, err
    assert "not a run of the rig" in err and "capture/" in err and "report.md" in err
    assert "Traceback" not in err
    assert (d / "capture" / "a.csv").read_text() == "x\n"
    assert (d / "report.md").read_text() == "notes\n"
    assert sorted(p.name for p in d.iterdir()) == ["capture", "report.md"]  # nothing added


def test_a_suite_into_a_folder_with_a_foreign_scenario_folder_is_refused_before_it_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "S"  # an earlier suite's folder, its scenario folder taken by the user
    (d / "smoke").mkdir(parents=True)
    (d / "smoke" / "mine.txt").write_text("mine\n")
    summary = json.dumps({"schema": "hil-suite/1", "suite": "quick", "passed": True})
    (d / "result.json").write_text(summary)
    code = rig_main(["run", "quick", "--bus", "inproc", "--out", str(d), "--quiet"])
    err = capsys.readouterr().err
    assert code == 3, err
    assert "scenario folder" in err and "mine.txt" in err
    assert sorted(p.name for p in d.iterdir()) == ["result.json", "smoke"]
    assert (d / "result.json").read_text() == summary
    assert [p.name for p in (d / "smoke").iterdir()] == ["mine.txt"]


def test_an_earlier_run_is_replaced_and_links_in_it_are_not_followed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "run"
    assert rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet",
                     "--no-record"]) == 0
    capsys.readouterr()
    first = json.loads((d / "result.json").read_text())["started"]
    (d / "notes.txt").write_text("my notes\n")  # the user's, in the run's folder
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.csv").write_text("precious\n")
    (elsewhere / "report.md").write_text("precious report\n")
    (d / "capture").symlink_to(elsewhere, target_is_directory=True)
    (d / "plant_rt.stderr.log").unlink(missing_ok=True)
    (d / "plant_rt.stderr.log").symlink_to(elsewhere / "report.md")
    code = rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet",
                     "--no-record", "--keep-all"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "Traceback" not in err
    assert (elsewhere / "keep.csv").read_text() == "precious\n"
    assert (elsewhere / "report.md").read_text() == "precious report\n"
    assert (d / "notes.txt").read_text() == "my notes\n"
    assert not (d / "capture").is_symlink() and (d / "capture" / "meta.json").is_file()
    assert not (d / "plant_rt.stderr.log").is_symlink()
    assert json.loads((d / "result.json").read_text())["started"] >= first


def test_a_killed_run_is_still_a_run_of_the_rig(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """A run killed before its result.json (SIGKILL) leaves its marker: the next run into
    that folder (./hil main's out/paper) replaces it instead of refusing."""
    d = tmp_path / "run"
    assert rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet",
                     "--no-record"]) == 0
    (d / "result.json").unlink()
    (d / "report.md").unlink()
    assert rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet",
                     "--no-record"]) == 0, capsys.readouterr().err


def test_clean_keeps_a_suite_whose_scenario_folder_holds_keep(tmp_path: Path) -> None:
    root = tmp_path / "out"
    for i in range(3):
        suite = root / f"paper-2026010{i}-120000"
        (suite / "table2_0001rpm_0nm").mkdir(parents=True)
        (suite / "result.json").write_text(json.dumps({"schema": "hil-suite/1",
                                                       "suite": "paper", "passed": True}))
        (suite / "table2_0001rpm_0nm" / "result.json").write_text(
            json.dumps({"schema": "hil-result/1", "scenario": "t", "passed": True}))
    kept = root / "paper-20260100-120000" / "table2_0001rpm_0nm" / "KEEP"
    kept.write_text("")
    assert cli.main(["clean", str(root), "--keep-last", "0", "--yes"]) == 0
    assert kept.is_file()
    assert sorted(p.name for p in root.iterdir()) == ["paper-20260100-120000"]


def _failing_smoke(tmp_path: Path) -> Path:
    """smoke with a position-error limit it cannot meet: it draws that criterion's picture."""
    text = (Path(outputs.__file__).parent / "scenarios" / "smoke.toml").read_text()
    text = text.replace("limit = 10.0", "limit = 0.001")
    path = tmp_path / "smoke.toml"
    path.write_text(text)
    return path


def test_a_rerun_removes_only_the_files_the_earlier_run_wrote(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The user's files that match the names a run gives its files (a program's log, a ready
    file, a criterion's picture) stay; the earlier run's own pictures go."""
    d = tmp_path / "run"
    assert rig_main(["run", str(_failing_smoke(tmp_path)), "--bus", "inproc", "--out", str(d),
                     "--quiet", "--no-record"]) == 1
    assert (d / "criterion-2.png").is_file()
    mine = {"notes.stdout.log": "my log\n", "mine.ready": "ready\n",
            "criterion-overview.png": "my picture\n"}
    for name, text in mine.items():
        (d / name).write_text(text)
    code = rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet",
                     "--no-record"])
    assert code == 0, capsys.readouterr().err
    for name, text in mine.items():
        assert (d / name).read_text() == text, name
    assert not (d / "criterion-2.png").exists()  # the earlier run's, gone with it


def test_a_second_run_into_a_folder_in_use_is_refused_at_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "run"
    held = outputs.claim(d, 100)  # a run in progress there
    try:
        (d / "result.json").write_text("{}")  # (a file of that run, half way)
        code = rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet"])
        err = capsys.readouterr().err
        assert code == 3, err
        assert f"the output folder {d} is in use by another run of the rig (pid {os.getpid()})" \
            in err, err
        assert (d / "result.json").read_text() == "{}"  # nothing changed
        code = rig_main(["run", "quick", "--bus", "inproc", "--out", str(d), "--quiet"])
        assert code == 3 and "in use by another run" in capsys.readouterr().err
    finally:
        held.release()
    assert rig_main(["run", "smoke", "--bus", "inproc", "--out", str(d), "--quiet",
                     "--no-record"]) == 0


def test_two_rig_runs_into_one_out_the_second_is_refused(tmp_path: Path) -> None:
    """End to end: the first run (stopped once it has taken the folder, so that it is
    surely still running) keeps the folder; the second exits 3 at once; the first passes."""
    import signal
    import time

    d = tmp_path / "run"
    argv = [sys.executable, "-m", "rig", "run", "smoke", "--bus", "inproc", "--out", str(d),
            "--quiet", "--no-record"]
    first = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while _marker_pid(d) != first.pid:
            assert first.poll() is None and time.monotonic() < deadline
            time.sleep(0.001)
        first.send_signal(signal.SIGSTOP)
        second = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    finally:
        first.send_signal(signal.SIGCONT)
    out, _ = first.communicate(timeout=120)
    assert second.returncode == 3, second.stderr
    assert f"is in use by another run of the rig (pid {first.pid})" in second.stderr
    assert first.returncode == 0, out
    assert json.loads((d / "result.json").read_text())["passed"]


def _marker_pid(d: Path) -> int | None:
    try:
        return json.loads((d / outputs.RUN_MARKER).read_text()).get("pid")
    except (OSError, ValueError):
        return None
