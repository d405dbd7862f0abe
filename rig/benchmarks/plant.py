"""``rig bench plant``: what one simulated PWM period of the bench emulator costs.

Three measurements, one JSON object (printed and returned) with the load average of the machine
before and after them (``load_average``, ``load_average_after``):

- ``compute``: plant compute per simulated period, median and 99th percentile in µs, per
  fidelity profile, from ``plant_bench`` (the physics library alone, no bus).
- ``lockstep``: periods per second of ``plant_rt`` in lockstep against ``pwm_responder``, a
  minimal C stand-in for the firmware that answers every ADC(k) with a fixed PWM(k+1), on
  every available transport. The difference between the wall time per period and the
  compute per period is what the bus round trip and the responder cost.
- ``realtime`` (only with ``--realtime SECONDS``): ``plant_rt --realtime`` against the same
  responder: wake-up lateness of the period timer (mean, p99, max in µs), late PWM updates,
  overruns and slipped periods (``--rt-spin-us`` passes the plant's busy-poll margin).
"""

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

from rig import _paths, cliargs, protocols
from rig import bus as rigbus
from rig.benchmarks import machine

PROFILES = ("ideal", "paper", "harsh")
TS = protocols.timebase().ts  # PWM period
RESPONDER_RT_PRIORITY = 70  # below plant_rt's default 80: the plant's timer comes first


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--periods", type=int, default=20000,
                        help="simulated periods per profile for the compute figures")
    parser.add_argument("--lockstep-periods", type=int, default=20000,
                        help="periods of each lockstep run")
    parser.add_argument("--profile", default="paper", choices=PROFILES,
                        help="fidelity profile of the lockstep and real-time runs")
    parser.add_argument("--realtime", type=float, default=0.0, metavar="SECONDS",
                        help="also run this long in real time on each transport (default: off)")
    parser.add_argument("--rt-spin-us", type=int, default=0, metavar="US",
                        help="real time: plant_rt --rt-spin-us (poll instead of sleeping for the "
                        "last US microseconds before each period; default 0)")
    cliargs.add_shared(parser, "bus", choices=("socketcan", "unixcan"),
                       help="only this transport (default: every available one)")
    parser.add_argument("--transport", action="append", choices=("socketcan", "unixcan"),
                        help="only this transport (repeatable, for both: --transport "
                        "socketcan --transport unixcan)")
    cliargs.add_shared(parser, "channel", default="vcanbench",
                       help="channel (SocketCAN: a vcan interface, created when possible)")


def _transports(args: argparse.Namespace) -> list[str]:
    chosen = [*(args.transport or []), *([args.bus] if args.bus else [])]
    wanted = chosen or ["socketcan", "unixcan"]
    found: list[str] = []
    if "socketcan" in wanted:
        if rigbus.kernel_has_can():
            try:
                rigbus.vcan_up(args.channel)
                found.append("socketcan")
            except RuntimeError as exc:
                print(f"rig bench plant: socketcan skipped: {exc}", file=sys.stderr)
        elif chosen:
            print("rig bench plant: socketcan skipped: this kernel has no CAN", file=sys.stderr)
    if "unixcan" in wanted:
        found.append("unixcan")
    return found


def _last_json(text: str, who: str) -> dict[str, Any]:
    for line in reversed(text.splitlines()):
        if line.strip().startswith("{"):
            value = json.loads(line)
            if isinstance(value, dict):
                return value
    raise RuntimeError(f"{who} printed no JSON result: {text.strip()[-500:]}")


def compute_cost(periods: int) -> dict[str, Any]:
    out = subprocess.run(
        [str(_paths.binary("plant_bench")), str(_paths.data_dir("profiles")), str(periods)],
        capture_output=True, text=True, check=False, timeout=600)
    if out.returncode != 0:
        raise RuntimeError(f"plant_bench failed: {out.stderr.strip()}")
    raw = _last_json(out.stdout, "plant_bench")
    return {name: {"median_us": v["median_us"], "p99_us": v["p99_us"],
                   "rhs_per_period": v["rhs_per_period"],
                   "events_per_period": v["events_per_period"]}
            for name, v in raw.items()}


def _wait_ready(path: Path, proc: subprocess.Popen[str], who: str) -> None:
    deadline = time.monotonic() + 10.0
    while not path.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            _, err = proc.communicate()
            raise RuntimeError(f"{who} did not start: {err.strip()}")
        time.sleep(0.005)


def run_pair(transport: str, channel: str, plant_args: list[str], responder_args: list[str],
             timeout: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """plant_rt against pwm_responder until the plant stops (--max-periods); returns both
    programs' JSON results."""
    with tempfile.TemporaryDirectory(prefix="rig-bench-plant-") as tmp:
        env = dict(os.environ, UNIXCAN_DIR=str(Path(tmp) / "unixcan"))
        ready = Path(tmp) / "responder.ready"
        responder = subprocess.Popen(
            [str(_paths.binary("pwm_responder")), "--bus", transport, "--channel", channel,
             "--ready-file", str(ready), *responder_args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        try:
            _wait_ready(ready, responder, "pwm_responder")
            plant = subprocess.run(
                [str(_paths.binary("plant_rt")), "--bus", transport, "--channel", channel,
                 *plant_args],
                capture_output=True, text=True, check=False, env=env, timeout=timeout)
            if plant.returncode != 0:
                raise RuntimeError(f"plant_rt on {transport} failed: {plant.stderr.strip()[-500:]}")
            plant_result = _last_json(plant.stderr, "plant_rt")
        finally:
            if responder.poll() is None:
                responder.terminate()
            out, _ = responder.communicate(timeout=10)
        return plant_result, _last_json(out, "pwm_responder")


def lockstep_rate(transport: str, channel: str, profile: str, periods: int,
                  compute_median_us: float | None) -> dict[str, Any]:
    plant, resp = run_pair(
        transport, channel,
        ["--lockstep", "--profile", profile, "--run-until", str(periods),
         "--max-periods", str(periods)],
        [], timeout=max(60.0, periods * 1e-3))
    pps = float(resp["periods_per_s"])
    entry: dict[str, Any] = {
        "periods": plant["periods"],
        "periods_per_s": round(pps, 1),
        "sim_s_per_wall_s": round(pps * TS, 3),
        "wall_us_per_period": round(1e6 / pps, 2) if pps > 0 else None,
        "resends": plant["resends"],
        "tx_drops": plant["tx_drops"] + resp.get("tx_drops", 0),
    }
    if compute_median_us is not None and pps > 0:
        entry["bus_and_responder_us_per_period"] = round(1e6 / pps - compute_median_us, 2)
    return entry


def realtime_run(transport: str, channel: str, profile: str, seconds: float,
                 spin_us: int = 0) -> dict[str, Any]:
    periods = max(1, round(seconds / TS))
    t0 = time.monotonic()
    plant, resp = run_pair(
        transport, channel,
        ["--realtime", "--profile", profile, "--max-periods", str(periods),
         "--rt-spin-us", str(spin_us)],
        ["--rt-priority", str(RESPONDER_RT_PRIORITY)], timeout=seconds * 20 + 60)
    return {
        "simulated_s": round(periods * TS, 3),
        "wall_s": round(time.monotonic() - t0, 3),  # includes start-up; more with slips
        "periods": plant["periods"],
        "rt_spin_us": spin_us,
        "wake_late_us": plant.get("wake_late_us"),
        "late_cmds": plant["late_cmds"],
        "overruns": plant["overruns"],
        "slipped_periods": plant.get("slipped_periods"),
        "max_late_us": plant["max_late_us"],
        "stale_rejects": plant["rejects"]["stale_period"],
        "tx_drops": plant["tx_drops"] + resp.get("tx_drops", 0),
        "plant_sched": plant.get("rt"),
        "responder_sched": resp.get("rt"),
    }


def measure(args: argparse.Namespace) -> dict[str, Any]:
    # the machine's load beside the figures (a shared machine's figures depend on it), at
    # the start and at the end of the measurement
    report: dict[str, Any] = {"benchmark": "plant", "host_cpus": os.cpu_count(),
                              "in_vm": os.environ.get("HIL_IN_VM") == "1",
                              "profile": args.profile,
                              "load_average": machine.load_average()}
    report["compute"] = compute_cost(args.periods)
    compute_median = report["compute"].get(args.profile, {}).get("median_us")
    transports = _transports(args)
    report["lockstep"] = {t: lockstep_rate(t, _channel(t, args.channel), args.profile,
                                           args.lockstep_periods, compute_median)
                          for t in transports}
    if args.realtime > 0:
        report["realtime"] = {t: realtime_run(t, _channel(t, args.channel), args.profile,
                                              args.realtime, args.rt_spin_us)
                              for t in transports}
    report["load_average_after"] = machine.load_average()
    print(json.dumps(report))
    return report


def _channel(transport: str, channel: str) -> str:
    # SocketCAN needs the interface; on unixcan a channel of the benchmark's own
    return channel if transport == "socketcan" else rigbus.own_channel("bench-plant")
