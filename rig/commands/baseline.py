"""``rig baseline``: record a suite's baseline over several noise seeds, or show one."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Any

from rig import cliargs

EPILOG = """\
record: runs every scenario of SUITE in process at every seed (default 1-8), refuses a
baseline whose verdicts depend on the seed or that holds a failing criterion (exit 1,
naming them), and otherwise writes rig/baselines/SUITE.toml (--to FILE elsewhere) and says
how the values moved against the file it replaces. Review the file's diff like code.

show: the baseline of SUITE (or a baseline file) as a table.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "baseline", help="record or show a suite's accepted values and their seed spread",
        description="Baselines hold every criterion's accepted value with a tolerance band "
        "from its spread over the plant's noise seeds (rig/baselines/<suite>.toml). `rig run` "
        "compares with them: a value beyond its band on the worse side fails the run even "
        "inside the criterion's limit.",
        epilog=EPILOG)
    verbs = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    r = verbs.add_parser("record", help="run a suite over several seeds and write its baseline")
    r.add_argument("suite", metavar="SUITE", help="a suite name or file (rig list)")
    r.add_argument("--seeds", default="1-8", metavar="LIST",
                   help="noise seeds: a range and/or a list, e.g. 1-8 or 1,2,3,4,5 "
                   "(default 1-8, at least 5)")
    r.add_argument("--jobs", "-j", type=cliargs.number(int, minimum=1, maximum=64), default=2,
                   metavar="N", help="scenario runs at once, one worker process each "
                   "(default 2)")
    cliargs.add_shared(r, "out", type=Path,
                       help="where the runs go (default: $HIL_OUT or ./out, baseline-SUITE-time)")
    r.add_argument("--from", dest="from_dir", type=Path, default=None, metavar="DIR",
                   help="accept the runs an earlier `rig baseline record --out DIR` left "
                   "(DIR/seed-N/<scenario>) instead of running the suite again")
    r.add_argument("--to", type=Path, default=None, metavar="FILE",
                   help="write the baseline here instead of rig/baselines/SUITE.toml")
    cliargs.command(r, cmd_record)
    s = verbs.add_parser("show", help="print a suite's baseline")
    s.add_argument("suite", metavar="SUITE|FILE")
    cliargs.command(s, cmd_show)


def _git(*args: str) -> str:
    from rig import _paths

    try:
        return subprocess.run(["git", *args], cwd=_paths.repo_dir(), capture_output=True,
                              text=True, timeout=10, check=False).stdout.strip()
    except (OSError, subprocess.SubprocessError, FileNotFoundError):
        return ""


def source() -> dict[str, Any]:
    """What the baseline was recorded with: the commit, whether the tree had changes, the
    in-process bench's hash."""
    from rig import _paths
    from rig.bench import sil
    from rig.run.versions import sha

    out: dict[str, Any] = {"commit": _git("rev-parse", "--short=12", "HEAD") or "unknown"}
    out["dirty"] = bool(_git("status", "--porcelain", "--untracked-files=no"))
    try:
        out["silbench_sha256"] = sha(_paths.library(sil.LIBRARY))[:16]
    except FileNotFoundError:
        pass
    return out


def cmd_record(args: argparse.Namespace) -> int:
    from rig import outputs, scenario
    from rig.regression import baseline
    from rig.run.seeds import parse_seeds, run_over_seeds
    from rig.supervisor import Terminated, terminate_as_exception

    try:
        seeds = parse_seeds(args.seeds)
    except ValueError as exc:
        print(f"rig baseline record: --seeds: {exc}", file=sys.stderr)
        return 2
    if len(seeds) < baseline.MIN_SEEDS:
        print(f"rig baseline record: a baseline needs at least {baseline.MIN_SEEDS} seeds "
              f"(--seeds {args.seeds} gives {len(seeds)})", file=sys.stderr)
        return 2
    try:
        suite = scenario.load(args.suite)
    except (FileNotFoundError, scenario.ScenarioError) as exc:
        print(f"rig baseline record: {exc}", file=sys.stderr)
        return 2
    if not isinstance(suite, scenario.Suite):
        print(f"rig baseline record: {args.suite} is a scenario; a baseline belongs to a suite",
              file=sys.stderr)
        return 2
    target = args.to or baseline.path_of(suite.name)
    why = _not_a_baseline_file(target)
    if why:  # checked before anything runs: a user's file is never overwritten
        print(f"rig baseline record: --to {target}: {why}", file=sys.stderr)
        return 2
    if args.from_dir is not None:
        runs = read_seed_runs(suite, seeds, args.from_dir)
    else:
        root = args.out or outputs.default_out(f"baseline-{suite.name}")
        print(f"rig baseline record: {suite.name}, {len(suite.scenarios)} scenarios x "
              f"{len(seeds)} seeds in process, {args.jobs} at a time -> {root}",
              file=sys.stderr)
        try:
            with terminate_as_exception():
                runs = run_over_seeds(suite, seeds, root, args.jobs).runs
        except (KeyboardInterrupt, Terminated):
            print(f"rig baseline record: interrupted; nothing written (runs in {root})",
                  file=sys.stderr)
            return 130
    per_seed = {seed: [None if r is None else baseline.SeedResult(
        r.criteria, f"{r.failure.kind}: {r.failure.message}" if r.failure else "")
        for r in rs] for seed, rs in runs.items()}
    new, problems = baseline.build(suite.name, seeds, suite.scenarios, per_seed, source())
    problems += comparison_problems(suite, runs)
    if problems:
        print(f"rig baseline record: not written: {len(problems)} criteria cannot be a "
              "baseline:", file=sys.stderr)
        for p in problems:
            print(f"  {p}", file=sys.stderr)
        return 1
    old = None
    if target.is_file():
        try:
            old = baseline.Baseline.load(target)
        except baseline.BaselineError as exc:
            print(f"rig baseline record: replacing an unreadable baseline: {exc}",
                  file=sys.stderr)
    _check_other_files(new, target)
    target.parent.mkdir(parents=True, exist_ok=True)
    from rig import outputs

    outputs.write_text(target, new.dumps())
    n = sum(len(e.records) for e in new.entries.values())
    print(f"rig baseline record: {target}: {len(new.entries)} scenario runs, {n} criteria, "
          f"seeds {args.seeds}", file=sys.stderr)
    if old is not None:
        from rig.regression import compare

        table = compare.baselines(old, new)
        print(compare.summary_line(table, "against the replaced baseline"), file=sys.stderr)
        for line in compare.markdown(table, only_changed=True).splitlines():
            print(line)
    return 0


def comparison_problems(suite: Any, runs: dict[int, list[Any]]) -> list[str]:
    """The suite's comparisons at every seed: an outcome that depends on the seed, or that
    fails at every seed, cannot be accepted either."""
    from rig.run.suite import entry, evaluate_comparison

    outcomes: dict[str, dict[str, list[int]]] = {}
    for seed, rs in runs.items():
        entries = [entry(sc, r) for sc, r in zip(suite.scenarios, rs, strict=True)
                   if r is not None]
        for cmp in suite.comparisons:
            got = evaluate_comparison(cmp, entries)
            outcomes.setdefault(cmp.name, {}).setdefault(str(got["outcome"]), []).append(seed)
    problems = []
    for name, by in outcomes.items():
        if len(by) > 1:
            problems.append(f"comparison {name!r} depends on the seed: " + "; ".join(
                f"{o.upper()} at seeds {ss}" for o, ss in by.items()))
        elif set(by) & {"fail", "not_evaluated"}:
            problems.append(f"comparison {name!r} is {next(iter(by)).upper()} at every seed")
    return problems


def read_seed_runs(suite: Any, seeds: tuple[int, ...], root: Path) -> dict[int, list[Any]]:
    """The runs a ``rig baseline record --out ROOT`` left, per seed in the suite's order
    (None where a run has no result.json)."""
    from rig.results.result import RunResult
    from rig.run.seeds import seed_dir

    out: dict[int, list[Any]] = {}
    for seed in seeds:
        rows: list[Any] = []
        for sc in suite.scenarios:
            folder = seed_dir(root, seeds[0] if sc.seeds else seed) / sc.name
            try:
                r = RunResult.load(folder)
            except (OSError, ValueError):
                rows.append(None)
                continue
            r.criteria = rejudge(sc, r.criteria)
            rows.append(r)
        out[seed] = rows
    return out


def rejudge(sc: Any, criteria: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A recorded run's criteria judged again on the scenario as it is now: a value is kept
    where the criterion still asks for the same metric, window and parameters (its limit,
    comparison or xfail may have changed: the outcome follows); a criterion that asks for
    something else has no value here (the run must be made again: `record` without --from
    says so as a missing criterion)."""
    import math

    from rig.data import metrics
    from rig.results.verdict import NOT_EVALUATED, outcome_of

    by_name = {c.get("name"): c for c in criteria}
    out: list[dict[str, Any]] = []
    for cr in sc.criteria:
        c = by_name.get(cr.name)
        if c is None or c.get("metric") != cr.metric or dict(c.get("params") or {}) != dict(
                cr.params) or [float(x) for x in c.get("window") or []] != list(cr.window):
            continue
        c = dict(c, limit=cr.limit if math.isfinite(cr.limit) else None,
                 comparison=cr.comparison, xfail=cr.xfail, better=cr.side())
        if c.get("outcome") != NOT_EVALUATED:
            v = c.get("value")
            passed = metrics.compare(math.nan if v is None else float(v), cr.comparison,
                                     cr.limit)
            c.update(passed=passed, outcome=outcome_of(passed, cr.xfail))
        out.append(c)
    return out


def _not_a_baseline_file(target: Path) -> str:
    """Why ``target`` may not be written ('' when it may): only a new file, or a baseline
    file (one this command wrote: its schema says so) is replaced; never through a link."""
    from rig.regression import baseline

    if target.is_symlink():
        return "is a symbolic link (write the file itself)"
    if target.suffix != ".toml":
        return "a baseline is a .toml file"
    if not target.exists():
        return "" if target.parent.is_dir() or not target.parent.exists() else \
            f"{target.parent} is not a folder"
    if not target.is_file():
        return "is not a regular file"
    try:
        head = target.read_text(encoding="utf-8", errors="replace")[:4096]
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if not any(f'schema = "{s}"' in head for s in baseline.SCHEMAS):
        return "exists and is not a baseline file (refused: it may be yours)"
    return ""


def _check_other_files(new: Any, target: Path) -> None:
    """A scenario run belongs to one baseline file: say which other files also hold some of
    the runs just recorded (they must be recorded again or cleaned by hand)."""
    from rig.regression import baseline

    for path in baseline.files(target.parent):
        if path.resolve() == target.resolve():
            continue
        try:
            other = baseline.Baseline.load(path)
        except baseline.BaselineError:
            continue
        both = sorted(set(other.entries) & set(new.entries))
        if both:
            print(f"rig baseline record: warning: {path} also holds {len(both)} of these runs "
                  f"({', '.join(both[:3])}{', ...' if len(both) > 3 else ''}); a run "
                  "belongs to one baseline: remove them there", file=sys.stderr)


def cmd_show(args: argparse.Namespace) -> int:
    from rig.regression import baseline

    path = Path(args.suite)
    if not path.is_file():
        path = baseline.path_of(args.suite)
    try:
        b = baseline.Baseline.load(path)
    except baseline.BaselineError as exc:
        print(f"rig baseline show: {exc}", file=sys.stderr)
        return 2
    print(f"# {path}: suite {b.suite}, seeds {list(b.seeds)}, recorded {b.recorded}, "
          f"source {b.source}")
    print("| scenario | criterion | metric | value | band | sd | outcome |")
    print("|---|---|---|---|---|---|---|")
    for key in sorted(b.entries):
        for name, r in b.entries[key].records.items():
            v = "—" if r.band.value is None else f"{r.band.value:.4g}"
            print(f"| {key} | {name} | `{r.metric}` | {v} {r.unit} | "
                  f"{r.band.lo:.4g} .. {r.band.hi:.4g} | {r.band.sd:.2g} | {r.outcome} |")
    return 0
