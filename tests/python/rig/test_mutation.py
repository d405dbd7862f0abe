"""The mutation catalogue (tests/mutants/catalogue.toml) and how a campaign scores: every
mutant applies to the file it names exactly once and changes it, the classes are the
documented ones, enough of them, and the score leaves equivalent and stillborn ones out."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig import _paths
from rig.regression.mutation import campaign, catalogue


def test_every_mutant_applies_once_and_changes_its_file() -> None:
    mutants = catalogue.load()
    judged = [m for m in mutants if not m.equivalent]
    assert len(judged) >= 40
    assert {m.cls for m in mutants} <= set(catalogue.CLASSES)
    for m in mutants:
        text = (_paths.repo_dir() / m.file).read_text()
        assert m.apply(text) != text
        assert m.file.startswith("firmware_c2000/"), m.id


def test_a_patch_that_does_not_match_is_refused(tmp_path: Path) -> None:
    (tmp_path / "a.c").write_text("int x = 1;\nint x = 1;\n")
    cat = tmp_path / "c.toml"
    cat.write_text('[[mutant]]\nid = "m"\nclass = "sign"\nfile = "a.c"\ndescription = "d"\n'
                   'find = "int x = 1;"\nreplace = "int x = -1;"\n')
    with pytest.raises(catalogue.CatalogueError, match="occurs 2 times"):
        catalogue.load(cat, tmp_path)
    cat.write_text(cat.read_text().replace('class = "sign"', 'class = "typo"'))
    (tmp_path / "a.c").write_text("int x = 1;\n")
    with pytest.raises(catalogue.CatalogueError, match="class 'typo'"):
        catalogue.load(cat, tmp_path)


def test_score_counts_killed_over_judged() -> None:
    v = [campaign.Verdict(str(i), "", "", "sign", s) for i, s in enumerate(
        ["killed"] * 9 + ["survived", "equivalent", "stillborn"])]
    s = campaign.score(v)
    assert (s.killed, s.judged, s.equivalent, s.stillborn) == (9, 10, 1, 1)
    assert s.percent == pytest.approx(90.0)
    assert "9/10 killed (90 %)" in campaign.markdown(v, campaign.Gate(), ("ctest", "gate"))
