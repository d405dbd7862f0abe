"""A suite over several plant noise seeds, in process: every scenario once per seed, all of
them spread over worker processes (``rig baseline record``, ``rig compare``). The seed is a
dimension of a run: the same scenario, the noise drawn from another seed."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from rig.bench import sil
from rig.results.result import RunResult
from rig.run import parallel
from rig.run.options import RunOptions
from rig.run.progress import Display
from rig.scenario import Scenario, Suite


def parse_seeds(text: str) -> tuple[int, ...]:
    """``1-8`` or ``1,2,5`` (or a mix: ``1-4,9``) as a sorted tuple of distinct seeds."""
    out: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a = int(lo)
            b = int(hi) if sep else a
        except ValueError:
            raise ValueError(f"not a seed or a range of seeds: {part!r}") from None
        if a < 0 or b < a or b - a > 1000:
            raise ValueError(f"not a range of seeds: {part!r}")
        out.update(range(a, b + 1))
    if not out:
        raise ValueError("no seeds given")
    return tuple(sorted(out))


@dataclass
class SeedRuns:
    """The runs of a suite per seed, in the suite's order (None: the run wrote nothing)."""

    suite: Suite
    seeds: tuple[int, ...]
    root: Path
    runs: dict[int, list[RunResult | None]]

    def of(self, seed: int, sc: Scenario) -> RunResult | None:
        i = next(i for i, s in enumerate(self.suite.scenarios) if s.name == sc.name)
        return self.runs[seed][i]


def seed_dir(root: Path, seed: int) -> Path:
    return root / f"seed-{seed}"


def run_over_seeds(suite: Suite, seeds: Sequence[int], root: Path, jobs: int,
                   progress: bool = True) -> SeedRuns:
    """Every scenario of ``suite`` at every seed, into ``root/seed-N/<scenario>``, on the
    in-process bench, ``jobs`` at a time; only the verdicts are kept (no recording, no
    full-rate data of passing runs). A scenario decided over its own seeds runs once (in
    the first seed's folder) and stands for every seed: no outer seed changes it."""
    base = RunOptions(out=root, bus=sil.INPROC, progress=False, record=False, keep="failing")
    slots: list[tuple[int, int]] = []  # (seed index, scenario index) of each job
    work: list[parallel.Job] = []
    for k, seed in enumerate(seeds):
        for i, sc in enumerate(suite.scenarios):
            if sc.seeds and k > 0:
                continue
            slots.append((k, i))
            work.append(parallel.Job(sc.with_seed(seed),
                                     replace(base, out=seed_dir(root, seed) / sc.name)))
    total = len(work)
    display = Display(f"{suite.name} over seeds {seeds[0]}-{seeds[-1]}", total, unit="run",
                      enabled=progress, work=[j.scenario.duration * max(1, len(j.scenario.seeds))
                                              for j in work])

    def done(job: parallel.Job, r: RunResult | None) -> None:
        verdict = "?" if r is None else "PASS" if r.passed else "FAIL"
        seed = job.scenario.seed
        display.done(job.scenario.name, r is not None and r.passed,
                     f"[{display.done_items + 1}/{total}] seed "
                     f"{seed if seed is not None else 'own'} {job.scenario.name}: {verdict}")

    got: list[RunResult | None] = [None] * total
    with display:
        parallel.run_jobs(work, jobs, got, on_done=done)
    runs: dict[int, list[RunResult | None]] = {
        seed: [None] * len(suite.scenarios) for seed in seeds}
    for (k, i), r in zip(slots, got, strict=True):
        runs[seeds[k]][i] = r
    for i, sc in enumerate(suite.scenarios):
        if sc.seeds:
            for seed in seeds[1:]:
                runs[seed][i] = runs[seeds[0]][i]
    return SeedRuns(suite, tuple(seeds), root, runs)
