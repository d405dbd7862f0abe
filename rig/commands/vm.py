"""``rig vm -- COMMAND``: run a command in a VM whose kernel has SocketCAN (vcan0 up)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig import cliargs
from rig.bus import vm


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "vm", help="run a command inside a virtme-ng VM with vcan0 up",
        description="Boot Debian's stock kernel with virtme-ng (TCG unless --kvm), bring up "
        "vcan interfaces with CAN FD MTU, run COMMAND in the current folder (mounted "
        "writable) and return its exit code. Example: rig vm -- pytest -m vcan",
    )
    p.add_argument("--memory", default="2G", help="guest memory (default 2G)")
    p.add_argument("--cpus", type=cliargs.number(int, minimum=1), default=2,
                   help="guest CPUs (default 2)")
    p.add_argument("--kvm", action="store_true", help="use KVM (hangs on some hosts)")
    p.add_argument("--kernel", type=Path, default=None,
                   help="kernel image (default: newest /boot/vmlinuz-*)")
    p.add_argument("--channel", action="append", default=None, type=cliargs.channel,
                   metavar="NAME",
                   help="vcan interface to create (repeatable; default vcan0)")
    p.add_argument("--rwdir", action="append", type=Path, default=None,
                   help="folder mounted writable (repeatable; default: the current folder)")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND [ARGS...]")
    cliargs.command(p, _run)


def _run(args: argparse.Namespace) -> int:
    command = list(args.command)
    if command and command[0] == "--":
        command = command[1:]
    if not command:
        print("rig vm: nothing to run; usage: rig vm -- COMMAND [ARGS...]", file=sys.stderr)
        return 2
    try:
        return vm.run_in_vm(command, rwdirs=args.rwdir, channels=args.channel,
                            memory=args.memory, cpus=args.cpus, kvm=args.kvm, kernel=args.kernel)
    except FileNotFoundError as exc:
        print(f"rig vm: {exc}", file=sys.stderr)
        return 2
