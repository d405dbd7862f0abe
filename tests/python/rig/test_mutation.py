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
    v = [campaign.Verdict(str(i), "", "", "sign", s, kill="confirmed" if s == "killed" else "")
         for i, s in enumerate(["killed"] * 9 + ["survived", "equivalent", "stillborn"])]
    s = campaign.score(v)
    assert (s.killed, s.judged, s.equivalent, s.stillborn) == (9, 10, 1, 1)
    assert s.percent == pytest.approx(90.0)
    assert "9/10 killed and confirmed (90 %)" in campaign.markdown(v, campaign.Gate(),
                                                                   ("ctest", "gate"))


def _write_cat(tmp_path: Path, **fields: object) -> Path:
    """A one-mutant catalogue with ``fields`` over a valid default."""
    import json as _json

    base: dict[str, object] = {"id": "m", "class": "sign", "file": "a.c", "description": "d",
                               "find": "int x = 1;", "replace": "int x = -1;"}
    base.update(fields)
    lines = ["[[mutant]]"] + [f"{k} = {_json.dumps(v)}" for k, v in base.items()]
    cat = tmp_path / "c.toml"
    cat.write_text("\n".join(lines) + "\n")
    return cat


@pytest.mark.parametrize(("fields", "why"), [
    ({"file": "/etc/passwd"}, "inside the tree"),
    ({"file": "../outside.c"}, "inside the tree"),
    ({"file": "sub/../../outside.c"}, "inside the tree"),
    ({"file": "link.c"}, "leads out of the tree"),
    ({"file": "zero"}, "leads out of the tree"),
    ({"file": "dev"}, "not a regular file"),
    ({"file": "fifo"}, "not a regular file"),
    ({"file": "big.c"}, "bytes"),
    ({"id": "../x"}, "id must be"),
    ({"id": "a/b"}, "id must be"),
    ({"find": 5}, "find must be a string"),
    ({"class": ["sign"]}, "class must be a string"),
])
def test_a_catalogue_patches_only_regular_files_inside_the_tree(
        tmp_path: Path, fields: dict[str, object], why: str) -> None:
    """A catalogue is input: a path out of the tree (absolute, .., a link), a device, a FIFO
    (it would block), an oversized file, an id that is a path, a wrong type: each a clear
    CatalogueError, nothing read or written outside the tree."""
    import os

    (tmp_path / "a.c").write_text("int x = 1;\n")
    (tmp_path / "outside.c").write_text("int x = 1;\n")
    tree = tmp_path / "tree"
    (tree / "sub").mkdir(parents=True)
    (tree / "a.c").write_text("int x = 1;\n")
    os.symlink(tmp_path / "outside.c", tree / "link.c")
    os.symlink("/dev/zero", tree / "zero")
    os.mkfifo(tree / "fifo")
    if os.geteuid() == 0:  # a character device inside the tree (as /dev/zero is)
        import stat

        os.mknod(tree / "dev", 0o600 | stat.S_IFCHR, os.makedev(1, 5))
    else:
        os.mkfifo(tree / "dev")
    (tree / "big.c").write_text("int x = 1;\n" + " " * (catalogue.MAX_FILE_BYTES + 1))
    cat = _write_cat(tmp_path, **fields)
    with pytest.raises(catalogue.CatalogueError, match=why):
        catalogue.load(cat, tree)
    assert (tmp_path / "outside.c").read_text() == "int x = 1;\n"


def test_the_benign_set_is_rounding_only_and_large_enough() -> None:
    """At least 20 benign mutants, each a change whose text differs but whose arithmetic is
    the same in exact numbers (checked by hand in review; here: they are all in the core or
    its build, and apply)."""
    benign = [m for m in catalogue.load() if m.benign]
    assert len(benign) >= 20
    for m in benign:
        assert m.file.startswith("firmware_c2000/"), m.id


def test_score_counts_confirmed_kills_and_false_alarms() -> None:
    v = [campaign.Verdict("a", "", "", "sign", "killed", kill="confirmed"),
         campaign.Verdict("b", "", "", "sign", "killed", kill="one-seed"),
         campaign.Verdict("c", "", "", "sign", "survived"),
         campaign.Verdict("d", "", "", "benign", "killed", kill="one-seed", benign=True),
         campaign.Verdict("e", "", "", "benign", "survived", benign=True),
         campaign.Verdict("seed-9", "", "", "null", "survived", benign=True)]
    s = campaign.score(v)
    assert (s.confirmed, s.one_seed, s.judged) == (1, 1, 3)
    assert s.percent == pytest.approx(100 / 3)
    assert (s.benign_killed, s.benign_judged, s.seeds_failed, s.seeds_judged) == (1, 2, 0, 1)
    md = campaign.markdown(v, campaign.Gate(), ("gate",))
    assert "1/3 killed and confirmed" in md and "false alarms 50.0 %" in md
