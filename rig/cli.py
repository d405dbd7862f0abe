"""The ``rig`` command line: one sub-command module per job, each with ``register()``."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from rig import __version__
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
    *(f"rig.commands.{m}" for m in ("console", "param", "loadbench", "commission")),
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rig",
        description="HIL regression rig for a current-slope sensorless IPMSM drive.",
    )
    parser.add_argument("--version", action="version", version=f"rig {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    interruptible()
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
