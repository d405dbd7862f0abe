"""A scenario or suite by name or path: the file it names, and which of the two it is."""

from __future__ import annotations

from pathlib import Path

from rig.scenario.files import SCENARIO_DIR, SUITE_DIR
from rig.scenario.model import Scenario, Suite
from rig.scenario.parse import load_scenario, parse_file
from rig.scenario.schema import ScenarioError, parse_toml, read_text
from rig.scenario.suite import load_suite


def is_suite_file(path: Path) -> bool:
    try:
        data = parse_toml(path, read_text(path))
        return "scenarios" in data or "include" in data
    except (OSError, ScenarioError):
        return False


def find(target: str | Path) -> Path:
    """The file of a scenario or suite given by name or path."""
    p = Path(target)
    if p.is_file():
        return p
    for cand in (SCENARIO_DIR / f"{target}.toml", SUITE_DIR / f"{target}.toml"):
        if cand.is_file():
            return cand
    near = nearest_names(str(target))
    raise FileNotFoundError(
        f"no scenario or suite {str(target)!r} (a file, or a name in {SCENARIO_DIR} or "
        f"{SUITE_DIR})" + (f"; did you mean {' or '.join(near)}?" if near else ""))


def nearest_names(text: str, n: int = 3) -> list[str]:
    """The shipped scenario and suite names closest to ``text`` (a misspelt name)."""
    import difflib

    names = [p.stem for d in (SCENARIO_DIR, SUITE_DIR) for p in sorted(d.glob("*.toml"))]
    return difflib.get_close_matches(text, names, n=n, cutoff=0.6)


def load(target: str | Path) -> Scenario | Suite:
    """A scenario or a suite, by name or path; ``<scenario>@<profile>`` runs a scenario on
    another fidelity profile."""
    text = str(target)
    if "@" in text and not Path(text).is_file():
        base, _, profile = text.rpartition("@")
        return parse_file(find(base)).with_profile(profile)
    p = find(target)
    return load_suite(p) if is_suite_file(p) else load_scenario(p)
