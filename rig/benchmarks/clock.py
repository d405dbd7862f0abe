"""``rig bench clock``: how closely the wall clock of a real bench keeps its cadence here.

A real bench's session runs on ``rig.link.clock.WallClock``: the drive command every cycle of
DRIVE_CMD (drive.dbc GenMsgCycleTime, 10 ms) and the idle hooks (the load bench's watchdog)
every 100 ms. The tests hold it only to what any machine gives (never faster than that, never
a burst); how close to the cadence it stays depends on the machine and its load, so it is
measured here: ``--seconds`` (default 5) of wall clock on a fallback-bus channel of its own,
sending DRIVE_CMD to nobody. One JSON object: the cycles and idle calls per second against
the nominal, the gaps between cycles (median, 99th percentile, largest) and the load average.
"""

from __future__ import annotations

import argparse
import statistics
import time
from itertools import pairwise
from typing import Any

from rig import bus as rigbus
from rig import cliargs, protocols
from rig.benchmarks import machine
from rig.link.bus import BusLink
from rig.link.clock import IDLE_S, WallClock

HELP = "the wall clock's 10 ms drive-command cycle and 100 ms idle hooks: rates and gaps"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=cliargs.number(float, above=0.0, unit="s"), default=5.0,
                   help="wall time measured (default 5 s)")


def measure(args: argparse.Namespace) -> dict[str, Any]:
    described = machine.described()
    cycle_s = protocols.database("drive").get_message_by_name("DRIVE_CMD").cycle_time / 1e3
    channel = rigbus.own_channel("bench-clock")
    link = BusLink.open("unixcan", channel)
    try:
        clock = WallClock(link)
        cycles: list[float] = []
        idles: list[float] = []

        def cycle() -> None:
            link.send("DRIVE_CMD", {"enable": 0, "fault_reset": 0, "ctrl_mode": 0,
                                    "fw_mode": 0, "alive": len(cycles) % 256,
                                    "speed_ref": 0.0, "iq_ref": 0.0})
            cycles.append(time.monotonic())

        clock.on_cycle(cycle)
        clock.on_idle(lambda: idles.append(time.monotonic()))
        t0 = time.monotonic()
        clock.advance(args.seconds)
        wall = time.monotonic() - t0
    finally:
        link.close()
        rigbus.release_own_channel(channel)
    gaps_ms = sorted((b - a) * 1e3 for a, b in pairwise(cycles))
    return {
        "benchmark": "clock", **described, "load_average_after": machine.load_average(),
        "seconds": round(wall, 3),
        "cycle_ms_nominal": cycle_s * 1e3,
        "cycles_per_s": round(len(cycles) / wall, 2),
        "cycles_per_s_nominal": round(1.0 / cycle_s, 2),
        "cycle_gap_ms": {"median": round(statistics.median(gaps_ms), 3),
                         "p99": round(gaps_ms[min(len(gaps_ms) - 1,
                                                  int(0.99 * len(gaps_ms)))], 3),
                         "max": round(gaps_ms[-1], 3)} if gaps_ms else None,
        "idle_per_s": round(len(idles) / wall, 2),
        "idle_per_s_nominal": round(1.0 / IDLE_S, 2),
    }
