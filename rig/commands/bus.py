"""``rig bus``: create and inspect the CAN bus."""

from __future__ import annotations

import argparse
import json
import sys

from rig import bus as rigbus
from rig.bus import unixcan


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("bus", help="create and inspect the CAN bus",
                       description="Create and inspect the CAN bus (SocketCAN or unixcan).")
    bsub = p.add_subparsers(dest="bus_command", metavar="ACTION", required=True)

    up = bsub.add_parser("up", help="create a CAN FD vcan interface (root) or a unixcan channel",
                         description="Create CHANNEL: a vcan interface with CAN FD MTU when the "
                         "kernel has CAN and you are root, else a unixcan channel folder.")
    up.add_argument("channel", nargs="?", default=rigbus.DEFAULT_CHANNEL)
    up.add_argument("--bus", choices=rigbus.TRANSPORTS, default=None,
                    help="transport (default: HIL_BUS or auto)")
    up.set_defaults(func=_up)

    st = bsub.add_parser("status", help="which transport the rig would use, as JSON",
                         description="Print the transport selection and what the kernel offers.")
    st.add_argument("channel", nargs="?", default=None)
    st.add_argument("--bus", choices=rigbus.TRANSPORTS, default=None)
    st.set_defaults(func=_status)


def _up(args: argparse.Namespace) -> int:
    transport = args.bus or "auto"
    if transport in ("auto", "socketcan") and rigbus.kernel_has_can():
        try:
            rigbus.vcan_up(args.channel)
        except RuntimeError as exc:
            if transport == "socketcan":
                print(f"rig bus up: {exc}", file=sys.stderr)
                return 1
        else:
            print(f"socketcan {args.channel} up (CAN FD MTU 72)")
            return 0
    elif transport == "socketcan":
        print("rig bus up: this kernel has no CAN support; use --bus unixcan or `rig vm`",
              file=sys.stderr)
        return 1
    try:
        folder = unixcan.channel_dir(args.channel)
    except OSError as exc:
        print(f"rig bus up: {exc}", file=sys.stderr)
        return 3
    print(f"unixcan {args.channel} ready ({folder})")
    return 0


def _status(args: argparse.Namespace) -> int:
    transport, channel = rigbus.select_transport(args.bus, args.channel)
    print(json.dumps({
        "selected": transport,
        "channel": channel,
        "kernel_has_can": rigbus.kernel_has_can(),
        "interface_exists": rigbus.interface_exists(channel),
        "unixcan_dir": str(unixcan.base_dir()),
    }))
    return 0
