"""rig clean: which run folders it lists, which it removes, and what it never touches."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from rig import cli, outputs


def _run(root: Path, name: str, *, age_days: float, schema: str = "hil-result/1",
         size: int = 1000, trace: bool = False) -> Path:
    d = root / name
    d.mkdir(parents=True)
    (d / "result.json").write_text(json.dumps({"schema": schema, "scenario": name.split("-")[0],
                                               "suite": None, "passed": True}))
    (d / "recording.rrd").write_bytes(b"x" * size)
    if trace:
        (d / "plant.trace").write_bytes(b"t" * size)
    stamp = time.time() - age_days * 86400
    os.utime(d / "result.json", (stamp, stamp))
    return d


@pytest.fixture
def root(tmp_path: Path) -> Path:
    r = tmp_path / "out"
    for i in range(7):  # smoke-...: 0 (newest) to 6 days old
        _run(r, f"smoke-2026010{i}-120000", age_days=i, trace=(i == 6))
    _run(r, "paper", age_days=30, schema="hil-suite/1")  # ./hil main's fixed folder
    (_run(r, "paper/table2_0001rpm_0nm", age_days=30))  # inside the suite: part of it
    kept = _run(r, "smoke-20250101-120000", age_days=300)
    (kept / "KEEP").write_text("")
    (r / "fuzz").mkdir()  # not a run
    (r / "fuzz" / "log").write_text("fuzz")
    return r


def test_lists_runs_and_removes_nothing_without_yes(root: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    before = sorted(p.name for p in root.iterdir())
    assert cli.main(["clean", str(root)]) == 0
    out = capsys.readouterr().out
    assert "9 runs" in out and "2 marked x" in out and "nothing removed" in out
    assert "full-rate data" in out and "KEEP" in out and "named (--all)" in out
    assert sorted(p.name for p in root.iterdir()) == before


def test_removes_old_auto_named_runs_beyond_the_newest(root: Path) -> None:
    assert cli.main(["clean", str(root), "--yes"]) == 0
    left = sorted(p.name for p in root.iterdir())
    assert left == sorted(["fuzz", "paper", "smoke-20250101-120000",
                           *(f"smoke-2026010{i}-120000" for i in range(5))])
    assert (root / "paper" / "table2_0001rpm_0nm" / "result.json").is_file()


def test_older_than_and_all(root: Path) -> None:
    runs = list(outputs.find_runs(root))
    assert len(runs) == 9  # the suite's scenario folder is part of the suite
    chosen = outputs.select(runs, keep_last=0, older_than_days=2.5, include_named=False)
    assert [r.path.name for r in chosen] == [f"smoke-2026010{i}-120000" for i in (6, 5, 4, 3)]
    everything = outputs.select(runs, keep_last=0, older_than_days=None, include_named=True)
    assert {r.path.name for r in everything} == {
        "paper", *(f"smoke-2026010{i}-120000" for i in range(7))}  # never the KEEP folder
    for r in everything:
        outputs.remove(r, root)
    assert sorted(p.name for p in root.iterdir()) == ["fuzz", "smoke-20250101-120000"]


def test_refuses_a_folder_outside_the_root(tmp_path: Path, root: Path) -> None:
    elsewhere = _run(tmp_path / "mine", "smoke-20260101-000000", age_days=9)
    run = next(iter(outputs.find_runs(tmp_path / "mine")))
    with pytest.raises(ValueError, match="not inside"):
        outputs.remove(run, root)
    assert elsewhere.is_dir()


def test_missing_root_and_bad_numbers(tmp_path: Path) -> None:
    assert cli.main(["clean", str(tmp_path / "nothing")]) == 0
    assert cli.main(["clean", str(tmp_path), "--keep-last", "-1"]) == 2
    (tmp_path / "file").write_text("")
    assert cli.main(["clean", str(tmp_path / "file")]) == 3


def test_rig_run_says_when_runs_pile_up(root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from rig.commands import clean

    assert clean.notice(root) is None  # 8 auto-named runs of a few kB
    monkeypatch.setattr(clean, "NOTICE_RUNS", 5)
    hint = clean.notice(root)
    assert hint is not None and "8 runs named by time" in hint and "rig clean" in hint


@pytest.mark.parametrize("keep_in", ["archive", "root"])
def test_a_keep_above_a_run_keeps_it(tmp_path: Path, keep_in: str) -> None:
    """A KEEP file in a folder above a run (up to the root) keeps the runs filed there."""
    root = tmp_path / "out"
    archive = root / "archive"
    for i in range(7):
        _run(archive, f"smoke-2026010{i}-120000", age_days=i)
    (archive if keep_in == "archive" else root).joinpath("KEEP").write_text("")
    before = sorted(p.name for p in archive.iterdir())
    assert cli.main(["clean", str(root), "--keep-last", "0", "--yes"]) == 0
    assert sorted(p.name for p in archive.iterdir()) == before
    # and removing one by hand through the API is refused as well
    run = next(r for r in outputs.find_runs(root))
    assert run.keep
    with pytest.raises(ValueError, match="KEEP"):
        outputs.remove(run, root)
