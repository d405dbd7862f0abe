"""C-to-C ping-pong (hilbus_tool echo/ping) on every available transport: round trip
min/median/p99 in µs with one frame in flight, and frames per second with a window of 8
frames in flight; each with sleeping receivers and with receivers that busy-poll up to
--spin-us before sleeping. vcan is measured only where the kernel has CAN (run `rig vm --
rig bench bus` to compare both on one kernel)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rig import _paths, cliargs
from rig import bus as rigbus

HELP = "C-to-C ping-pong round trip and frame rate per transport"


def add_arguments(b: argparse.ArgumentParser) -> None:
    b.add_argument("--count", type=cliargs.number(int, minimum=1), default=20000,
                   help="pings per measurement")
    cliargs.add_shared(b, "channel", default=None,
                       help="channel name to use (default: on unixcan one of its own, "
                       "bench-bus-<pid>; on SocketCAN vcanbench)")
    b.add_argument("--spin-us", type=cliargs.number(int, minimum=0), default=100,
                   help="busy-poll budget of the 'spin' measurement (HILBUS_SPIN_US)")


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


def measure(args: argparse.Namespace) -> dict[str, Any]:
    named = args.channel
    if (named is None or not named.startswith("vcan")) and rigbus.kernel_has_can():
        channel = "vcanbench"
    else:
        channel = named or rigbus.own_channel("bench-bus")
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
    return report
