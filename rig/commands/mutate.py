"""``rig mutate``: the mutation catalogue against the gate and the C tests."""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from rig import cliargs

if TYPE_CHECKING:
    from collections.abc import Callable

    from rig.regression.mutation.campaign import Gate, Verdict
    from rig.regression.mutation.catalogue import Mutant
    from rig.regression.mutation.worktree import MutationTree

EPILOG = """\
Each mutant of tests/mutants/catalogue.toml is applied alone to a copy of this checkout
(OUT/work), rebuilt incrementally, and judged: ctest, then the gate (the suite `gate` in
process against the committed baselines, its flags confirmed at fresh seeds, stopping at the
first scenario whose failure the seeds confirm). The unmutated copy goes through the same
detectors first and must pass them. Results in OUT/results.json and OUT/summary.md.

The score counts confirmed kills / (killed + survived) of the harmful mutants, leaving out
those argued equivalent in the catalogue and those that do not compile; a kill the fresh
seeds do not confirm (a limit failed at one seed only) is counted apart. --set benign runs
the rounding-only mutants instead (class benign): every kill is a false alarm.
--null-seeds LIST also runs the unmutated gate at seeds the baselines never saw: a failure
is a false alarm. `rig mutate --set all --null-seeds 9-28` prints all three rates.

--cluster tcp://HOST:PORT runs the control, the null seeds and the mutants as tasks on a Dask
cluster: each worker unpacks this checkout into a tree of its own, builds it once and judges
one mutant at a time (--jobs is then each worker's build and gate parallelism); every worker
must run this same rig. A lost worker's mutant is judged again on another one.

exit status: 0 the campaign ran (whatever the score); 1 the unmutated tree fails a detector;
2 usage or catalogue error; 3 the cluster could not run the campaign.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "mutate", help="mutation testing: does the gate catch realistic firmware bugs?",
        description="Apply realistic firmware bugs one at a time and check that the gate or "
        "the C tests catch each of them.", epilog=EPILOG)
    p.add_argument("--only", default=None, metavar="IDS",
                   help="comma-separated mutant ids (default: the whole catalogue)")
    p.add_argument("--catalogue", type=Path, default=None, metavar="FILE",
                   help="another catalogue file")
    p.add_argument("--suite", default="gate", metavar="SUITES",
                   help="the gate's suites, comma-separated (default: gate)")
    p.add_argument("--baseline", choices=("require", "auto", "off"), default="require",
                   help="how the gate uses the baselines (off: the criteria's limits only)")
    p.add_argument("--detectors", default="ctest,gate", metavar="LIST",
                   help="ctest and/or gate (default both, ctest first)")
    p.add_argument("--both", action="store_true",
                   help="run every detector on every mutant (a score per detector)")
    p.add_argument("--seed", type=cliargs.number(int, minimum=0, maximum=2**31 - 1),
                   default=None, metavar="N",
                   help="run the gate at this noise seed (default: the profiles')")
    p.add_argument("--jobs", "-j", type=cliargs.number(int, minimum=1, maximum=64), default=2,
                   metavar="N", help="build and gate parallelism (default 2)")
    cliargs.add_shared(p, "out", type=Path,
                       help="results (default: $HIL_OUT or ./out, mutate-time)")
    p.add_argument("--keep-work", action="store_true",
                   help="keep the work copy (source and build) afterwards")
    p.add_argument("--set", dest="which", choices=("harmful", "benign", "all"),
                   default="harmful",
                   help="which mutants: the harmful ones (default), the benign "
                   "rounding-only ones (their kills are false alarms), or all")
    p.add_argument("--null-seeds", default=None, metavar="LIST",
                   help="also run the unmutated gate at these seeds (e.g. 9-28; none of the "
                   "baselines' 1-8): each failure is a false alarm")
    p.add_argument("--cluster", default=None, metavar="tcp://HOST:PORT",
                   help="judge the mutants on the Dask cluster whose scheduler is at this "
                   "address (each worker builds its own copy of this checkout)")
    p.add_argument("--no-worker-timeout", type=cliargs.number(above=0.0), default=60.0,
                   metavar="S", help="with --cluster: end the campaign when the cluster has "
                   "had no worker for S seconds (default 60; exit 3)")
    p.add_argument("--list", action="store_true", help="list the catalogue and exit")
    cliargs.command(p, cmd_mutate)


def cmd_mutate(args: argparse.Namespace) -> int:
    from rig import outputs
    from rig.regression.mutation import campaign, catalogue
    from rig.regression.mutation.worktree import MutationTree

    try:
        mutants = catalogue.load(args.catalogue)
    except catalogue.CatalogueError as exc:
        print(f"rig mutate: {exc}", file=sys.stderr)
        return 2
    if args.list:
        for m in mutants:
            eq = f"  [equivalent: {m.equivalent}]" if m.equivalent else ""
            print(f"{m.id:<32} {m.cls:<6} {Path(m.file).name:<22} {m.description}{eq}")
        print(f"{len(mutants)} mutants", file=sys.stderr)
        return 0
    if args.only:
        wanted = [x.strip() for x in args.only.split(",") if x.strip()]
        unknown = sorted(set(wanted) - {m.id for m in mutants})
        if unknown:
            print(f"rig mutate: unknown mutants: {', '.join(unknown)[:500]}", file=sys.stderr)
            return 2
        mutants = [m for m in mutants if m.id in wanted]
    elif args.which != "all":
        mutants = [m for m in mutants if m.benign == (args.which == "benign")]
    null_seeds: tuple[int, ...] = ()
    if args.null_seeds:
        from rig.run.seeds import parse_seeds

        try:
            null_seeds = parse_seeds(args.null_seeds)
        except ValueError as exc:
            print(f"rig mutate: --null-seeds: {exc}", file=sys.stderr)
            return 2
    detectors = [d.strip() for d in args.detectors.split(",") if d.strip()]
    if not detectors or set(detectors) - {"ctest", "gate"}:
        print("rig mutate: --detectors takes ctest and/or gate", file=sys.stderr)
        return 2
    out = args.out or outputs.default_out("mutate")
    out.mkdir(parents=True, exist_ok=True)
    gate = campaign.Gate(tuple(s.strip() for s in args.suite.split(",") if s.strip()),
                         args.baseline, args.jobs, args.seed)
    if args.cluster is not None:
        return _on_cluster(args, mutants, gate, out, detectors, null_seeds)
    # the copy lives in a short temporary path: the C bus tests put Unix sockets under their
    # build folder, and a socket address holds at most 107 bytes
    work = Path(tempfile.mkdtemp(prefix="rig-mutate-"))
    try:
        return _campaign(args, mutants, gate, MutationTree(work, jobs=args.jobs), out,
                         detectors, null_seeds)
    finally:
        if not args.keep_work:
            shutil.rmtree(work, ignore_errors=True)


def _on_cluster(args: argparse.Namespace, mutants: list[Mutant], gate: Gate, out: Path,
                detectors: list[str], null_seeds: tuple[int, ...]) -> int:
    from rig.regression.mutation import on_cluster
    from rig.run.cluster import ClusterError

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    say(f"rig mutate: {len(mutants)} mutants on the cluster at {args.cluster}; the unmutated "
        "tree first through " + ", ".join(detectors))
    try:
        problems, verdicts = on_cluster.run(
            args.cluster, mutants, gate, out, both=args.both, detectors=detectors,
            null_seeds=null_seeds, no_worker_timeout_s=args.no_worker_timeout, progress=say)
    except ClusterError as exc:
        say(f"rig mutate: {exc}; the verdicts that arrived are in {out}")
        return 3
    except KeyboardInterrupt:
        say(f"rig mutate: interrupted; partial results in {out}")
        return 130
    if problems:
        say("rig mutate: the unmutated tree fails; no kill would mean anything:")
        for p in problems:
            say(f"  {p}")
        return 1
    return _said(verdicts, out, say)


def _said(verdicts: list[Verdict], out: Path, say: Callable[[str], None]) -> int:
    """The campaign's score and its survivors and false alarms, as every campaign ends."""
    from rig.regression.mutation import campaign

    s = campaign.score(verdicts)
    for line in campaign.summary_lines(s):
        say(f"rig mutate: {line}")
    say(f"rig mutate: -> {out}/summary.md")
    for v in verdicts:
        if v.status == campaign.SURVIVED and not v.benign:
            say(f"  survived: {v.id}: {v.description}")
        if v.status == campaign.KILLED and v.benign:
            say(f"  false alarm: {v.id}: {v.killed_by[0][:160]}")
    return 0


def _campaign(args: argparse.Namespace, mutants: list[Mutant], gate: Gate, tree: MutationTree,
              out: Path, detectors: list[str], null_seeds: tuple[int, ...]) -> int:
    from rig.regression.mutation import campaign
    from rig.regression.mutation.worktree import BuildError

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    try:
        say(f"rig mutate: {len(mutants)} mutants; copying the tree to {tree.src}")
        tree.copy()
        step = tree.configure()
        if not step.ok:
            say(f"rig mutate: cmake configure failed:\n{step.log[-2000:]}")
            return 1
        say("rig mutate: the unmutated tree through " + ", ".join(detectors))
        problems = campaign.control(tree, gate, out, detectors)
    except BuildError as exc:
        say(f"rig mutate: {exc}")
        return 1
    if problems:
        say("rig mutate: the unmutated tree fails; no kill would mean anything:")
        for p in problems:
            say(f"  {p}")
        return 1
    try:
        verdicts = campaign.run(mutants, tree, gate, out, both=args.both,
                                detectors=detectors, null_seeds=null_seeds, progress=say)
    except KeyboardInterrupt:
        say(f"rig mutate: interrupted; partial results in {out}")
        return 130
    return _said(verdicts, out, say)
