"""Scenario and suite files at the edge of what a parser survives (issue 36's adversarial
campaign): each is a schema error with file and line and exit 2, never a traceback, and
costs what an ordinary file costs."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig import cli, scenario

HEAD = 'description = "x"\nprofile = "paper"\n'


@pytest.mark.parametrize(("body", "why"), [
    ("duration = " + "1" * 5000, "more than 400 digits"),
    ("duration = " + "1" * 1000, "integer of 1000 digits"),
    ("duration = 1.0\n[overrides" + ".a" * 5000 + "]\nb = 1", "nested more than 32"),
    ("duration = 1.0\n[firmware" + ".a" * 5000 + "]\nb = 1", "nested more than 32"),
    ("duration = 1.0\noverrides." + ".".join(["a"] * 5000) + " = 1", "nested more than 32"),
])
def test_huge_numbers_and_deep_tables(tmp_path: Path, body: str, why: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "x.toml"
    path.write_text(HEAD + body + "\n")
    with pytest.raises(scenario.ScenarioError, match=why):
        scenario.load_scenario(path)
    assert cli.main(["run", str(path), "--bus", "inproc", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{path.name}:" in err and "Traceback" not in err


def test_many_unknown_keys_are_counted_not_listed(tmp_path: Path) -> None:
    path = tmp_path / "x.toml"
    path.write_text(HEAD + "duration = 1.0\n" + "".join(f"k{i} = 1\n" for i in range(5000)))
    with pytest.raises(scenario.ScenarioError) as info:
        scenario.load_scenario(path)
    text = str(info.value)
    assert len(text.splitlines()) == 21 and "4980 more unknown fields" in text
    big = tmp_path / "big.toml"
    big.write_text(HEAD + "duration = 1.0\n" + "#" * (2 << 20) + "\n")
    with pytest.raises(scenario.ScenarioError, match="larger than"):
        scenario.load_scenario(big)


def test_a_suite_listing_one_scenario_many_times(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """20 000 entries of one scenario: one error naming it and the count; the scenario file
    is read once, not 20 000 times (which with the duplicates counted pairwise took
    minutes)."""
    from rig.scenario import suite as suite_module

    reads: list[Path] = []
    real = suite_module.parse_file

    def counted(p: Path) -> scenario.Scenario:
        reads.append(p)
        return real(p)

    monkeypatch.setattr(suite_module, "parse_file", counted)
    path = tmp_path / "s.toml"
    path.write_text('name = "s"\nscenarios = [' + ", ".join(['"smoke"'] * 20000) + "]\n")
    with pytest.raises(scenario.ScenarioError, match="'smoke' appears 20000 times"):
        scenario.load_suite(path)
    assert len(reads) == 1
