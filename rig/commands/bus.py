"""``rig bus``: create and inspect the CAN bus."""

from __future__ import annotations

import argparse
import json
import sys

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(sub, "bus", help="create and inspect the CAN bus",
                     description="Create and inspect the CAN bus (SocketCAN or unixcan).")
    bsub = p.add_subparsers(dest="bus_command", metavar="ACTION", required=True)

    up = bsub.add_parser("up", help="create a CAN FD vcan interface (root) or a unixcan channel",
                         description="Create the channel: a vcan interface with CAN FD MTU when "
                         "the kernel has CAN and you are root, else a unixcan channel folder.")
    _channel_options(up, "the channel to create (default: $HIL_CHANNEL, else vcan0)")
    cliargs.command(up, _up)

    st = bsub.add_parser("status", help="which transport the rig would use, as JSON",
                         description="Print the transport selection and what the kernel offers.")
    _channel_options(st, "the channel to look at (default: $HIL_CHANNEL, else vcan0)")
    cliargs.command(st, _status)

    ld = bsub.add_parser("load", help="the drive protocol's bus load, from its DBC",
                         description="Each cyclic message of protocols/drive.dbc: its frame in "
                         "bits with worst-case stuffing (classic CAN) times its rate "
                         "(GenMsgCycleTime), over the bit rate (the Baudrate attribute), and "
                         "each cyclic message's worst-case latency (fixed-priority "
                         "non-preemptive arbitration, Davis et al. 2007); exit 1 when the "
                         "total passes the 60 % the telemetry is held to, or a message's "
                         "worst-case latency passes its period.")
    cliargs.command(ld, _load)

    ar = bsub.add_parser(
        "arbiter", help="give a fallback-bus channel a bit clock (classic CAN's timing)",
        description="Holds the channel's classic CAN frames to their bit times at BITRATE, "
        "one at a time, the lowest identifier first, as on the lab's bus (rig.bus.arbiter); "
        "CAN FD frames (the virtual wires) pass as before. For a free-running bench (rig up "
        "--bitrate starts one), never a lockstep run. Prints the bus's figures every 5 s and "
        "when stopped (Ctrl-C, SIGTERM, --for).",
        epilog="exit status: 0 stopped; 2 usage; 3 the channel has a bit clock already or its "
        "folder cannot be used.")
    cliargs.add_shared(ar, "channel", env="HIL_CHANNEL",
                       help="the unixcan channel (default: $HIL_CHANNEL, else vcan0)")
    ar.add_argument("--bitrate", type=cliargs.number(int, minimum=1), default=None,
                    metavar="BIT/S", help="default: the drive protocol's (protocols/drive.dbc "
                    "Baudrate: 1000000)")
    ar.add_argument("--for", dest="for_s", type=cliargs.number(float, minimum=0.0),
                    default=None, metavar="S", help="stop by itself after S seconds")
    cliargs.command(ar, _arbiter)


def _channel_options(p: argparse.ArgumentParser, what: str) -> None:
    cliargs.add_shared(p, "channel", env="HIL_CHANNEL", help=what)
    p.add_argument("channel_arg", nargs="?", type=cliargs.channel, default=None,
                   metavar="CHANNEL", help="the same as --channel (older spelling)")
    cliargs.add_shared(p, "bus", choices=cliargs.BUS_TRANSPORTS,
                       help="transport (default: $HIL_BUS, else auto)")


def _channel(args: argparse.Namespace) -> str | None:
    if args.channel_arg and args.channel and args.channel_arg != args.channel:
        print(f"rig bus: error: two channels: {args.channel_arg} and --channel "
              f"{args.channel}", file=sys.stderr)
        raise SystemExit(2)
    return args.channel_arg or args.channel


def _up(args: argparse.Namespace) -> int:
    from rig import bus as rigbus
    from rig.bus import unixcan

    transport = args.bus or "auto"
    channel = _channel(args) or rigbus.select_transport(transport, None)[1]
    if transport in ("auto", "socketcan") and rigbus.kernel_has_can():
        try:
            rigbus.vcan_up(channel)
        except RuntimeError as exc:
            if transport == "socketcan":
                print(f"rig bus up: {exc}", file=sys.stderr)
                return EXIT_FAIL
        else:
            print(f"socketcan {channel} up (CAN FD MTU 72)")
            return EXIT_OK
    elif transport == "socketcan":
        print("rig bus up: this kernel has no CAN support; use --bus unixcan or `rig vm`",
              file=sys.stderr)
        return EXIT_FAIL
    try:
        folder = unixcan.channel_dir(channel)
    except OSError as exc:
        print(f"rig bus up: {exc}", file=sys.stderr)
        return EXIT_ENV
    print(f"unixcan {channel} ready ({folder})")
    return EXIT_OK


def _load(args: argparse.Namespace) -> int:
    from rig.bus import latency, load

    print(load.table("drive"))
    loads, rate = load.message_loads("drive"), load.bitrate("drive")
    total = load.total_pct(loads, rate)
    status = EXIT_OK
    if total > load.TELEMETRY_LIMIT_PCT:
        print(f"rig bus load: {total:.1f} % is above {load.TELEMETRY_LIMIT_PCT:g} %",
              file=sys.stderr)
        status = EXIT_FAIL
    for x in latency.worst_case_latencies(loads, rate):
        if not x.meets_period:
            worst = "unbounded" if x.worst_s is None else f"{x.worst_s * 1e6:.0f} µs"
            print(f"rig bus load: {x.name}'s worst-case latency ({worst}) is beyond its "
                  f"period ({x.period_s * 1e6:.0f} µs)", file=sys.stderr)
            status = EXIT_FAIL
    return status


def _arbiter(args: argparse.Namespace) -> int:
    import threading
    import time

    from rig.bus import arbiter, load
    from rig.supervisor import Terminated, terminate_as_exception

    channel = args.channel or "vcan0"
    rate = args.bitrate or load.bitrate("drive")
    try:
        clock = arbiter.Arbiter(channel, rate)
    except arbiter.ArbiterError as exc:
        print(f"rig bus arbiter: {exc}", file=sys.stderr)
        return EXIT_ENV
    stop = threading.Event()
    runner = threading.Thread(target=clock.run, args=(stop,), name="arbiter", daemon=True)
    print(f"rig bus arbiter: unixcan channel {channel} at {rate} bit/s", flush=True)
    runner.start()
    try:
        with terminate_as_exception():
            t_end = None if args.for_s is None else time.monotonic() + args.for_s
            while t_end is None or time.monotonic() < t_end:
                time.sleep(5.0 if t_end is None else min(5.0, max(0.0, t_end - time.monotonic())))
                print(f"rig bus arbiter: {clock.stats.line(time.monotonic() - clock.t0)}",
                      flush=True)
    except (KeyboardInterrupt, Terminated):
        pass
    finally:
        stop.set()
        runner.join(timeout=5.0)
        clock.close()
    print(f"rig bus arbiter: stopped: {clock.stats.line(time.monotonic() - clock.t0)}",
          flush=True)
    return EXIT_OK


def _status(args: argparse.Namespace) -> int:
    from rig import bus as rigbus
    from rig.bus import unixcan

    transport, channel = rigbus.select_transport(args.bus, _channel(args))
    print(json.dumps({
        "selected": transport,
        "channel": channel,
        "kernel_has_can": rigbus.kernel_has_can(),
        "interface_exists": rigbus.interface_exists(channel),
        "unixcan_dir": str(unixcan.base_dir()),
    }))
    return EXIT_OK
