"""``rig param``: drive parameters over CAN (PARAM_REQ / PARAM_RESP)."""

from __future__ import annotations

import argparse
import sys

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_OK, EXIT_USAGE


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "param", help="read, write, list, save and load drive parameters over CAN",
        description="Drive parameters (protocols/parameters.csv) through PARAM_REQ / "
        "PARAM_RESP: every request has a sequence number and a time-out; a write is "
        "range-checked here and by the drive and then read back.",
        epilog="exit status: 0 done; 1 refused or not read back; 2 usage; 3 no answer or no "
        "bus.")
    _link_options(p)
    ps = p.add_subparsers(dest="param_command", metavar="ACTION", required=True)
    g = ps.add_parser("get", help="read one parameter")
    g.add_argument("name", metavar="NAME|ID")
    s = ps.add_parser("set", help="write one parameter (range-checked, read back)")
    s.add_argument("name", metavar="NAME|ID")
    s.add_argument("value", type=cliargs.number())
    actions = [g, s, ps.add_parser("list", help="every parameter with its value, unit and range"),
               ps.add_parser("save", help="drive: write the parameters to its store"),
               ps.add_parser("load", help="drive: re-read its store")]
    for action in actions:  # the link's options also after the action: rig param list --bus X
        _link_options(action)
        cliargs.command(action, cmd_param)


def _link_options(p: argparse.ArgumentParser) -> None:
    cliargs.add_shared(p, "bench", help="take the bus from a bench description")
    cliargs.add_shared(p, "bus", choices=cliargs.BUS_TRANSPORTS,
                       help="transport (default: the bench's, else $HIL_BUS, else auto)")
    cliargs.add_shared(p, "channel", env="HIL_CHANNEL",
                       help="bus channel (default: the bench's, else $HIL_CHANNEL, else vcan0)")
    cliargs.add_shared(p, "timeout", default=1.0, help="time-out per request, s (default 1)")


def cmd_param(args: argparse.Namespace) -> int:
    from rig.bench import description
    from rig.drive.params import ParamClient, ParamError, ParamTimeout
    from rig.link.bus import BusLink, LinkError

    bus, channel = args.bus, args.channel
    if args.bench:
        try:
            desc = description.load(args.bench)
        except description.BenchDescriptionError as exc:
            print(f"rig param: {exc}", file=sys.stderr)
            return EXIT_USAGE
        bus, channel = bus or desc.can.transport, channel or desc.can.channel
    try:
        link = BusLink.open(bus, channel)
    except (LinkError, ValueError) as exc:
        print(f"rig param: {exc}", file=sys.stderr)
        return EXIT_ENV
    client = ParamClient(link, timeout_s=args.timeout)
    try:
        act = args.param_command
        if act == "get":
            info = client.t.lookup(args.name)
            print(f"{info.name} = {client.get(info.id):.9g} {info.unit}")
        elif act == "set":
            info = client.t.lookup(args.name)
            print(f"{info.name} = {client.set(info.id, args.value):.9g} {info.unit} "
                  "(read back)")
        elif act == "list":
            for info, value in client.list():
                print(f"{info.id:4d} {info.name:22s} {value:14.9g} {info.unit:10s} "
                      f"[{info.minimum:g}, {info.maximum:g}] {info.access}")
        elif act == "save":
            client.save()
            print("saved")
        else:
            client.load()
            print("loaded")
        return EXIT_OK
    except ParamTimeout as exc:
        print(f"rig param: {exc}", file=sys.stderr)
        return EXIT_ENV
    except ParamError as exc:
        print(f"rig param: {exc}", file=sys.stderr)
        return EXIT_FAIL
    finally:
        link.close()
