"""``rig up``: the virtual bench, free-running on the wall clock, until Ctrl-C or SIGTERM.

Named for what it does to the bench (brings it up), so that "bench" keeps its one meaning:
``--bench`` names the bench under test, ``rig bench`` measures costs."""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import sys
import time
from pathlib import Path

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_OK, EXIT_USAGE

EPILOG = """\
What it starts: plant_rt and fw_host in real time (--realtime: SCHED_FIFO and mlockall where
the kernel allows; it says what each was granted) and the Modbus load bench, on a fallback-bus
channel of its own (up-<pid>) unless one is named. It prints the bus and channel, the
console's pty, the Modbus address and a bench file for --bench, then a health line every few
seconds. Ctrl-C or SIGTERM stops it: programs, channel, pty and files go with it.
--pace wall runs them in lockstep instead, at SCHED_FIFO 10, granted bench time as the wall
clock passes: for a machine that does not hold 10 kHz real time (README: Pointing it at a
real bench).

Try it (in another shell, with the same UNIXCAN_DIR):
  rig console --bench FILE -c version        # or interactive: rig console --bench FILE
  rig param list --bench FILE
  rig drive --bench FILE --speed 1000 --load 1.0 --for 10
  rig watch --bench FILE                     # a live view; Ctrl-C detaches
  rig commission all --bench FILE

exit status: 0 stopped (Ctrl-C, SIGTERM, --for); 1 a program of the bench died; 2 usage;
3 the bench could not come up (channel in use or not quiet, a program not ready).
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "up", help="bring the virtual bench up, free-running, until Ctrl-C",
        description="The virtual bench (plant_rt, fw_host, Modbus load bench) free-running on "
        "the wall clock, as a real bench is: every real-bench command reaches it with "
        "--bench FILE.", epilog=EPILOG)
    cliargs.add_shared(p, "bench", default="virtual",
                       help="the virtual bench's description (default: virtual)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a field of the description (repeatable), e.g. "
                   "virtual.profile=harsh, can.channel=NAME, modbus.port=5020")
    cliargs.add_shared(p, "channel",
                       help="bus channel (default: one of its own on the fallback bus)")
    p.add_argument("--bench-file", type=Path, default=None, metavar="FILE",
                   help="also write the bench file here (refused if FILE exists; removed "
                   "when the bench stops)")
    p.add_argument("--health-every", type=cliargs.number(float, minimum=0.2), default=5.0,
                   metavar="S", help="a health line every S seconds (default 5)")
    p.add_argument("--for", dest="for_s", type=cliargs.number(float, minimum=0.0),
                   default=None, metavar="S", help="stop by itself after S seconds")
    p.add_argument("--pace", choices=("realtime", "wall"), default="realtime",
                   help="realtime (default): plant_rt and fw_host in their real-time mode; "
                   "wall: in lockstep, granted bench time as the wall clock passes (for a "
                   "machine that cannot hold 10 kHz real time: nothing is lost, the bench "
                   "time pauses when the machine falls behind)")
    p.add_argument("--bitrate", type=cliargs.number(int, minimum=1), default=None,
                   metavar="BIT/S", help="give the bench's fallback-bus channel the lab's bit "
                   "timing (rig bus arbiter): classic CAN frames one at a time for their bits, "
                   "the lowest id first; the virtual wires (CAN FD) as before. E.g. 1000000, "
                   "the drive's; lower to see an overloaded bus")
    p.add_argument("--rt-priority", type=cliargs.number(int, minimum=0, maximum=99),
                   default=None, metavar="N",
                   help="SCHED_FIFO priority: in real time of plant_rt and fw_host (default: "
                   "theirs, 80), paced by the wall clock of every process of the bench "
                   "(default 10: clients on a loaded machine run above it); 0: none")
    cliargs.command(p, cmd_up)


def _say(msg: str) -> None:
    print(msg, flush=True)


def cmd_up(args: argparse.Namespace) -> int:
    from rig.bench import description, live
    from rig.supervisor import ChildFailed, Terminated, terminate_as_exception

    sets = list(args.set) + ([f"can.channel={args.channel}"] if args.channel else [])
    try:
        desc = description.load(args.bench, sets)
        if desc.virtual is None:
            raise description.BenchDescriptionError(
                f"{args.bench}: not a virtual bench (no [virtual] section): rig up brings up "
                "the emulated bench only")
    except description.BenchDescriptionError as exc:
        print(f"rig up: {exc}", file=sys.stderr)
        return EXIT_USAGE
    copy: Path | None = args.bench_file
    if copy is not None and (copy.exists() or copy.is_symlink()):
        print(f"rig up: --bench-file {copy} exists; refused (name a new file)", file=sys.stderr)
        return EXIT_USAGE
    bench = live.LiveBench(desc, rt_priority=args.rt_priority, pace=args.pace,
                           bitrate=args.bitrate)
    status = EXIT_OK
    wrote_copy = False
    with terminate_as_exception():
        try:
            addr = bench.start()
            if copy is not None:
                from rig import outputs
                outputs.write_text(copy, addr.bench_file.read_text())
                wrote_copy = True
            _print_address(desc, addr, copy, bench)
            end = None if args.for_s is None else time.monotonic() + args.for_s
            while end is None or time.monotonic() < end:
                step = args.health_every if end is None else min(
                    args.health_every, max(0.0, end - time.monotonic()))
                bench.watch(step)
                _say(bench.health().line())
        except live.BenchRefused as exc:
            print(f"rig up: {exc}", file=sys.stderr)
            status = EXIT_ENV
        except ChildFailed as exc:
            started = bench.address is not None
            print(f"rig up: {exc}", file=sys.stderr)
            status = EXIT_FAIL if started else EXIT_ENV
        except (KeyboardInterrupt, Terminated):
            print("rig up: stopping", file=sys.stderr, flush=True)
        finally:
            with contextlib.suppress(KeyboardInterrupt, Terminated):
                reports = bench.stop()
                if wrote_copy and copy is not None:
                    copy.unlink(missing_ok=True)
                _print_exit(reports, bench)
    return status


def _print_address(desc, addr, copy: Path | None, bench) -> None:  # type: ignore[no-untyped-def]
    from rig.bench import live

    file = copy if copy is not None else addr.bench_file
    where = (f" (UNIXCAN_DIR={os.environ['UNIXCAN_DIR']})"
             if addr.transport == "unixcan" and os.environ.get("UNIXCAN_DIR") else "")
    rt = ", ".join(f"{n} {s}" for n, s in bench.scheduling().items())
    if bench.pace == "wall":
        rt = (f"paced by the wall clock (lockstep, {live.GRANT_S * 1e3:g} ms grants; "
              f"{rt})")
    profile = desc.virtual.profile if desc.virtual else "?"
    f = shlex.quote(str(file))
    _say(f"rig up: the virtual bench ({profile} profile) is up, free-running; Ctrl-C stops it")
    _say(f"  bus        {addr.transport} channel {addr.channel}{where}")
    _say(f"  console    {addr.console}")
    _say(f"  modbus     tcp {addr.modbus_host}:{addr.modbus_port} unit {desc.modbus.unit}")
    _say(f"  bench file {file}")
    _say(f"  real time  {rt}")
    if bench.bitrate is not None:
        _say(f"  bit clock  {bench.bitrate} bit/s: classic frames one at a time for their "
             "bits, the lowest id first (rig bus arbiter)")
    if bench.pace == "realtime" and "SCHED_FIFO" not in rt:
        _say("             (SCHED_FIFO not granted: periods may slip on a loaded machine; "
             "run as root or give the user an rtprio limit, `ulimit -r`)")
    _say(f"  try        rig console --bench {f} -c version")
    _say(f"             rig param list --bench {f}")
    _say(f"             rig drive --bench {f} --speed 1000 --load 1.0 --for 10")
    _say(f"             rig watch --bench {f}      (a live view; Ctrl-C detaches)")
    _say(f"             rig commission all --bench {f}")
    if addr.transport == "unixcan":
        _say(f"             python -m can.logger -i unixcan -c {addr.channel} --fd")
    else:
        _say(f"             python -m can.logger -i socketcan -c {addr.channel} --fd")


def _print_exit(reports, bench) -> None:  # type: ignore[no-untyped-def]
    if bench.clock is not None:
        _say(f"rig up: paced by the wall clock: {bench.slipped_wall} periods slipped, bench "
             f"at period {bench.clock.period}")
    for name, rep in reports.items():
        c = rep.counters or {}
        bits = [f"exit {rep.returncode}"]
        for key in ("periods", "isr_calls", "slipped_periods", "overruns", "late_cmds", "rt"):
            if key in c:
                bits.append(f"{key} {c[key]}")
        _say(f"rig up: {name}: {', '.join(bits)}")
    if bench.bit_clock_summary:
        _say(f"rig up: {bench.bit_clock_summary.removeprefix('rig bus ')}")
    _say("rig up: stopped; channel released, files removed")
