"""Scenario schema: shipped files load; malformed ones name the file, the line and the field."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rig import scenario as sc
from rig.cli import main as rig_main

GOOD = """\
description = "test scenario"
profile = "paper"
duration = 2.0

[drive]
fw_mode = "conventional"
enable_at = 0.01

[[speed]]
kind = "ramp"
to = 1000.0
duration = 0.5

[[speed]]
kind = "trapezoid"
peak = 1500.0
rise = 0.25
hold = 0.1
fall = 0.25
dwell = 0.1
repeat = 2

[[load]]
at = 1.0
kind = "step"
torque = 2.0

[[load]]
at = 1.5
kind = "ramp"
torque = 0.5
duration = 0.01

[[criteria]]
name = "drop"
metric = "speed_drop_pct"
window = [1.0, "end"]
limit = 20.0
params = { baseline_s = 0.1 }
"""


def _write(tmp: Path, text: str, name: str = "case") -> Path:
    p = tmp / f"{name}.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("path", sc.scenario_files(), ids=lambda p: p.stem)
def test_shipped_scenarios_are_valid(path: Path) -> None:
    s = sc.load_scenario(path)
    assert s.name == path.stem and s.description and s.criteria
    assert s.profile in sc.PROFILES


@pytest.mark.parametrize("path", sc.suite_files(), ids=lambda p: p.stem)
def test_shipped_suites_are_valid(path: Path) -> None:
    su = sc.load_suite(path)
    assert su.scenarios


def test_paper_suite_covers_the_figures() -> None:
    su = sc.load("paper")
    assert isinstance(su, sc.Suite)
    figures = {s.figure.split("(")[0].strip() for s in su.scenarios}
    assert {"Table 2", "Fig. 5", "Fig. 6", "Fig. 7", "Fig. 8", "Fig. 9", "Fig. 10", "Fig. 11",
            "Fig. 12"} <= figures


def test_good_scenario_model(tmp_path: Path) -> None:
    s = sc.load_scenario(_write(tmp_path, GOOD))
    assert (s.profile, s.fw_mode, s.ctrl_mode, s.duration) == ("paper", "conventional", "speed",
                                                               2.0)
    assert s.criteria[0].window == (1.0, 2.0) and s.criteria[0].params == {"baseline_s": 0.1}
    cmds = s.speed_commands(step_accel=1e5)
    # ramp 0->1000 in 0.5 s, then 2 x (ramp to 1500 in 0.25, hold, ramp to 1000, dwell)
    assert [(round(c.t, 6), c.target, round(c.accel, 6)) for c in cmds] == [
        (0.0, 1000.0, 2000.0),
        (0.5, 1500.0, 2000.0), (0.85, 1000.0, 2000.0),
        (1.2, 1500.0, 2000.0), (1.55, 1000.0, 2000.0),
    ]
    ref = s.speed_reference(np.array([0.0, 0.25, 0.5, 0.625, 0.75, 0.8, 0.975, 1.1, 1.9]), 1e5)
    np.testing.assert_allclose(ref, [0, 500, 1000, 1250, 1500, 1500, 1250, 1000, 1000])
    loads = s.load_commands()
    assert loads[0].t == 0 and loads[0].torque == 0
    assert (loads[1].t, loads[1].torque) == (1.0, 2.0)
    ramp = [c for c in loads if 1.5 <= c.t < 1.51]
    assert len(ramp) == 10 and ramp[0].torque == pytest.approx(2.0 - 1.5 * 0.05)
    assert loads[-1].t == pytest.approx(1.51) and loads[-1].torque == 0.5
    bps = s.breakpoints(1e5)
    assert {0.0, 0.01, 0.5, 0.85, 1.0, 1.2, 1.5, 1.55} <= {round(b, 6) for b in bps}


def test_reference_is_rate_limited_when_the_next_command_comes_early() -> None:
    s = sc.parse_scenario(Path("x.toml"), GOOD.replace(
        'kind = "ramp"\nto = 1000.0\nduration = 0.5',
        'kind = "step"\nto = 1000.0\nduration = 0.005'))
    # a step with a slow limit (1000 r/min/s) is cut short by the trapezoid at 5 ms
    ref = s.speed_reference(np.array([0.005, 0.01]), step_accel=1000.0)
    np.testing.assert_allclose(ref, [5.0, 5.0 + 2000.0 * 0.005])


BAD_CASES = [
    # (text, line, field, message fragment)
    (GOOD.replace('profile = "paper"', 'profile = "paperr"'), 2, "profile", "not one of"),
    (GOOD.replace("duration = 2.0", 'duration = "2 s"'), 3, "duration", "finite number"),
    (GOOD.replace("duration = 2.0", "duration = -1.0"), 3, "duration", "must be > 0"),
    (GOOD.replace('fw_mode = "conventional"', 'fw_mode = "nominal"'), 6, "drive.fw_mode",
     "realtime, conventional, id_zero"),
    (GOOD.replace('kind = "trapezoid"', 'kind = "trapezium"'), 15, "speed[1].kind",
     "not one of"),
    (GOOD.replace("peak = 1500.0\n", ""), 14, "speed[1].peak", "missing"),
    (GOOD.replace("torque = 2.0\n", "torque = 2.0\nspeeed = 3\n"), 27, "load[0].speeed",
     "unknown field"),
    (GOOD.replace('window = [1.0, "end"]', "window = [1.0, 2.5]"), 37, "criteria[0].window[1]",
     "after the end"),
    (GOOD.replace('metric = "speed_drop_pct"', 'metric = "speed_dorp_pct"'), 36,
     "criteria[0].metric", "unknown metric"),
    (GOOD.replace("params = { baseline_s = 0.1 }", "params = { baseline = 0.1 }"), 39,
     "criteria[0].params.baseline", "unknown field"),
    (GOOD + "\n[runn]\nx = 1\n", 41, "runn", "unknown field"),
    (GOOD.replace("[drive]", "[drive]\nenable = 1"), 6, "drive.enable", "unknown field"),
    (GOOD.replace("repeat = 2", "repeat = 0"), 21, "speed[1].repeat", "integer >= 1"),
]


def schema_error(tmp: Path, text: str, line: int, field: str,
                 fragment: str) -> sc.ScenarioError:
    """The error loading ``text`` raises, which names the file, ``line`` and ``field`` and
    says ``fragment``."""
    path = _write(tmp, text)
    with pytest.raises(sc.ScenarioError) as info:
        sc.load_scenario(path)
    msg = str(info.value)
    assert f"{path}:{line}: {field}: " in msg, msg
    assert fragment in msg, msg
    return info.value


@pytest.mark.parametrize("text, line, field, fragment", BAD_CASES)
def test_schema_errors_name_file_line_and_field(tmp_path: Path, text: str, line: int,
                                                field: str, fragment: str) -> None:
    error = schema_error(tmp_path, text, line, field, fragment)
    assert len(error.issues) == 1, str(error)


def test_all_problems_are_reported_at_once(tmp_path: Path) -> None:
    text = GOOD.replace('profile = "paper"', "profile = 3").replace("limit = 20.0", "limit = []")
    with pytest.raises(sc.ScenarioError) as info:
        sc.load_scenario(_write(tmp_path, text))
    fields = [i.field for i in info.value.issues]
    assert fields == ["profile", "criteria[0].limit"]
    assert [i.line for i in info.value.issues] == [2, 38]


def test_inline_arrays_of_tables_are_located(tmp_path: Path) -> None:
    text = """description = "inline"
profile = "ideal"
duration = 1.0
speed = [
  { kind = "ramp", to = 100.0, duration = 0.2 },
  { kind = "hold", duration = "long" },  # a comment with { braces } and [brackets]
]
criteria = [{ metric = "pos_err_max_deg", limit = 1 }]
"""
    with pytest.raises(sc.ScenarioError) as info:
        sc.load_scenario(_write(tmp_path, text))
    assert f"{tmp_path / 'case.toml'}:6: speed[1].duration: must be a finite number" in str(
        info.value)


def test_missing_required_key_points_at_its_table(tmp_path: Path) -> None:
    text = GOOD.replace('kind = "ramp"\nto = 1000.0\n', 'kind = "ramp"\n')
    with pytest.raises(sc.ScenarioError, match=r"case\.toml:9: speed\[0\]\.to: required"):
        sc.load_scenario(_write(tmp_path, text))


def test_toml_syntax_error_has_its_line(tmp_path: Path) -> None:
    text = GOOD.replace("limit = 20.0", "limit = = 20.0")
    with pytest.raises(sc.ScenarioError, match=r"case\.toml:38: TOML syntax"):
        sc.load_scenario(_write(tmp_path, text))


def test_semantic_checks(tmp_path: Path) -> None:
    rev = GOOD.replace('kind = "ramp"\nto = 1000.0', 'kind = "reversal"\nto = 1000.0')
    with pytest.raises(sc.ScenarioError, match=r"speed\[0\]\.to: a reversal goes"):
        sc.load_scenario(_write(tmp_path, rev, "rev"))
    long = GOOD.replace("duration = 2.0", "duration = 1.0")
    with pytest.raises(sc.ScenarioError) as info:
        sc.load_scenario(_write(tmp_path, long, "long"))
    assert "longer than duration" in str(info.value)
    assert "load[0].at: 1 s is not before the end" in str(info.value)
    named = 'name = "other"\n' + GOOD
    with pytest.raises(sc.ScenarioError, match=r"named\.toml:1: name: must match"):
        sc.load_scenario(_write(tmp_path, named, "named"))


def test_suite_errors_name_the_entry(tmp_path: Path) -> None:
    _write(tmp_path, GOOD, "ok_one")
    suite = _write(tmp_path, 'description = "s"\nscenarios = [\n  "ok_one",\n  "nope",\n]\n',
                   "suite")
    with pytest.raises(sc.ScenarioError, match=r"suite\.toml:4: scenarios\[1\]: no scenario"):
        sc.load_suite(suite)
    good_suite = _write(tmp_path, 'scenarios = ["ok_one", "smoke"]\n', "suite2")
    loaded = sc.load(good_suite)
    assert isinstance(loaded, sc.Suite) and [s.name for s in loaded.scenarios] == ["ok_one",
                                                                                   "smoke"]


LOCATOR_TEXT = '''title = "a [b] # not a comment = x"
"quoted.key" = 1
dotted.inner = 2
multi = """
[[not_a_header]]
"""
[table]
key = [1,
  2, # comment [
  3]
[[arr]]
x = 1
[[arr]]
x = 2
[arr.sub]
y = 3
[[arr.list]]
z = 4
'''


@pytest.mark.parametrize("path, line", [
    (("title",), 1), (("quoted.key",), 2), (("dotted", "inner"), 3), (("multi",), 4),
    (("table",), 7), (("table", "key"), 8), (("table", "key", 2), 10), (("arr", 0, "x"), 12),
    (("arr", 1), 13), (("arr", 1, "x"), 14), (("arr", 1, "sub", "y"), 16),
    (("arr", 1, "list", 0, "z"), 18), (("arr", 1, "missing"), 13), (("nope",), None),
])
def test_locator(path: tuple[str | int, ...], line: int | None) -> None:
    import tomllib

    tomllib.loads(LOCATOR_TEXT)  # valid TOML
    assert sc.locate(LOCATOR_TEXT, path) == line


def test_cli_exits_2_on_schema_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = _write(tmp_path, GOOD.replace("duration = 2.0", "duration = 0"), "bad")
    assert rig_main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:3: duration: must be > 0" in err
    assert not (tmp_path / "o").exists()
    assert rig_main(["run", "no_such_scenario_anywhere"]) == 2


def test_cli_list_shows_name_profile_duration_description(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert rig_main(["list"]) == 0
    out = capsys.readouterr().out
    smoke = next(line for line in out.splitlines() if line.startswith("smoke "))
    assert "ideal" in smoke and "0.5 s" in smoke and "closed-loop" in smoke
    assert any(line.startswith("paper ") and "suite" in line for line in out.splitlines())
    assert rig_main(["list", "--metrics"]) == 0
    assert "pos_err_max_deg" in capsys.readouterr().out


def test_subcommands_have_help(capsys: pytest.CaptureFixture[str]) -> None:
    for cmd in ("run", "list", "view"):
        assert rig_main([cmd, "--help"]) == 0  # a status, not a SystemExit (rig.cli.main)
        assert len(capsys.readouterr().out) > 200


def test_view_without_recording_exits_2(tmp_path: Path) -> None:
    assert rig_main(["view", str(tmp_path)]) == 2


PER_PROFILE = """
description = "per-profile criteria"
profile = "paper"
duration = 1.0

[[criteria]]
name = "err"
metric = "pos_err_max_deg"
limit = 0.5
profiles = ["ideal"]

[[criteria]]
name = "err"
metric = "pos_err_max_deg"
limit = 2.5
profiles = ["paper"]
xfail = "measured 3.1 deg: noise-limited window (note 6)"

[[criteria]]
name = "err"
metric = "pos_err_max_deg"
comparison = "report"
profiles = ["harsh"]

[[criteria]]
name = "speed"
metric = "speed_track_err_max_rpm"
limit = 10
"""


def test_criteria_per_profile_and_profile_override(tmp_path: Path) -> None:
    p = _write(tmp_path, PER_PROFILE, "cell")
    own = sc.load_scenario(p)
    assert [(c.name, c.limit) for c in own.criteria] == [("err", 2.5), ("speed", 10.0)]
    assert own.criteria[0].xfail.startswith("measured 3.1")
    harsh = sc.load(f"{p}@harsh")
    assert isinstance(harsh, sc.Scenario)
    assert harsh.name == "cell@harsh" and harsh.profile == "harsh"
    assert [c.comparison for c in harsh.criteria] == ["report", "<="]
    suite = _write(tmp_path, 'scenarios = ["cell@ideal", "cell"]\n', "s")
    su = sc.load_suite(suite)
    assert [s.name for s in su.scenarios] == ["cell@ideal", "cell"]
    assert [c.limit for c in su.scenarios[0].criteria] == [0.5, 10.0]


@pytest.mark.parametrize(("extra", "message"), [
    ('profiles = ["fast"]', "is not one of"),
    ('xfail = " "', "reason"),
])
def test_criterion_profile_and_xfail_checks(tmp_path: Path, extra: str, message: str) -> None:
    text = ('description = "x"\nprofile = "paper"\nduration = 1.0\n[[criteria]]\n'
            f'metric = "pos_err_max_deg"\nlimit = 1\n{extra}\n')
    with pytest.raises(sc.ScenarioError, match=message):
        sc.parse_scenario(tmp_path / "x.toml", text)


def test_duplicate_names_only_on_a_common_profile(tmp_path: Path) -> None:
    text = PER_PROFILE.replace('profiles = ["harsh"]', 'profiles = ["harsh", "paper"]')
    with pytest.raises(sc.ScenarioError, match="duplicate criterion name"):
        sc.parse_scenario(tmp_path / "cell.toml", text)


def test_table2_files_are_what_the_generator_writes() -> None:
    """The grid cells are generated (rig/scenario/table2.py is their source)."""
    from rig.scenario import SCENARIO_DIR, table2

    files = table2.render()
    assert len(files) == 17
    for name, text in files.items():
        assert (SCENARIO_DIR / name).read_text() == text, \
            f"{name} is stale: rerun rig.scenario.table2"
        assert "not measured yet" not in text, f"{name}: run the grid, then --measured"


def test_start_files_are_what_the_generator_writes() -> None:
    """The starts' scenarios and suite are generated (rig/scenario/starts.py is their source)."""
    from rig.scenario import SCENARIO_DIR, starts

    files = starts.files()
    assert len(files) == 14  # 5 starts against a load, 8 flying starts, the suite
    for name, text in files.items():
        assert (SCENARIO_DIR / name).read_text() == text, \
            f"{name} is stale: rerun python -m rig.scenario.starts"


COMPARED = '''description = "two runs compared"
scenarios = ["ok_one", "ok_two"]

[[comparisons]]
name = "one drops less than two"
criterion = "crit"
a = "ok_one"
b = "ok_two"
relation = "<"
'''


def test_suite_comparisons_and_includes(tmp_path: Path) -> None:
    crit = '\n[[criteria]]\nname = "crit"\nmetric = "speed_drop_pct"\ncomparison = "report"\n'
    body = GOOD.split("[[criteria]]")[0]
    _write(tmp_path, body + crit, "ok_one")
    _write(tmp_path, body + crit, "ok_two")
    su = sc.load_suite(_write(tmp_path, COMPARED, "cmp"))
    assert su.comparisons == (sc.Comparison("one drops less than two", "crit", "ok_one",
                                            "ok_two", "<"),)
    outer = sc.load_suite(_write(tmp_path, 'include = ["cmp"]\nscenarios = ["smoke"]\n', "outer"))
    assert [s.name for s in outer.scenarios] == ["ok_one", "ok_two", "smoke"]
    assert outer.comparisons == su.comparisons
    bad = COMPARED.replace('b = "ok_two"', 'b = "ok_three"').replace('"crit"\na', '"nope"\na')
    with pytest.raises(sc.ScenarioError) as info:
        sc.load_suite(_write(tmp_path, bad, "bad"))
    msg = str(info.value)
    assert "comparisons[0].b: 'ok_three' is not a scenario of this suite" in msg
    assert "comparisons[0].criterion: scenario 'ok_one' has no criterion named 'nope'" in msg
    with pytest.raises(sc.ScenarioError, match="includes itself"):
        sc.load_suite(_write(tmp_path, 'include = ["loop"]\n', "loop"))
    with pytest.raises(sc.ScenarioError, match="appears 2 times"):
        sc.load_suite(_write(tmp_path, 'include = ["cmp"]\nscenarios = ["ok_one"]\n', "dup"))


def test_paper_suite_is_table2_then_figures_then_robustness_with_the_fig9_comparisons() -> None:
    paper, t2, figs, rob = (sc.load(n) for n in ("paper", "table2", "figures", "robustness"))
    assert isinstance(paper, sc.Suite) and isinstance(t2, sc.Suite)
    assert isinstance(figs, sc.Suite) and isinstance(rob, sc.Suite)
    assert paper.scenarios == t2.scenarios + figs.scenarios + rob.scenarios
    assert {(c.a, c.b) for c in paper.comparisons} == {
        ("fig09_load_step_realtime", "fig09_load_step_conventional")}


# -- what a file may hold that tomllib accepts but the rig did not (issue: tracebacks) ----

HUGE = "9" * 400  # an integer beyond the float range (TOML integers are unbounded here)
NUMBER_LINE = re.compile(r"^(\s*[\w\"\.]+\s*=\s*)(-?[0-9][0-9_.eE+-]*)\s*(#.*)?$")


def _number_lines() -> list[tuple[Path, int]]:
    out = []
    for path in sc.scenario_files():
        for i, line in enumerate(path.read_text().splitlines()):
            if NUMBER_LINE.match(line):
                out.append((path, i))
    return out


def test_an_integer_beyond_float_range_in_any_number_field_is_a_schema_error() -> None:
    seen_fields: set[str] = set()
    for path, i in _number_lines():
        lines = path.read_text().splitlines()
        m = NUMBER_LINE.match(lines[i])
        assert m is not None
        for value in (HUGE, "-" + HUGE):
            text = "\n".join([*lines[:i], m.group(1) + value, *lines[i + 1:]])
            with pytest.raises(sc.ScenarioError) as info:
                sc.parse_scenario(path, text)
            hit = [x for x in info.value.issues if x.line == i + 1]
            assert hit, (path.name, lines[i], str(info.value))
            assert "digits" in str(info.value) or "must be" in str(info.value)
            assert HUGE not in str(info.value)  # named, not quoted
        seen_fields.add(m.group(1).split("=")[0].strip())
    # the fields the issue found (and more): every number a shipped scenario writes
    assert {"at", "duration", "to", "torque", "limit", "i_max", "value", "repeat", "peak",
            "timeout_s", "grant_max_s", "soc_on_us", "k_speed", "ramp"} <= seen_fields


@pytest.mark.parametrize("nested", ["[" * 5000 + "]" * 5000,
                                    "{ a = " * 5000 + "1" + " }" * 5000])
def test_deep_nesting_is_a_schema_error_at_its_line(tmp_path: Path, nested: str) -> None:
    path = _write(tmp_path, GOOD + f"x = {nested}\n")
    with pytest.raises(sc.ScenarioError) as info:
        sc.load(path)
    assert f"{path}:{GOOD.count(chr(10)) + 1}: arrays or inline tables nested more than" in str(
        info.value)
    assert rig_main(["run", str(path), "--bus", "inproc", "--out", str(tmp_path / "o")]) == 2


def test_a_utf8_byte_order_mark_is_accepted(tmp_path: Path) -> None:
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + GOOD.encode())
    s = sc.load(path)
    assert isinstance(s, sc.Scenario) and s.duration == 2.0
    with pytest.raises(sc.ScenarioError) as info:  # and the lines stay the file's lines
        path.write_bytes(b"\xef\xbb\xbf" + GOOD.replace("duration = 2.0", "duration = -2").encode())
        sc.load(path)
    assert f"{path}:3: duration: " in str(info.value)


def test_an_unknown_profile_after_the_at_is_a_usage_error(tmp_path: Path) -> None:
    with pytest.raises(sc.ScenarioError, match="unknown profile 'nope'"):
        sc.load("smoke@nope")
    assert rig_main(["run", "smoke@nope", "--bus", "inproc", "--out", str(tmp_path)]) == 2
