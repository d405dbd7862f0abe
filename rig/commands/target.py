"""``rig target``: the control core's Cortex-M4F build under emulation (``rig.target_m4``)."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from rig import cliargs
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
        "One JSON object per scenario; exit 0 when all are identical, 1 otherwise. Default "
        "scenarios: " + ", ".join(f"{k.scenario} ({k.what})" for k in scenarios.CASES) + ".")
    c.add_argument("scenarios", nargs="*", metavar="SCENARIO",
                   help="scenario names (default: the cases above)")
    c.add_argument("--short", action="store_true",
                   help="only the start and the cases' windows (as the CI test), not the "
                   "whole runs")
    c.add_argument("--out", type=Path, default=None,
                   help="keep the runs and journals here (default: a temporary folder)")
    c.set_defaults(func=_compare)


def _compare(args: argparse.Namespace) -> int:
    from rig.target_m4 import run

    names = args.scenarios or [k.scenario for k in scenarios.CASES]
    all_same = True
    with tempfile.TemporaryDirectory() as tmp:
        base = args.out or Path(tmp)
        for name in names:
            case = scenarios.case(name)
            comp = run.compare_case(case, base / name, full=not args.short)
            all_same &= comp.identical
            print(json.dumps(comp.summary()), flush=True)
    if not all_same:
        print("rig target compare: the target's outputs differ from the host's",
              file=sys.stderr)
    return 0 if all_same else 1
