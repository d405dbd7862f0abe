"""``rig bench sil``: the closed loop in one process against the closed loop on the bus.

One JSON object with both paths measured in the same run, on the same scenario (default: the
Table 2 cell 1000 r/min with 1 N·m on the ``paper`` profile):

- ``inproc``: ``rig run --bus inproc`` (plant and control core in this process): simulated
  seconds per wall second, wall µs per PWM period, and simulated seconds per CPU second of
  the closed loop (what a core of its own gives: less sensitive to a loaded machine);
- ``bus``: the same scenario in lockstep over the bus (plant_rt and fw_host, ``--bus``):
  the same figures;
- ``bus_overhead_us_per_period``: what the bus path costs per period beyond the in-process
  loop, and ``bus_round_trip_us``, the median C-to-C CAN FD ping-pong on that transport with
  sleeping receivers (``rig bench bus``): a lockstep period needs at least one round trip
  (ADC out, PWM back) plus the grant traffic;
- ``sil_bench``: the ``sil_bench`` program on the profile (closed loop at 1000 r/min, no
  Python): wall µs per period, and plant and ISR µs per period from timed calls;
- ``vs_motulator_0_5``: the in-process speed over 0.03 simulated s per wall s, what
  motulator 0.5 (a switching-level Python simulator) was measured at on this motor and
  scenario by the issue's author (not measured here).

Wall times on a shared machine vary with its load; the JSON carries the load average. With
``--repeat N`` each path runs N times and its fastest run counts.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from rig import bus as rigbus
from rig import cliargs, scenario
from rig.benchmarks import machine
from rig.benchmarks.bus import ping_pong
from rig.benchmarks.isr import sil_bench_argv
from rig.data import capture
from rig.run import runner

MOTULATOR_0_5_SIM_S_PER_WALL_S = 0.03
DEFAULT_SCENARIO = "table2_1000rpm_1nm"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default=DEFAULT_SCENARIO,
                   help=f"scenario to run on both paths (default {DEFAULT_SCENARIO})")
    cliargs.add_shared(p, "bus", choices=cliargs.BUS_TRANSPORTS,
                       help="transport of the bus path (default: auto)")
    cliargs.add_shared(p, "channel", default=None,
                       help="bus channel of the bus path (default: on unixcan one of its "
                       "own, run-<pid>; else $HIL_CHANNEL, else vcan0)")
    p.add_argument("--repeat", type=cliargs.number(int, minimum=1), default=1,
                   help="runs per path; the fastest counts (default 1)")
    p.add_argument("--count", type=cliargs.number(int, minimum=1), default=5000,
                   help="pings for the bus round trip")


def _run(sc: scenario.Scenario, out: Path, bus: str | None, channel: str | None
         ) -> dict[str, Any]:
    r = runner.run_scenario(sc, runner.RunOptions(out=out, bus=bus, channel=channel,
                                                  progress=False, record=False,
                                                  figures=False))
    if r.status != "passed" and not r.criteria:
        raise RuntimeError(f"{sc.name} on {bus}: {r.explain()}")
    t = r.timing
    assert t is not None and t.wall_s is not None
    periods = round(t.sim_s / capture.TS)
    out_: dict[str, Any] = {"bus": r.bus, "status": r.status, "sim_s": t.sim_s,
                            "wall_s": round(t.wall_s, 4),
                            "sim_s_per_wall_s": round(t.sim_s / t.wall_s, 3),
                            "wall_us_per_period": round(1e6 * t.wall_s / periods, 3)}
    if t.cpu_s:
        out_["sim_s_per_cpu_s"] = round(t.sim_s / t.cpu_s, 3)
    return out_


def _fastest(runs: list[dict[str, Any]]) -> dict[str, Any]:
    return min(runs, key=lambda r: r["wall_s"])


def sil_bench_program(profile: str) -> dict[str, Any]:
    out = subprocess.run([*sil_bench_argv(profile, 20000), "--time-isr"], capture_output=True,
                         text=True, check=True)
    data: dict[str, Any] = json.loads(out.stdout)
    keys = ("sim_s_per_wall_s", "wall_us_per_period", "plant_us_per_period",
            "isr_us_per_period")
    return {k: data[k] for k in keys}


def measure(args: argparse.Namespace) -> dict[str, Any]:
    sc = scenario.load(args.scenario)
    if not isinstance(sc, scenario.Scenario):
        raise SystemExit(f"rig bench sil: {args.scenario} is a suite, not a scenario")
    report: dict[str, Any] = {"benchmark": "sil", "scenario": sc.name, "profile": sc.profile,
                              "host_cpus": os.cpu_count(),
                              "load_average": machine.load_average()}
    with tempfile.TemporaryDirectory() as tmp:
        inproc = _fastest([_run(sc, Path(tmp) / f"inproc{k}", "inproc", "")
                           for k in range(args.repeat)])
        bus = _fastest([_run(sc, Path(tmp) / f"bus{k}", args.bus, args.channel)
                        for k in range(args.repeat)])
    report["inproc"] = inproc
    report["bus"] = bus
    report["same_status"] = inproc["status"] == bus["status"]
    report["speedup_inproc_over_bus"] = round(bus["wall_s"] / inproc["wall_s"], 2)
    report["bus_overhead_us_per_period"] = round(
        bus["wall_us_per_period"] - inproc["wall_us_per_period"], 3)
    rtt = ping_pong(bus["bus"], args.channel or rigbus.own_channel("bench-sil"), args.count,
                    fd=True, window=1)
    report["bus_round_trip_us"] = rtt.get("rtt_us", {}).get("median")
    if report["bus_round_trip_us"]:
        report["bus_overhead_over_round_trip"] = round(
            report["bus_overhead_us_per_period"] / report["bus_round_trip_us"], 2)
    report["sil_bench"] = sil_bench_program(sc.profile)
    report["vs_motulator_0_5"] = round(
        inproc["sim_s_per_wall_s"] / MOTULATOR_0_5_SIM_S_PER_WALL_S, 0)
    report["load_average_after"] = machine.load_average()
    return report
