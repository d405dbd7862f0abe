"""The ``rig`` command line: one sub-command module per job, each with ``register()``;
``rig.cliargs`` reads the arguments the same way for all of them."""

from __future__ import annotations

import importlib
import os
import signal
import sys
from collections.abc import Sequence

from rig import __version__, cliargs
from rig.supervisor import interruptible

COMMAND_MODULES = (
    "rig.commands.run",
    "rig.commands.baseline",
    "rig.commands.compare",
    "rig.commands.mutate",
    "rig.commands.sweep",
    "rig.commands.bus",
    "rig.commands.bench",
    "rig.commands.target",
    "rig.commands.vm",
    "rig.commands.clean",
    "rig.commands.export",
    *(f"rig.commands.{m}" for m in ("console", "param", "loadbench", "commission", "up", "drive",
                                       "watch")),
)


def build_parser() -> cliargs.Parser:
    parser = cliargs.Parser(
        prog="rig",
        description="HIL regression rig for a current-slope sensorless IPMSM drive.",
    )
    parser.add_argument("--version", action="version", version=f"rig {__version__}")
    cliargs.add_top_level(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = cliargs.finish(parser.parse_args(argv))
    except SystemExit as exc:  # --help, --version, a usage error (2): a status, not a raise
        return exc.code if isinstance(exc.code, int) else 2
    interruptible()
    try:
        status = int(args.func(args) or 0)
        if argv is None:  # the process's own command: its status is decided, exit with it
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                signal.signal(sig, signal.SIG_IGN)
        return status
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader went away (`rig list | head`): what it wanted it has; the rest of the
        # output goes nowhere, and Python's flush at exit must not complain either
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
