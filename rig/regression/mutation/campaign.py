"""A mutation campaign: the unmutated tree first (it must pass every detector, or no kill
means anything), then each mutant built and judged by the detectors in turn, ctest (seconds)
then the gate (minutes; it stops at the first scenario that fails).

A kill by the gate is robust by construction: the gate compares against baselines whose
bands hold the unmutated firmware at every recorded seed (``rig baseline record`` refuses a
suite whose verdicts depend on the seed), so the same failure cannot come from the noise.
With ``both`` every detector runs on every mutant (for a per-detector score)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from rig.regression.mutation.catalogue import Mutant
from rig.regression.mutation.worktree import MutationTree, Step

KILLED, SURVIVED, STILLBORN, EQUIVALENT = "killed", "survived", "stillborn", "equivalent"


@dataclass
class Gate:
    """The suite a mutant must get past, run in process against the baselines."""

    suites: Sequence[str] = ("gate",)
    baseline: str = "require"
    jobs: int = 2
    seed: int | None = None

    def command(self, suite: str, out: Path) -> list[str]:
        cmd = [sys.executable, "-m", "rig", "run", suite, "--bus", "inproc", "--jobs",
               str(self.jobs), "--baseline", self.baseline, "--fail-fast", "--no-record",
               "--no-figures", "--quiet", "--out", str(out)]
        if self.seed is not None:
            cmd += ["--seed", str(self.seed)]
        return cmd


@dataclass
class Verdict:
    id: str
    description: str
    file: str
    cls: str
    status: str  # killed | survived | stillborn | equivalent
    killed_by: list[str] = field(default_factory=list)  # "ctest: name", "gate: scenario: why"
    seconds: float = 0.0
    note: str = ""


def _gate_failures(out: Path) -> list[str]:
    """What failed in a gate run: per failed scenario the criteria that failed or regressed."""
    try:
        data = json.loads((out / "result.json").read_text())
    except (OSError, ValueError):
        return ["no suite result"]
    found: list[str] = []
    for e in data.get("scenarios") or []:
        if e.get("passed"):
            continue
        why = [f"{c['name']} ({c.get('outcome')})" for c in e.get("criteria") or []
               if c.get("outcome") in ("fail", "not_evaluated")]
        why += [f"{c['name']} ({c['baseline']['class']})" for c in e.get("criteria") or []
                if (c.get("baseline") or {}).get("class") in ("regressed", "changed", "stale")]
        if e.get("failure"):
            why.append(str(e["failure"])[:120])
        found.append(f"{e['name']}: {'; '.join(why) or e.get('status')}")
    for c in data.get("comparisons") or []:
        if c.get("outcome") in ("fail", "not_evaluated"):
            found.append(f"comparison {c['name']}")
    return found or ([] if data.get("passed") else ["suite failed (incomplete)"])


_CTEST_FAILED = re.compile(r"^\s*\d+ - (\S+) \((Failed|Timeout|Exception|Not Run|SEGFAULT|"
                           r"Subprocess aborted|Child aborted|Bus error|[^)]*)\)")


def _ctest_failures(step: Step) -> list[str]:
    """The failed tests' names from ctest's closing summary."""
    found = [m.group(1) for line in step.log.splitlines()
             if (m := _CTEST_FAILED.match(line))]
    return found or (["ctest failed"] if not step.ok else [])


def run_gate(tree: MutationTree, gate: Gate, out: Path) -> tuple[bool, list[str]]:
    failures: list[str] = []
    for suite in gate.suites:
        folder = out / suite
        p = subprocess.run(gate.command(suite, folder), env=tree.env(), capture_output=True,
                           text=True, check=False)
        if p.returncode != 0:
            got = _gate_failures(folder)
            if not got:
                got = [f"exit {p.returncode}: {(p.stderr or '').strip()[-300:]}"]
            failures += [f"{suite}: {g}" for g in got]
            break
    return not failures, failures


def judge(m: Mutant, tree: MutationTree, gate: Gate, out: Path, both: bool,
          detectors: Sequence[str]) -> Verdict:
    v = Verdict(m.id, m.description, m.file, m.cls, SURVIVED)
    if m.equivalent:
        v.status, v.note = EQUIVALENT, m.equivalent
        return v
    t0 = time.monotonic()
    original = tree.apply(m)
    try:
        built = tree.compile()
        if not built.ok:
            v.status, v.note = STILLBORN, built.log[-400:]
            return v
        if "ctest" in detectors:
            step = tree.ctest()
            if not step.ok:
                v.killed_by += [f"ctest: {n}" for n in _ctest_failures(step)]
        if "gate" in detectors and (both or not v.killed_by):
            ok, failures = run_gate(tree, gate, out / m.id)
            if not ok:
                v.killed_by += [f"gate: {f}" for f in failures]
        v.status = KILLED if v.killed_by else SURVIVED
        return v
    finally:
        tree.restore(m, original)
        v.seconds = time.monotonic() - t0


def control(tree: MutationTree, gate: Gate, out: Path, detectors: Sequence[str]) -> list[str]:
    """The unmutated tree through every detector: what fails here makes kills meaningless."""
    problems: list[str] = []
    built = tree.compile()
    if not built.ok:
        return [f"the unmutated tree does not build:\n{built.log[-2000:]}"]
    if "ctest" in detectors:
        step = tree.ctest()
        if not step.ok:
            problems += [f"ctest: {n}" for n in _ctest_failures(step)]
    if "gate" in detectors:
        _ok, failures = run_gate(tree, gate, out / "_control")
        problems += [f"gate: {f}" for f in failures]
    return problems


@dataclass
class Score:
    total: int
    equivalent: int
    stillborn: int
    killed: int
    survived: int

    @property
    def judged(self) -> int:
        return self.killed + self.survived

    @property
    def percent(self) -> float:
        return 100.0 * self.killed / self.judged if self.judged else 0.0


def score(verdicts: Sequence[Verdict]) -> Score:
    def n(s: str) -> int:
        return sum(1 for v in verdicts if v.status == s)

    return Score(len(verdicts), n(EQUIVALENT), n(STILLBORN), n(KILLED), n(SURVIVED))


def run(mutants: Sequence[Mutant], tree: MutationTree, gate: Gate, out: Path, *,
        both: bool = False, detectors: Sequence[str] = ("ctest", "gate"),
        progress: Callable[[str], None] | None = None) -> list[Verdict]:
    verdicts: list[Verdict] = []
    for i, m in enumerate(mutants, 1):
        v = judge(m, tree, gate, out, both, detectors)
        verdicts.append(v)
        write(out, verdicts, gate, detectors)
        if progress is not None:
            why = f" by {v.killed_by[0]}" if v.killed_by else (f": {v.note[:80]}"
                                                                 if v.note else "")
            progress(f"[{i}/{len(mutants)}] {m.id}: {v.status.upper()}{why} "
                     f"({v.seconds:.0f} s)")
    return verdicts


def write(out: Path, verdicts: Sequence[Verdict], gate: Gate, detectors: Sequence[str]) -> None:
    s = score(verdicts)
    data: dict[str, Any] = {
        "gate": asdict(gate), "detectors": list(detectors), "score": {
            **asdict(s), "percent": round(s.percent, 1)},
        "mutants": [asdict(v) for v in verdicts],
    }
    (out / "results.json").write_text(json.dumps(data, indent=1))
    (out / "summary.md").write_text(markdown(verdicts, gate, detectors))


def markdown(verdicts: Sequence[Verdict], gate: Gate, detectors: Sequence[str]) -> str:
    s = score(verdicts)
    lines = [
        f"# Mutation score: {s.killed}/{s.judged} killed ({s.percent:.0f} %)", "",
        f"detectors: {', '.join(detectors)}; gate: suites {', '.join(gate.suites)} in process, "
        f"baseline {gate.baseline}; {s.equivalent} equivalent, {s.stillborn} stillborn", "",
        "| mutant | class | file | status | killed by |", "|---|---|---|---|---|",
    ]
    for v in verdicts:
        lines.append(f"| {v.id} | {v.cls} | `{Path(v.file).name}` | {v.status} | "
                     f"{(v.killed_by[0] if v.killed_by else v.note)[:140]} |")
    survivors = [v for v in verdicts if v.status == SURVIVED]
    if survivors:
        lines += ["", "## Survivors", ""]
        lines += [f"- `{v.id}`: {v.description} ({v.file})" for v in survivors]
    return "\n".join(lines) + "\n"
