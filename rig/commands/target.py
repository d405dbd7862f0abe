"""``rig target``: the control core's Cortex-M4F build under emulation (``rig.target_m4``)."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_USAGE
from rig.target_m4 import scenarios


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(sub, "target", help="the control core on an emulated Cortex-M4F",
                     description="The control core built for a Cortex-M4F "
                     "(firmware_c2000/target_m4) under emulation.")
    tsub = p.add_subparsers(dest="target_command", metavar="COMMAND", required=True)
    c = tsub.add_parser(
        "compare", help="replay closed-loop runs on the target, compare every period",
        description="Runs each scenario in process with every call into the host's control "
        "core journalled (ADC data, commands, limits, parameters) and replays the journal on "
        "the Cortex-M4F image: every period's PWM compares, SOC plan and gate enable, every "
        "command's status and a CRC of the whole core state are compared with the host's. "
        "One JSON object per scenario; exit 0 when all are identical, 1 otherwise, 2 for a "
        "name that is not a scenario or an --out that is not a new, empty or earlier "
        "--out folder of this command, 3 when the runs cannot be written. Default "
        "scenarios: " + ", ".join(f"{k.scenario} ({k.what})" for k in scenarios.CASES) + ".")
    c.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                   help="scenario names (default: the cases above)")
    c.add_argument("--short", action="store_true",
                   help="only the start and the cases' windows (as the CI test), not the "
                   "whole runs")
    c.add_argument("--out", type=Path, default=None,
                   help="keep the runs and journals here (default: a temporary folder)")
    c.set_defaults(func=_compare)


MARK = ".hil-target-compare"  # in an --out folder this command made: the only kind it reuses


def out_problem(out: Path) -> str | None:
    """Why ``--out`` cannot take the runs (None when it can): it must be a new or empty
    folder, or one this command made (its marker inside); never a file or a user's folder."""
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        return f"{out} is not a folder"
    if out.is_dir():
        entries = sorted(p.name for p in out.iterdir())
        if entries and MARK not in entries:
            shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
            return (f"{out} holds files of its own ({shown}) and was not made by rig target "
                    "compare; give a new or empty folder")
    return None


def _cases(names: list[str]) -> list[tuple[scenarios.Case, str]] | str:
    """Each name's case and the folder its run goes to, or why a name is not a scenario."""
    from rig import scenario

    found: list[tuple[scenarios.Case, str]] = []
    for name in names:
        try:
            target = scenario.load(name)
        except FileNotFoundError as exc:
            return str(exc)
        except scenario.ScenarioError as exc:
            return f"invalid scenario:\n{exc}"
        if isinstance(target, scenario.Suite):
            return (f"{name} is a suite; name its scenarios (rig list) or none for the "
                    "default cases")
        found.append((scenarios.case(name), target.name))
    return found


def _compare(args: argparse.Namespace) -> int:
    from rig.target_m4 import run

    cases = _cases(args.scenarios or [k.scenario for k in scenarios.CASES])
    if isinstance(cases, str):
        print(f"rig target compare: {cases}", file=sys.stderr)
        return EXIT_USAGE
    if args.out is not None:
        problem = out_problem(args.out)
        if problem is not None:
            print(f"rig target compare: --out: {problem}", file=sys.stderr)
            return EXIT_USAGE
    all_same = True
    with tempfile.TemporaryDirectory() as tmp:
        base = args.out or Path(tmp)
        try:
            base.mkdir(parents=True, exist_ok=True)
            (base / MARK).touch()
            for case, folder in cases:
                comp = run.compare_case(case, base / folder, full=not args.short)
                all_same &= comp.identical
                print(json.dumps(comp.summary()), flush=True)
        except OSError as exc:  # (outputs.OutputError too: a folder the run refused)
            print(f"rig target compare: {exc}", file=sys.stderr)
            return EXIT_ENV
        except RuntimeError as exc:  # the run did not get to a comparison
            print(f"rig target compare: {exc}", file=sys.stderr)
            return 1
    if not all_same:
        print("rig target compare: the target's outputs differ from the host's",
              file=sys.stderr)
    return 0 if all_same else 1
