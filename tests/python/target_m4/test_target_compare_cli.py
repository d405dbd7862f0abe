"""``rig target compare`` on bad input (issue 36.7): an unknown name, an invalid scenario
file, a suite, ``--out`` on a file or on a user's folder were tracebacks; now each is a clear
message and exit 2, before anything runs, and nothing of the user's is touched."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig import cli
from rig.commands import target

SMOKE = Path(__file__).resolve().parents[3] / "rig" / "scenarios" / "smoke.toml"


def _bad(tmp_path: Path, case: str) -> tuple[list[str], str]:
    if case == "unknown name":
        return ["no-such-scenario"], "no scenario or suite 'no-such-scenario'"
    if case == "invalid file":
        bad = tmp_path / "bad.toml"
        bad.write_text("duration = \n")
        return [str(bad)], "bad.toml:1: TOML syntax"
    if case == "suite":
        return ["paper"], "paper is a suite"
    if case == "out on a file":
        f = tmp_path / "afile"
        f.write_text("mine")
        return ["smoke", "--out", str(f)], "is not a folder"
    folder = tmp_path / "user"
    (folder / "smoke").mkdir(parents=True)
    (folder / "smoke" / "notes.txt").write_text("mine")
    return ["smoke", "--out", str(folder)], "holds files of its own (smoke)"


@pytest.mark.parametrize("short", [True, False])
@pytest.mark.parametrize("case", ["unknown name", "invalid file", "suite", "out on a file",
                                  "out on a user folder"])
def test_bad_input_is_a_clear_error_and_exit_2(tmp_path: Path, case: str, short: bool,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    args, said = _bad(tmp_path, case)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert cli.main(["target", "compare", *args, *(["--short"] if short else [])]) == 2
    err = capsys.readouterr().err
    assert said in err and err.startswith("rig target compare: "), err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_out_is_refused_for_a_user_folder_and_reused_when_it_made_it(tmp_path: Path) -> None:
    out = tmp_path / "new"
    assert target.out_problem(out) is None
    out.mkdir()
    assert target.out_problem(out) is None  # empty
    (out / "x").write_text("")
    assert target.out_problem(out) is not None
    (out / target.MARK).touch()
    assert target.out_problem(out) is None
