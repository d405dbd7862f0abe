"""``rig bench``: benchmarks that print one JSON object each (``rig.benchmarks``).

The verb is ``bench`` for the users who know it; in the code a benchmark is a benchmark and a
bench is the test bench."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

from rig import cliargs
from rig.benchmarks import apart, bus, clock, cluster, gate, isr, overload, plant, sil, startup


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(sub, "bench", help="benchmarks (one JSON object on stdout)",
                     description="Benchmarks; each prints one JSON object.")
    bsub = p.add_subparsers(dest="bench_command", metavar="TARGET", required=True)
    b = bsub.add_parser("bus", help=bus.HELP, description=bus.__doc__)
    bus.add_arguments(b)
    cliargs.command(b, _printed(bus.measure))

    i = bsub.add_parser("isr", help=isr.HELP, description=isr.__doc__)
    isr.add_arguments(i)
    cliargs.command(i, _printed(isr.measure))

    raw = argparse.RawDescriptionHelpFormatter
    pl = bsub.add_parser(
        "plant", help="plant compute per period, lockstep periods/s, real-time jitter",
        description=plant.__doc__, formatter_class=raw)
    plant.add_arguments(pl)
    cliargs.command(pl, _plant)

    si = bsub.add_parser(
        "sil", help="closed loop in one process (--bus inproc) against the bus, same run",
        description=sil.__doc__, formatter_class=raw)
    sil.add_arguments(si)
    cliargs.command(si, _printed(sil.measure))

    su = bsub.add_parser(
        "startup", help="CPU and wall time of a scenario's start in a new process",
        description=startup.__doc__, formatter_class=raw)
    startup.add_arguments(su)
    cliargs.command(su, _printed(startup.measure))

    ov = bsub.add_parser(
        "overload", help="a suite on the fallback bus with every core saturated, against it "
        "in process: identical values, no lockstep drop (stall and drop figures)",
        description=overload.__doc__, formatter_class=raw)
    overload.add_arguments(ov)
    cliargs.command(ov, _printed(overload.measure))

    ap = bsub.add_parser(
        "apart", help="two suites and a commissioning session started together with no "
        "channel named: each its own channel, all green, values as in process",
        description=apart.__doc__, formatter_class=raw)
    apart.add_arguments(ap)
    cliargs.command(ap, _printed(apart.measure))

    ga = bsub.add_parser(
        "gate", help="the regression gate's wall and CPU time (target: 30 s on 2 cores)",
        description=gate.__doc__, formatter_class=raw)
    gate.add_arguments(ga)
    cliargs.command(ga, _printed(gate.measure))

    ck = bsub.add_parser("clock", help=clock.HELP, description=clock.__doc__,
                         formatter_class=raw)
    clock.add_arguments(ck)
    cliargs.command(ck, _printed(clock.measure))

    cl = bsub.add_parser(
        "cluster", help="a suite on 1, 2 and 4 local Dask workers: the speed-up",
        description=cluster.__doc__, formatter_class=raw)
    cluster.add_arguments(cl)
    cliargs.command(cl, _printed(cluster.measure))


def _printed(measure: Callable[[argparse.Namespace], dict[str, Any]]
             ) -> Callable[[argparse.Namespace], int]:
    """A benchmark as a command: its JSON object on stdout."""
    def command(args: argparse.Namespace) -> int:
        print(json.dumps(measure(args)))
        return 0
    return command


def _plant(args: argparse.Namespace) -> int:
    plant.measure(args)  # prints its JSON object
    return 0
