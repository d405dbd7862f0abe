"""``rig loadbench``: the virtual load bench's Modbus server, and a look at any load bench."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_OK, EXIT_USAGE


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "loadbench",
        help="virtual load bench (Modbus TCP server) and a Modbus look at a bench",
        description="The load machine and torque sensor over Modbus "
        "(protocols/modbus_load_bench.json).")
    ls = p.add_subparsers(dest="loadbench_command", metavar="ACTION", required=True)
    s = ls.add_parser(
        "serve", help="serve the virtual load bench: setpoints -> LOAD_CMD, BENCH_TRUTH -> "
        "measurements",
        description="Modbus TCP server of the virtual bench: holding registers become "
        "LOAD_CMD frames on the bus, BENCH_TRUTH (speed, shaft torque) becomes input "
        "registers; watchdog, exception codes and scaling as the register map says. Runs "
        "until SIGTERM / Ctrl-C and leaves the load machine off.")
    cliargs.add_shared(s, "bus", choices=cliargs.BUS_TRANSPORTS,
                       help="transport (default: $HIL_BUS, else auto)")
    cliargs.add_shared(s, "channel", env="HIL_CHANNEL",
                       help="bus channel (default: $HIL_CHANNEL, else vcan0)")
    s.add_argument("--host", default="127.0.0.1",
                   help="address to bind (127.0.0.1 only: the virtual bench is local)")
    s.add_argument("--port", type=cliargs.number(int, minimum=0, maximum=65535), default=5020,
                   help="TCP port (0: any free one)")
    s.add_argument("--watchdog-ms", type=cliargs.number(int, minimum=0), default=None,
                   help="initial watchdog time-out (default: the map's)")
    s.add_argument("--ready-file", type=Path, default=None,
                   help="written (JSON: host, port, pid) once the server listens")
    cliargs.command(s, cmd_serve)
    r = ls.add_parser("read", help="print every holding and input register of a load bench")
    cliargs.add_shared(r, "bench", required=True, help="bench description")
    r.add_argument("--port", type=cliargs.port, default=None,
                   help="override the bench's TCP port")
    cliargs.command(r, cmd_read)


def cmd_serve(args: argparse.Namespace) -> int:
    from rig.loadbench.server import ServeOptions, serve

    if args.host != "127.0.0.1":
        print("rig loadbench serve: the virtual load bench binds 127.0.0.1 only",
              file=sys.stderr)
        return EXIT_USAGE
    try:
        return serve(ServeOptions(host=args.host, port=args.port, bus=args.bus,
                                  channel=args.channel, ready_file=args.ready_file,
                                  watchdog_timeout_ms=args.watchdog_ms))
    except (OSError, ValueError) as exc:
        print(f"rig loadbench serve: {exc}", file=sys.stderr)
        return EXIT_FAIL


def cmd_read(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from rig.bench import description
    from rig.loadbench.client import LoadBench, LoadBenchError

    try:
        desc = description.load(args.bench)
    except description.BenchDescriptionError as exc:
        print(f"rig loadbench read: {exc}", file=sys.stderr)
        return EXIT_USAGE
    spec = desc.modbus if args.port is None else replace(desc.modbus, port=args.port)
    try:
        with LoadBench(spec) as lb:
            out = {"endpoint": lb.endpoint, "holding": lb.read_table("holding"),
                   "input": lb.read_table("input")}
    except LoadBenchError as exc:
        print(f"rig loadbench read: {exc}", file=sys.stderr)
        return EXIT_ENV
    print(json.dumps(out, indent=1))
    return EXIT_OK
