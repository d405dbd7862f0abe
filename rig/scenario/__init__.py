"""Scenarios as data: one TOML file per scenario, suites as files listing scenarios.

A scenario names a fidelity profile (plus overrides), the drive modes, a speed profile (a
sequence of segments), a load profile (events at absolute times), faults (``[[faults]]``,
``rig.scenario.faults``), the initial rotor state, the duration and the pass criteria. ``load()``
validates a file and reports every schema error with the file, the line and the field
(``file:line: field: message``); the CLI exits 2 on them. The wire enumerations (control
modes, flux-weakening modes, load modes) come from the DBC choices, not from this package.

The modules: ``model`` (the scenario and suite as the rig runs them), ``parse`` (a scenario
file's fields, checked), ``suite`` (suite files), ``schema`` and ``checks`` (schema errors
and what the plant and firmware accept), ``positions`` (the line of a key, for the errors),
``files`` and ``lookup`` (where scenarios and suites are, by name or path).
"""

from rig.scenario.files import (
    SCENARIO_DIR,
    SUITE_DIR,
    scenario_files,
    scenario_names,
    suite_files,
    validate_name,
)
from rig.scenario.lookup import find, is_suite_file, load
from rig.scenario.model import (
    PROFILES,
    SEED_KEY,
    Comparison,
    Criterion,
    LoadCommand,
    LoadEvent,
    Scenario,
    SpeedCommand,
    SpeedSegment,
    Suite,
)
from rig.scenario.parse import (
    LOAD_KINDS,
    MAX_DURATION_S,
    MAX_READY_TIMEOUT_S,
    MAX_TIMEOUT_S,
    SEGMENT_KINDS,
    load_scenario,
    parse_scenario,
)
from rig.scenario.positions import locate
from rig.scenario.schema import Issue, ScenarioError, field_name, read_text
from rig.scenario.suite import COMPARISON_RELATIONS, load_suite, parse_suite

__all__ = [
    "COMPARISON_RELATIONS", "LOAD_KINDS", "MAX_DURATION_S", "MAX_READY_TIMEOUT_S",
    "MAX_TIMEOUT_S", "PROFILES", "SCENARIO_DIR", "SEED_KEY", "SEGMENT_KINDS", "SUITE_DIR",
    "Comparison", "Criterion", "Issue", "LoadCommand", "LoadEvent", "Scenario", "ScenarioError",
    "SpeedCommand", "SpeedSegment", "Suite", "field_name", "find", "is_suite_file", "load",
    "load_scenario", "load_suite", "locate", "parse_scenario", "parse_suite", "read_text",
    "scenario_files", "scenario_names", "suite_files", "validate_name",
]
