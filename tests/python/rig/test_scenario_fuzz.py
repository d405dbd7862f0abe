"""Property tests of the scenario loader (Hypothesis): whatever a file holds, loading it
either gives a scenario or a ScenarioError whose issues name the file and a line of it;
never another exception (a traceback in ``rig run``)."""

from __future__ import annotations

import math
import re
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_scenario import GOOD

from rig import scenario as sc

FILE = Path("/nonexistent/fuzz.toml")

toml_scalar = st.one_of(
    st.integers(min_value=-(2**63), max_value=2**63 - 1).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(
        lambda x: "nan" if math.isnan(x) else ("inf" if x == math.inf else
                                               "-inf" if x == -math.inf else repr(x))),
    st.booleans().map(lambda b: "true" if b else "false"),
    st.text(alphabet=st.characters(blacklist_categories=("Cs", "Cc")), max_size=12).map(
        lambda s: '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'),
)
toml_value = st.recursive(
    toml_scalar,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3).map(lambda xs: "[" + ", ".join(xs) + "]"),
        st.dictionaries(st.from_regex(r"[a-z_]{1,8}", fullmatch=True), inner, max_size=3).map(
            lambda d: "{ " + ", ".join(f"{k} = {v}" for k, v in d.items()) + " }")),
    max_leaves=6)

ASSIGNMENT = re.compile(r"^(\s*[\w\"\.]+\s*=\s*)(.+)$")
GOOD_LINES = GOOD.splitlines()
VALUE_LINES = [i for i, line in enumerate(GOOD_LINES) if ASSIGNMENT.match(line)]


def check(text: str) -> None:
    try:
        s = sc.parse_scenario(FILE, text)
    except sc.ScenarioError as exc:
        n_lines = text.count("\n") + 1
        assert exc.issues
        for issue in exc.issues:
            assert issue.file == str(FILE)
            assert issue.line is None or 1 <= issue.line <= n_lines, (issue, n_lines)
            assert issue.message
        return
    assert s.duration > 0 and math.isfinite(s.duration)
    assert s.duration <= sc.MAX_DURATION_S


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(VALUE_LINES), toml_value), min_size=1, max_size=4))
def test_any_value_in_a_good_scenario_is_loaded_or_reported(
        edits: list[tuple[int, str]]) -> None:
    lines = list(GOOD_LINES)
    for i, value in edits:
        m = ASSIGNMENT.match(GOOD_LINES[i])
        assert m
        lines[i] = m.group(1) + value
    check("\n".join(lines) + "\n")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["overrides", "firmware", "run", "drive", "limits",
                                           "initial"]),
                          st.from_regex(r"[a-z_]{1,12}(\.[a-z_]{1,12})?", fullmatch=True),
                          toml_scalar), max_size=4))
def test_any_table_entry_is_loaded_or_reported(entries: list[tuple[str, str, str]]) -> None:
    text = 'description = "p"\nprofile = "paper"\nduration = 1.0\n'
    for table, key, value in entries:
        text += f'[{table}]\n"{key}" = {value}\n'
    check(text)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=300))
def test_any_text_is_loaded_or_reported(text: str) -> None:
    check(text)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_in_a_file_are_loaded_or_reported(data: bytes) -> None:
    import tempfile

    with tempfile.NamedTemporaryFile(suffix=".toml") as fh:
        fh.write(data)
        fh.flush()
        try:
            sc.load_scenario(fh.name)
        except sc.ScenarioError as exc:
            assert all(i.file == fh.name for i in exc.issues)


FAULT_KEYS = ["at", "duration", "kind", "channel", "phase", "gate", "value", "code", "ramp",
              "message", "delay", "signal", "xor", "other"]
FAULT_WORDS = st.sampled_from(['"adc_offset"', '"adc_stuck"', '"gate_off"', '"dc_link"',
                               '"frame_corrupt"', '"frame_delay"', '"heartbeat_loss"', '"ia"',
                               '"vdc"', '"c"', '"lower"', '"VIO_ADC_0"', '"DRIVE_CMD"',
                               '"ia_0"', '"speed_ref"', "0.5", "3", "65536", "0x10000"])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.dictionaries(st.sampled_from(FAULT_KEYS), st.one_of(FAULT_WORDS, toml_value),
                                max_size=6), min_size=1, max_size=3))
def test_any_faults_event_is_loaded_or_reported(events: list[dict[str, str]]) -> None:
    """[[faults]] tables of any keys and values (issue 15.1): a scenario or file:line:field."""
    text = 'description = "p"\nprofile = "paper"\nduration = 1.0\n'
    for event in events:
        text += "[[faults]]\n" + "".join(f"{k} = {v}\n" for k, v in event.items())
    check(text)
