"""A mutation campaign: the unmutated tree first (it must pass every detector, or no kill
means anything), then each mutant built and judged by the detectors in turn, ctest (seconds)
then the gate (minutes; it stops at the first scenario whose failure the seeds confirm).

A kill by the gate is *confirmed* when what failed holds over fresh seeds: a regression the
confirmation confirmed (rig.regression.confirm), a limit that fails with values the fresh
seeds confirm worse, a crash or a stall. A gate that failed only on limits at one seed,
which the fresh seeds do not confirm, is a *one-seed* kill: it may be the noise drawn again,
and the score counts it apart. ctest's kills are deterministic (fixed inputs and seeds) and
count as confirmed; the benign mutants measure what that costs (a rounding-only change that
ctest kills is its false alarm).

Benign mutants (class ``benign``: rounding only) are judged the same way; for them a kill is
a false alarm. ``null_seeds``: the unmutated tree's gate at seeds the baselines never saw,
each a harmless change in effect (the noise drawn again); a failure there is a false alarm
too. With ``both`` every detector runs on every mutant (for a per-detector score)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from rig.regression.mutation.catalogue import Mutant
from rig.regression.mutation.worktree import MutationTree, Step

KILLED, SURVIVED, STILLBORN, EQUIVALENT = "killed", "survived", "stillborn", "equivalent"
# how a kill stands over the seeds (rig.regression.confirm.failure_kind)
CONFIRMED, ONE_SEED = "confirmed", "one-seed"


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
    kill: str = ""  # a kill: confirmed | one-seed
    benign: bool = False


def _gate_failures(out: Path) -> tuple[list[str], str]:
    """What failed in a gate run: per failed scenario the criteria that failed or regressed,
    and how the failure stands over the seeds (confirmed, one-seed; '' when nothing
    failed)."""
    from rig.regression.confirm import failure_kind

    try:
        data = json.loads((out / "result.json").read_text())
    except (OSError, ValueError):
        return ["no suite result"], CONFIRMED
    found: list[str] = []
    kinds: list[str] = []
    for e in data.get("scenarios") or []:
        if e.get("passed"):
            continue
        why = [f"{c['name']} ({c.get('outcome')})" for c in e.get("criteria") or []
               if c.get("outcome") in ("fail", "not_evaluated")]
        why += [f"{c['name']} ({c['baseline']['class']}"
                + (f": {c['baseline']['where']}" if c["baseline"].get("where") else "") + ")"
                for c in e.get("criteria") or []
                if (c.get("baseline") or {}).get("class") in ("regressed", "changed", "stale",
                                                               "missing")]
        if e.get("failure"):
            why.append(str(e["failure"])[:120])
        kind = failure_kind(e)
        kinds.append(kind)
        found.append(f"{e['name']} [{kind}]: {'; '.join(why) or e.get('status')}")
    for c in data.get("comparisons") or []:
        if c.get("outcome") in ("fail", "not_evaluated"):
            found.append(f"comparison {c['name']}")
            kinds.append(ONE_SEED)
    if not found and not data.get("passed"):
        return ["suite failed (incomplete)"], CONFIRMED
    kind = CONFIRMED if CONFIRMED in kinds or "stale" in kinds else (ONE_SEED if kinds else "")
    return found, kind


_CTEST_FAILED = re.compile(r"^\s*\d+ - (\S+) \((Failed|Timeout|Exception|Not Run|SEGFAULT|"
                           r"Subprocess aborted|Child aborted|Bus error|[^)]*)\)")


def _ctest_failures(step: Step) -> list[str]:
    """The failed tests' names from ctest's closing summary."""
    found = [m.group(1) for line in step.log.splitlines()
             if (m := _CTEST_FAILED.match(line))]
    return found or (["ctest failed"] if not step.ok else [])


def run_gate(tree: MutationTree, gate: Gate, out: Path) -> tuple[bool, list[str], str]:
    """The gate on the tree's build: passed, what failed, and how that stands over the seeds
    (confirmed or one-seed)."""
    failures: list[str] = []
    kind = ""
    for suite in gate.suites:
        folder = out / suite
        p = subprocess.run(gate.command(suite, folder), env=tree.env(), capture_output=True,
                           text=True, check=False)
        if p.returncode != 0:
            got, kind = _gate_failures(folder)
            if not got:
                got, kind = [f"exit {p.returncode}: {(p.stderr or '').strip()[-300:]}"], \
                    CONFIRMED
            failures += [f"{suite}: {g}" for g in got]
            break
    return not failures, failures, kind


def judge(m: Mutant, tree: MutationTree, gate: Gate, out: Path, both: bool,
          detectors: Sequence[str]) -> Verdict:
    v = Verdict(m.id, m.description, m.file, m.cls, SURVIVED, benign=m.benign)
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
        kinds: list[str] = []
        if "ctest" in detectors:
            step = tree.ctest()
            if not step.ok:
                v.killed_by += [f"ctest: {n}" for n in _ctest_failures(step)]
                kinds.append(CONFIRMED)
        if "gate" in detectors and (both or not v.killed_by):
            ok, failures, kind = run_gate(tree, gate, out / m.id)
            if not ok:
                v.killed_by += [f"gate: {f}" for f in failures]
                kinds.append(kind or CONFIRMED)
        v.status = KILLED if v.killed_by else SURVIVED
        if v.killed_by:
            v.kill = CONFIRMED if CONFIRMED in kinds else ONE_SEED
        return v
    finally:
        tree.restore(m, original)
        v.seconds = time.monotonic() - t0


def null_run(seed: int, tree: MutationTree, gate: Gate, out: Path) -> Verdict:
    """The unmutated tree's gate at ``seed`` (not one the baselines recorded): a harmless
    change in effect; a failure is a false alarm."""
    t0 = time.monotonic()
    v = Verdict(f"seed-{seed}", f"the unmutated firmware at seed {seed}", "", "null",
                SURVIVED, benign=True)
    ok, failures, kind = run_gate(tree, replace(gate, seed=seed), out / f"_seed-{seed}")
    if not ok:
        v.status, v.killed_by, v.kill = KILLED, [f"gate: {f}" for f in failures], \
            kind or CONFIRMED
    v.seconds = time.monotonic() - t0
    return v


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
        _ok, failures, _kind = run_gate(tree, gate, out / "_control")
        problems += [f"gate: {f}" for f in failures]
    return problems


@dataclass
class Score:
    """The harmful mutants' score (kills over the judged), the kills split by how they stand
    over the seeds; and the false-alarm rates of the harmless runs (benign mutants, the
    unmutated tree at unrecorded seeds)."""

    total: int
    equivalent: int
    stillborn: int
    killed: int
    survived: int
    confirmed: int = 0
    one_seed: int = 0
    benign_judged: int = 0
    benign_killed: int = 0
    seeds_judged: int = 0
    seeds_failed: int = 0

    @property
    def judged(self) -> int:
        return self.killed + self.survived

    @property
    def percent(self) -> float:
        """Confirmed kills over the judged harmful mutants: the score the README quotes."""
        return 100.0 * self.confirmed / self.judged if self.judged else 0.0

    @property
    def benign_percent(self) -> float:
        return 100.0 * self.benign_killed / self.benign_judged if self.benign_judged else 0.0

    @property
    def seeds_percent(self) -> float:
        return 100.0 * self.seeds_failed / self.seeds_judged if self.seeds_judged else 0.0


def score(verdicts: Sequence[Verdict]) -> Score:
    harmful = [v for v in verdicts if not v.benign]
    benign = [v for v in verdicts if v.benign and v.cls != "null"]
    null = [v for v in verdicts if v.cls == "null"]

    def n(vs: Sequence[Verdict], s: str) -> int:
        return sum(1 for v in vs if v.status == s)

    return Score(
        len(harmful), n(harmful, EQUIVALENT), n(harmful, STILLBORN), n(harmful, KILLED),
        n(harmful, SURVIVED),
        confirmed=sum(1 for v in harmful if v.status == KILLED and v.kill == CONFIRMED),
        one_seed=sum(1 for v in harmful if v.status == KILLED and v.kill == ONE_SEED),
        benign_judged=n(benign, KILLED) + n(benign, SURVIVED), benign_killed=n(benign, KILLED),
        seeds_judged=len(null), seeds_failed=n(null, KILLED))


def summary_lines(s: Score) -> list[str]:
    """What the campaign measured, one line per kind of run."""
    out = []
    if s.judged or s.total:
        out.append(f"harmful: {s.confirmed}/{s.judged} killed and confirmed ({s.percent:.0f} %)"
                   f"; {s.one_seed} one-seed kills, {s.survived} survived, {s.equivalent} "
                   f"equivalent, {s.stillborn} stillborn")
    if s.benign_judged:
        out.append(f"benign (rounding only): {s.benign_killed}/{s.benign_judged} failed: false "
                   f"alarms {s.benign_percent:.1f} %")
    if s.seeds_judged:
        out.append(f"unmutated at unrecorded seeds: {s.seeds_failed}/{s.seeds_judged} failed: "
                   f"false alarms {s.seeds_percent:.1f} %")
    return out


def say_one(v: Verdict, i: int, total: int, progress: Callable[[str], None]) -> None:
    """One verdict said as a line (a campaign on a cluster, where no display runs)."""
    progress(_line(v, i, total))


def run(mutants: Sequence[Mutant], tree: MutationTree, gate: Gate, out: Path, *,
        both: bool = False, detectors: Sequence[str] = ("ctest", "gate"),
        null_seeds: Sequence[int] = (),
        progress: Callable[[str], None] | None = None) -> list[Verdict]:
    """Every run of the campaign: the unmutated gate at ``null_seeds``, then each mutant; one
    progress display over them (k/N, elapsed, ETA), each verdict said as it comes."""
    from rig.run.progress import Display

    verdicts: list[Verdict] = []
    seeds = list(null_seeds) if "gate" in detectors else []
    total = len(mutants) + len(seeds)
    with Display("mutate", total, unit="run", enabled=progress is not None) as shown:
        items: list[tuple[str, Callable[[], Verdict]]] = [
            (f"seed-{s}", lambda s=s: null_run(s, tree, gate, out)) for s in seeds]
        items += [(m.id, lambda m=m: judge(m, tree, gate, out, both, detectors))
                  for m in mutants]
        for i, (name, work) in enumerate(items, 1):
            shown.start(name)
            v = work()
            verdicts.append(v)
            write(out, verdicts, gate, detectors)
            line = _line(v, i, total)
            shown.done(name, v.status != KILLED if v.benign else v.status == KILLED, line)
    return verdicts


def _line(v: Verdict, i: int, total: int) -> str:
    why = f" by {v.killed_by[0]}" if v.killed_by else (f": {v.note[:80]}" if v.note else "")
    what = v.status.upper() + (f" ({v.kill})" if v.kill else "")
    if v.benign and v.status == KILLED:
        what += " = FALSE ALARM"
    return f"[{i}/{total}] {v.id}: {what}{why} ({v.seconds:.0f} s)"


def write(out: Path, verdicts: Sequence[Verdict], gate: Gate, detectors: Sequence[str]) -> None:
    s = score(verdicts)
    data: dict[str, Any] = {
        "gate": asdict(gate), "detectors": list(detectors), "score": {
            **asdict(s), "percent": round(s.percent, 1),
            "benign_percent": round(s.benign_percent, 1),
            "seeds_percent": round(s.seeds_percent, 1)},
        "mutants": [asdict(v) for v in verdicts],
    }
    (out / "results.json").write_text(json.dumps(data, indent=1))
    (out / "summary.md").write_text(markdown(verdicts, gate, detectors))


def markdown(verdicts: Sequence[Verdict], gate: Gate, detectors: Sequence[str]) -> str:
    s = score(verdicts)
    lines = [
        f"# Mutation score: {s.confirmed}/{s.judged} killed and confirmed ({s.percent:.0f} %)",
        "", *[f"- {x}" for x in summary_lines(s)], "",
        f"detectors: {', '.join(detectors)}; gate: suites {', '.join(gate.suites)} in process, "
        f"baseline {gate.baseline}, flags confirmed at fresh seeds (rig.regression.confirm)",
        "", "| run | class | file | status | kill | killed by |", "|---|---|---|---|---|---|",
    ]
    for v in verdicts:
        status = v.status + (" (false alarm)" if v.benign and v.status == KILLED else "")
        lines.append(f"| {v.id} | {v.cls} | `{Path(v.file).name}` | {status} | {v.kill} | "
                     f"{(v.killed_by[0] if v.killed_by else v.note)[:140]} |")
    survivors = [v for v in verdicts if v.status == SURVIVED and not v.benign]
    if survivors:
        lines += ["", "## Survivors", ""]
        lines += [f"- `{v.id}`: {v.description} ({v.file})" for v in survivors]
    alarms = [v for v in verdicts if v.benign and v.status == KILLED]
    if alarms:
        lines += ["", "## False alarms (a harmless run failed)", ""]
        lines += [f"- `{v.id}`: {v.description}: {'; '.join(v.killed_by)[:300]}"
                  for v in alarms]
    return "\n".join(lines) + "\n"
