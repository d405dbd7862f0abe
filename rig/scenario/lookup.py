"""A scenario or suite by name or path: the file it names, and which of the two it is."""

from __future__ import annotations

import tomllib
from pathlib import Path

from rig.scenario.checker import ScenarioError, read_text
from rig.scenario.files import SCENARIO_DIR, SUITE_DIR
from rig.scenario.model import Scenario, Suite
from rig.scenario.parse import load_scenario, parse_file
from rig.scenario.suite import load_suite


def is_suite_file(path: Path) -> bool:
    try:
        data = tomllib.loads(read_text(path))
        return "scenarios" in data or "include" in data
    except (OSError, tomllib.TOMLDecodeError, ScenarioError):
        return False


def find(target: str | Path) -> Path:
    """The file of a scenario or suite given by name or path."""
    p = Path(target)
    if p.is_file():
        return p
    for cand in (SCENARIO_DIR / f"{target}.toml", SUITE_DIR / f"{target}.toml"):
        if cand.is_file():
            return cand
    raise FileNotFoundError(
        f"no scenario or suite {str(target)!r} (a file, or a name in {SCENARIO_DIR} or {SUITE_DIR})"
    )


def load(target: str | Path) -> Scenario | Suite:
    """A scenario or a suite, by name or path; ``<scenario>@<profile>`` runs a scenario on
    another fidelity profile."""
    text = str(target)
    if "@" in text and not Path(text).is_file():
        base, _, profile = text.rpartition("@")
        return parse_file(find(base)).with_profile(profile)
    p = find(target)
    return load_suite(p) if is_suite_file(p) else load_scenario(p)
