"""``rig bench``: benchmarks that print one JSON object each."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rig import _paths, bench_gate, bench_plant, bench_sil, bench_startup, cliargs
from rig import bus as rigbus


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("bench", help="benchmarks (one JSON object on stdout)",
                       description="Benchmarks; each prints one JSON object.")
    bsub = p.add_subparsers(dest="bench_command", metavar="TARGET", required=True)
    b = bsub.add_parser(
        "bus", help="C-to-C ping-pong round trip and frame rate per transport",
        description="C-to-C ping-pong (hilbus_tool echo/ping) on every available transport: "
        "round trip min/median/p99 in µs with one frame in flight, and frames per second "
        "with a window of 8 frames in flight; each with sleeping receivers and with "
        "receivers that busy-poll up to --spin-us before sleeping. vcan is measured only "
        "where the kernel has CAN "
        "(run `rig vm -- rig bench bus` to compare both on one kernel).",
    )
    b.add_argument("--count", type=cliargs.number(int, minimum=1), default=20000,
                   help="pings per measurement")
    cliargs.add_shared(b, "channel", default="benchbus", help="channel name to use")
    b.add_argument("--spin-us", type=cliargs.number(int, minimum=0), default=100,
                   help="busy-poll budget of the 'spin' measurement (HILBUS_SPIN_US)")
    cliargs.command(b, _bench_bus)

    i = bsub.add_parser(
        "isr", help="firmware ISR cost per period: ns on this host, instructions (callgrind)",
        description="Times fw_core_isr() on the host (sil_bench: the core against the real "
        "plant in one process, RUN state at 1000 r/min) and counts instructions per call with "
        "callgrind (one dump per call; the 1 kHz tasks run on a fixed period residue, so "
        "calls are grouped by period mod 10 to tell the 10 kHz path from the 1 kHz path).",
    )
    i.add_argument("--periods", type=cliargs.number(int, minimum=1), default=20000,
                   help="RUN-state periods timed")
    i.add_argument("--callgrind-periods", type=cliargs.number(int, minimum=0), default=400,
                   help="RUN-state periods under callgrind (0: skip callgrind)")
    i.add_argument("--profile", default="paper", choices=bench_plant.PROFILES,
                   help="plant fidelity profile")
    i.add_argument("--target", choices=("host", "cortex-m4f"), default="host",
                   help="cortex-m4f: instructions per call on the emulated Cortex-M4F by path "
                   "(rig.target_m4.bench), beside the host's callgrind figure")
    i.add_argument("--scale", type=cliargs.number(above=0.0), default=4.0,
                   help="cortex-m4f: each measured stretch this many times the CI test's")
    i.add_argument("--whole-runs", action="store_true",
                   help="cortex-m4f: the cases' whole runs (minutes)")
    cliargs.command(i, _bench_isr)

    pl = bsub.add_parser(
        "plant", help="plant compute per period, lockstep periods/s, real-time jitter",
        description=bench_plant.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    bench_plant.add_arguments(pl)
    cliargs.command(pl, _bench_plant)

    si = bsub.add_parser(
        "sil", help="closed loop in one process (--bus inproc) against the bus, same run",
        description=bench_sil.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    bench_sil.add_arguments(si)
    cliargs.command(si, _bench_sil)

    su = bsub.add_parser(
        "startup", help="CPU and wall time of a scenario's start in a new process",
        description=bench_startup.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    bench_startup.add_arguments(su)
    cliargs.command(su, _bench_startup)

    ga = bsub.add_parser(
        "gate", help="the regression gate's wall and CPU time (target: 3 min on 2 cores)",
        description=bench_gate.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    bench_gate.add_arguments(ga)
    cliargs.command(ga, _bench_gate)


def _bench_plant(args: argparse.Namespace) -> int:
    bench_plant.bench_plant(args)  # prints its JSON object
    return 0


def _bench_gate(args: argparse.Namespace) -> int:
    print(json.dumps(bench_gate.bench_gate(args)))
    return 0


def _bench_sil(args: argparse.Namespace) -> int:
    print(json.dumps(bench_sil.bench_sil(args)))
    return 0


def _bench_startup(args: argparse.Namespace) -> int:
    print(json.dumps(bench_startup.bench_startup(args)))
    return 0


def _available_transports(channel: str) -> list[str]:
    found = ["unixcan"]
    if rigbus.kernel_has_can():
        try:
            rigbus.vcan_up(channel)
            found.insert(0, "socketcan")
        except RuntimeError as exc:
            print(f"rig bench bus: socketcan skipped: {exc}", file=sys.stderr)
    return found


def ping_pong(transport: str, channel: str, count: int, fd: bool, window: int,
              spin_us: int = 0) -> dict[str, Any]:
    """Runs an echo node and a ping node (both C) and returns the ping's JSON result."""
    tool = str(_paths.binary("hilbus_tool"))
    env = dict(os.environ, HILBUS_SPIN_US=str(spin_us))
    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / "echo.ready"
        echo = subprocess.Popen([tool, "echo", "--bus", transport, "--channel", channel,
                                 "--ready-file", str(ready)], stdout=subprocess.DEVNULL, env=env)
        try:
            deadline = time.monotonic() + 5
            while not ready.exists():
                if time.monotonic() > deadline or echo.poll() is not None:
                    raise RuntimeError(f"echo node on {transport} did not start")
                time.sleep(0.01)
            args = [tool, "ping", "--bus", transport, "--channel", channel,
                    "--count", str(count), "--window", str(window), "--timeout-ms", "1000"]
            if fd:
                args.append("--fd")
            out = subprocess.run(args, capture_output=True, text=True, check=False, env=env)
            if out.returncode not in (0, 3):
                raise RuntimeError(f"ping on {transport} failed: {out.stderr.strip()}")
            result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
            return result
        finally:
            echo.terminate()
            echo.wait(timeout=5)


def _bench_bus(args: argparse.Namespace) -> int:
    if args.channel.startswith("vcan") is False and rigbus.kernel_has_can():
        channel = "vcanbench"
    else:
        channel = args.channel
    report: dict[str, Any] = {"benchmark": "bus", "host_cpus": os.cpu_count(),
                              "in_vm": os.environ.get("HIL_IN_VM") == "1", "transports": {}}
    for transport in _available_transports(channel):
        entry: dict[str, Any] = {}
        for receiver, spin in (("sleep", 0), ("spin", args.spin_us)):
            for fd in (False, True):
                kind = f"{'fd' if fd else 'classic'}_{receiver}"
                rt = ping_pong(transport, channel, args.count, fd, window=1, spin_us=spin)
                tp = ping_pong(transport, channel, args.count, fd, window=8, spin_us=spin)
                entry[kind] = {"rtt_us": rt.get("rtt_us"), "lost": rt.get("lost"),
                               "frames_per_s": tp.get("frames_per_s"),
                               "tx_drops": tp.get("tx_drops")}
        report["transports"][transport] = entry
    t = report["transports"]
    if "socketcan" in t and "unixcan" in t:
        for kind in ("fd_sleep", "fd_spin"):
            report[f"unixcan_over_vcan_median_rtt_{kind}"] = round(
                t["unixcan"][kind]["rtt_us"]["median"]
                / t["socketcan"][kind]["rtt_us"]["median"], 2)
    print(json.dumps(report))
    return 0


def sil_bench_argv(profile: str, periods: int) -> list[str]:
    """The in-process bench program on a fidelity profile, ``periods`` periods in RUN."""
    path = _paths.data_dir("profiles") / f"{profile}.toml"
    return [str(_paths.binary("sil_bench")), "--profile", str(path), "--periods", str(periods)]


def _bench_isr(args: argparse.Namespace) -> int:
    if args.target == "cortex-m4f":
        from rig.target_m4.bench import bench_isr_m4

        cg = (callgrind_isr(sil_bench_argv(args.profile, args.callgrind_periods),
                            args.callgrind_periods) if args.callgrind_periods > 0 else None)
        print(json.dumps(bench_isr_m4(args.scale, args.whole_runs, cg)))
        return 0
    argv = sil_bench_argv(args.profile, args.periods)
    timed = subprocess.run([*argv, "--time-isr"], capture_output=True, text=True, check=True)
    report: dict[str, Any] = {"benchmark": "isr", "host_timing": json.loads(timed.stdout)}
    if args.callgrind_periods > 0:
        report["instructions"] = callgrind_isr(
            sil_bench_argv(args.profile, args.callgrind_periods), args.callgrind_periods)
    print(json.dumps(report))
    return 0


def callgrind_isr(argv: list[str], periods: int) -> dict[str, Any]:
    """Instructions per fw_core_isr() call, 10 kHz and 1 kHz paths, from callgrind dumps."""
    if shutil.which("valgrind") is None:
        return {"skipped": "valgrind not installed"}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cg.out"
        subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                        "--toggle-collect=fw_core_isr", "--dump-after=fw_core_isr",
                        "--dump-instr=no", *argv],
                       capture_output=True, text=True, check=True)
        dumps = sorted(Path(tmp).glob("cg.out.*"), key=lambda p: int(p.name.rsplit(".", 1)[1]))
        per_call = [_callgrind_total(p) for p in dumps]
    run = per_call[-periods:]  # the bench ends with `periods` calls in the RUN state
    groups: dict[int, list[int]] = {k: run[k::10] for k in range(10)}
    slow_key = max(groups, key=lambda k: statistics.median(groups[k]))
    fast = [v for k, g in groups.items() if k != slow_key for v in g]
    slow = groups[slow_key]
    return {
        "calls_measured": len(run),
        "isr_10khz": {"median": statistics.median(fast), "max": max(fast)},
        "isr_1khz": {"median": statistics.median(slow), "max": max(slow)},
    }


def _callgrind_total(path: Path) -> int:
    for line in path.read_text().splitlines():
        if line.startswith("totals:"):
            return int(line.split()[1])
    return 0
