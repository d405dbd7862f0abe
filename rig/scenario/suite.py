"""Suites: files listing scenarios (by name or path, ``<scenario>@<profile>`` on another
fidelity profile), including other suites, and comparing criterion values between two of
their runs (``[[comparisons]]``)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rig.scenario.files import SCENARIO_DIR, SUITE_DIR, scenario_path, suite_path
from rig.scenario.model import PROFILES, Comparison, Scenario, Suite
from rig.scenario.parse import parse_file
from rig.scenario.positions import Path_
from rig.scenario.schema import (
    MAX_SHOWN,
    Checker,
    Issue,
    ScenarioError,
    parse_toml,
    read_text,
)

COMPARISON_RELATIONS = ("<", "<=", ">", ">=")


def parse_suite(file: Path, text: str) -> Suite:
    data = parse_toml(file, text)
    c = Checker(file, text)
    c.table(data, (), ("name", "description", "include", "scenarios", "comparisons"))
    name = c.string(data, (), "name", file.stem)
    description = c.string(data, (), "description", "")
    scenarios: list[Scenario] = []
    comparisons: list[Comparison] = []
    issues: list[Issue] = []
    included = data.get("include", [])
    if not isinstance(included, list) or not all(isinstance(x, str) for x in included):
        c.err(("include",), "must be a list of suite names")
        included = []
    for i, entry in enumerate(included):
        sub = suite_path(entry, file.parent)
        if sub is None or sub.resolve() in _including:
            c.err(("include", i), f"no suite {entry!r} (looked in {SUITE_DIR})" if sub is None
                  else f"suite {entry!r} includes itself")
            continue
        _including.add(sub.resolve())
        try:
            inner = load_suite(sub)
        except ScenarioError as exc:
            issues.extend(exc.issues)
            continue
        finally:
            _including.discard(sub.resolve())
        scenarios.extend(inner.scenarios)
        comparisons.extend(inner.comparisons)
    raw = data.get("scenarios", [])
    if not isinstance(raw, list) or not (raw or scenarios):
        c.err(("scenarios",), "must be a non-empty list of scenario names or paths "
                              "(or the suite must include other suites)")
        raw = []
    parsed: dict[Path, Scenario | ScenarioError] = {}  # each file read once
    for i, entry in enumerate(raw):
        if not isinstance(entry, str):
            c.err(("scenarios", i), f"must be a scenario name or path, not {entry!r}")
            continue
        base, _, profile = entry.partition("@")
        if profile and profile not in PROFILES:
            c.err(("scenarios", i), f"profile {profile!r} is not one of: {', '.join(PROFILES)}")
            continue
        target = scenario_path(base, file.parent)
        if target is None:
            c.err(("scenarios", i), f"no scenario {base!r} (looked in {SCENARIO_DIR})")
            continue
        if target not in parsed:
            try:
                parsed[target] = parse_file(target)
            except ScenarioError as exc:
                parsed[target] = exc
                issues.extend(exc.issues)
        sc = parsed[target]
        if isinstance(sc, ScenarioError):
            continue
        scenarios.append(sc.with_profile(profile) if profile else sc.on_own_profile())
    if not issues:
        comparisons += _comparisons(c, data.get("comparisons", []), scenarios)
    seen = Counter(s.name for s in scenarios)
    for dup in sorted(n for n, k in seen.items() if k > 1)[:MAX_SHOWN]:
        c.err(("scenarios",), f"{dup!r} appears {seen[dup]} times (its output folder is its "
                              "name)")
    if c.issues or issues:
        raise ScenarioError(c.issues + issues)
    return Suite(name, file, description, tuple(scenarios), tuple(comparisons))

_including: set[Path] = set()  # suites being parsed (include cycles)


def _comparisons(c: Checker, raw: Any, scenarios: Sequence[Scenario]) -> list[Comparison]:
    if not isinstance(raw, list):
        c.err(("comparisons",), "must be an array of tables ([[comparisons]])")
        return []
    by_name = {s.name: s for s in scenarios}
    out: list[Comparison] = []
    for i, item in enumerate(raw):
        path: Path_ = ("comparisons", i)
        d = c.table(item, path, ("name", "criterion", "a", "b", "relation", "xfail"))
        if not d:
            continue
        crit = c.string(d, path, "criterion")
        runs = []
        for key in ("a", "b"):
            run = c.string(d, path, key)
            sc = by_name.get(run)
            if run and sc is None:
                c.err((*path, key), f"{run!r} is not a scenario of this suite "
                                    f"(entries: {', '.join(by_name) or 'none'})")
            elif sc is not None and crit and not any(
                    cr.name == crit and cr.applies_to(sc.profile) for cr in sc.criteria):
                c.err((*path, "criterion"),
                      f"scenario {run!r} has no criterion named {crit!r} on profile {sc.profile}")
            runs.append(run)
        relation = c.string(d, path, "relation", "<", choices=COMPARISON_RELATIONS)
        name = c.string(d, path, "name", f"{runs[0]} {relation} {runs[1]}: {crit}")
        xfail = c.string(d, path, "xfail", "")
        out.append(Comparison(name, crit, runs[0], runs[1], relation, xfail))
    return out


def load_suite(path: str | Path) -> Suite:
    p = Path(path)
    return parse_suite(p, read_text(p))
