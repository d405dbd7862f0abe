"""Runs a scenario (or a suite) end to end: plant and firmware up, commands, capture, verdict.

Lockstep (default): before each grant the rig sends DRIVE_LIMITS, DRIVE_CMD, LOAD_CMD, the
FAULT_CMDs of faults that start or end on its first period (``rig.faults``; faults on the
rig's own frames act in ``rig.drive_link``) and then BENCH_STEP; the plant simulates up to
``run_until`` and answers BENCH_PROGRESS. Grants last at most ``grant_max_s`` (100 ms) of
simulated time and end exactly at every profile breakpoint, so commands take effect on an
exact period. Speed ramps are the firmware's own ramp: at a segment start the rig sets
``speed_ref`` to the segment's target and ``accel_max`` to the segment's slope (a step uses
the DBC maximum of ``accel_max``); the expected reference (``speed_ref_rpm`` in the capture)
is the same rate limiter evaluated here. Torque ramps of the load are sent as 1 ms steps.
DRIVE_CMD goes out with every grant, which also keeps the firmware's command time-out alive.

Real-time: the same commands on the wall clock against the plant's period counter
(estimated from BENCH_PROGRESS), DRIVE_CMD every 10 ms.

In process (``--bus inproc``, ``rig.sil``): no programs and no bus; the same frames go into the
in-process bench before each of the same grants, and a grant runs the bench to its
``run_until`` (lockstep only). The traces are the same files.

Afterwards the traces are merged (``rig.capture``), the criteria evaluated on the data the
run produced (``rig.verdict``, ``rig.metrics``), and ``result.json``, ``report.md`` and
``recording.rrd`` written.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import json
import math
import platform
import shutil
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import can
import numpy as np

from rig import (
    __version__,
    _paths,
    capture,
    drive_link,
    faults,
    metrics,
    outdirs,
    output,
    profiles,
    protocols,
    recording,
    report,
    sil,
)
from rig.firmware_from_profile import firmware_settings
from rig.frames import FrameDecoder
from rig.progress import Progress
from rig.scenario import Comparison, Scenario, Suite
from rig.supervisor import ChildFailed, StopReport, Supervisor, Terminated
from rig.verdict import AGAINST, NOT_EVALUATED, Coverage, evaluate_one, outcome, outcome_of

TS = capture.TS
PROGRESS_RESEND_S = 1.0  # re-send a grant when the plant has said nothing for this long
STALL_S = 10.0  # no progress at all for this long: the lockstep is stuck
CMD_PERIOD_S = 0.01  # real time: DRIVE_CMD cycle (drive.dbc GenMsgCycleTime)
RECV_SLICE_S = 0.05
MAX_POST_FAILURE_PERIODS = 50_000  # after a crash, merge/record only short traces (fast)

EXIT_PASS = 0
EXIT_FAIL = 1
EXIT_USAGE = 2
EXIT_ENV = 3
EXIT_INTERRUPTED = 130


class RunError(RuntimeError):
    """The run could not go on: stall, time-out, bus error. ``kind`` names the reason."""

    def __init__(self, kind: str, message: str, log_tail: str = "") -> None:
        self.kind = kind
        self.log_tail = log_tail
        super().__init__(message)


class EnvironmentProblem(RuntimeError):
    """The run cannot start here (programs not built, bus unavailable)."""


# --------------------------------------------------------------------------------------
# Options and results


@dataclass
class RunOptions:
    out: Path
    bus: str | None = None
    channel: str | None = None
    realtime: bool = False
    live: bool = False
    live_stream: Any = None  # an rr.RecordingStream to use instead of spawning a viewer
    live_url: str | None = None  # stream the live view to this gRPC server (the web viewer)
    progress: bool = True
    timeout_s: float | None = None
    grace_s: float = 5.0
    stall_s: float = STALL_S
    record: bool = True
    # what a run keeps besides result.json, report.md and recording.rrd: "all" keeps the
    # full-rate traces (*.trace) and capture columns (capture/) of every run, "failing" only
    # of runs that did not pass (rig run's default; the API's is "all": callers read captures)
    keep: str = "all"
    extra_plant_args: Sequence[str] = ()
    extra_fw_args: Sequence[str] = ()
    env: Mapping[str, str] = field(default_factory=dict)


@dataclass
class RunResult:
    """What a run produced: ``data`` is the content of ``result.json``."""

    out_dir: Path
    data: dict[str, Any]
    capture: capture.Capture | None = None

    @property
    def passed(self) -> bool:
        return bool(self.data.get("passed"))

    @property
    def status(self) -> str:
        return str(self.data.get("status"))

    @property
    def criteria(self) -> list[dict[str, Any]]:
        return list(self.data.get("criteria", []))

    def failed_criteria(self) -> list[dict[str, Any]]:
        """Criteria that count against the run: failed or not evaluated (an XFAIL does not,
        an XPASS does not)."""
        return [c for c in self.criteria if outcome(c) in AGAINST]

    def expected_failures(self) -> list[dict[str, Any]]:
        return [c for c in self.criteria if outcome(c) in ("xfail", "xpass")]

    def criterion(self, name: str) -> dict[str, Any]:
        for c in self.criteria:
            if c["name"] == name:
                return c
        raise KeyError(name)

    def window(self, t0: float = 0.0, t1: float | None = None) -> metrics.Window:
        if self.capture is None:
            raise RuntimeError(f"run in {self.out_dir} has no capture ({self.status})")
        cap = self.capture
        end = cap.duration + cap.first_period * cap.ts if t1 is None else t1
        return metrics.Window(cap, t0, end, ts=cap.ts, first_period=cap.first_period,
                              counters=self.data.get("counters", {}))

    def metric(self, name: str, window: tuple[float, float] | None = None,
               **params: float) -> float:
        """Any metric over any window of the capture (for custom assertions in tests)."""
        w = self.window(*(window or (0.0, None)))  # type: ignore[arg-type]
        return metrics.compute(name, w, params)

    def explain(self) -> str:
        lines = [f"{self.data.get('scenario')}: {self.status} ({self.out_dir})"]
        failure = self.data.get("failure")
        if failure:
            lines.append(f"  {failure.get('kind')}: {failure.get('message')}")
            if failure.get("log_tail"):
                lines += ["    " + x for x in str(failure["log_tail"]).splitlines()[-15:]]
        for c in self.failed_criteria():
            if outcome(c) == NOT_EVALUATED:
                lines.append(f"  NOT EVALUATED {c['name']}: {c.get('note')}")
                continue
            lines.append(
                f"  FAIL {c['name']}: {c['metric']} over {c['window']} = {c['value']} "
                f"(limit {c['comparison']} {c['limit']})"
            )
        return "\n".join(lines)

    def assert_passed(self) -> None:
        if not self.passed:
            raise AssertionError(self.explain())

    @classmethod
    def load(cls, out_dir: str | Path) -> RunResult:
        d = Path(out_dir)
        data = json.loads((d / "result.json").read_text())
        cap = capture.Capture(d / "capture") if (d / "capture" / "meta.json").exists() else None
        return cls(d, data, cap)


@dataclass
class SuiteResult:
    out_dir: Path
    data: dict[str, Any]
    results: list[RunResult]

    @property
    def passed(self) -> bool:
        return bool(self.data.get("passed"))


# --------------------------------------------------------------------------------------
# Commands


def _step_accel() -> float:
    """The acceleration limit of a speed step, as DRIVE_LIMITS carries it."""
    return protocols.quantize("drive", "DRIVE_LIMITS", "accel_max", accel_step_limit())


def _msg(db: str, name: str) -> Any:
    return protocols.database(db).get_message_by_name(name)


def accel_step_limit() -> float:
    """The largest acceleration DRIVE_LIMITS can carry (a speed 'step')."""
    sig = _msg("drive", "DRIVE_LIMITS").get_signal_by_name("accel_max")
    return float(sig.maximum)


@dataclass
class DriveState:
    enable: int = 0
    ctrl_mode: str = "speed"
    fw_mode: str = "realtime"
    speed_ref: float = 0.0
    accel: float = 0.0
    iq_ref: float = 0.0
    i_max: float = 3.0
    speed_max: float = 3300.0


@dataclass
class LoadState:
    mode: str = "torque"
    torque: float = 0.0
    speed: float = 0.0
    k_speed: float = 0.0


@dataclass
class Plan:
    """Commands per period and the grant boundaries of a scenario."""

    n_periods: int
    drive_events: dict[int, list[Callable[[DriveState], None]]]
    load_events: dict[int, LoadState]
    boundaries: list[int]
    grant_max: int
    # FAULT_CMD signals to send before the grant that starts on a period (plant-side faults)
    fault_cmds: dict[int, list[dict[str, float | int]]] = field(default_factory=dict)
    # the faults on the rig's own frames (rig.drive_link)
    link_windows: list[drive_link.Window] = field(default_factory=list)

    @classmethod
    def build(cls, sc: Scenario) -> Plan:
        n = round(sc.duration / TS)
        step = accel_step_limit()
        drive: dict[int, list[Callable[[DriveState], None]]] = {}

        def at(t: float) -> int:
            return min(max(round(t / TS), 0), n)

        def on(t: float, fn: Callable[[DriveState], None]) -> None:
            drive.setdefault(at(t), []).append(fn)

        on(sc.enable_at, lambda s: setattr(s, "enable", 1))
        for cmd in sc.speed_commands(step):
            acc = protocols.quantize("drive", "DRIVE_LIMITS", "accel_max", min(cmd.accel, step))
            if acc <= 0:
                acc = protocols.quantize("drive", "DRIVE_LIMITS", "accel_max", step)

            def apply(s: DriveState, target: float = cmd.target, a: float = acc) -> None:
                s.speed_ref, s.accel = target, a

            on(cmd.t, apply)
        loads: dict[int, LoadState] = {}
        for lc in sc.load_commands():
            loads[at(lc.t)] = LoadState(lc.mode, lc.torque, lc.speed, lc.k_speed)
        fault_cmds: dict[int, list[dict[str, float | int]]] = {}
        slot = 0
        for f in sc.faults:
            if not f.on_plant:
                continue
            start, end = f.periods(n)
            fault_cmds.setdefault(start, []).append(f.fault_cmd(slot))
            if end < n:
                fault_cmds.setdefault(end, []).append(faults.Fault.clear_cmd(slot))
            slot += 1
        link_windows = drive_link.windows(sc.faults, n)
        bps = {at(t) for t in sc.breakpoints(step)} | set(drive) | set(loads) | set(fault_cmds)
        for w in link_windows:
            bps |= {w.start, w.end}
        plan = cls(n, drive, loads, [], max(1, round(sc.grant_max_s / TS)), fault_cmds,
                   link_windows)
        while True:
            # a frame the rig holds back arrives exactly before its due period: make every
            # due period a grant start (due periods of those starts too, up to a fixed point)
            plan.boundaries = [*sorted(p for p in bps if 0 < p < n), n]
            due = drive_link.due_periods(link_windows, (g[0] for g in plan.grants()), n)
            if due <= bps:
                return plan
            bps |= due

    def grants(self) -> list[tuple[int, int]]:
        """(start, run_until) pairs covering [0, n)."""
        out: list[tuple[int, int]] = []
        p = 0
        for b in self.boundaries:
            while p < b:
                q = min(b, p + self.grant_max)
                out.append((p, q))
                p = q
        return out


class Commander:
    """Encodes and sends the rig's frames (cantools; layouts only from the DBC)."""

    def __init__(self, bus: can.BusABC | sil.BenchPort,
                 link: drive_link.DriveLink | None = None) -> None:
        self.bus = bus
        self.alive = 0
        self.load_seq = 0
        self.step_seq = 0
        self.fault_seq = 0
        self.tx = 0
        self.link = link if link is not None else drive_link.DriveLink()
        # the frames sent since the last at(), and whether a fault corrupted each
        self.batch: list[tuple[can.Message, bool]] = []
        self._m = {
            "DRIVE_CMD": _msg("drive", "DRIVE_CMD"),
            "DRIVE_LIMITS": _msg("drive", "DRIVE_LIMITS"),
            "LOAD_CMD": _msg("bench", "LOAD_CMD"),
            "FAULT_CMD": _msg("bench", "FAULT_CMD"),
            "BENCH_STEP": _msg("bench", "BENCH_STEP"),
        }
        self._ctrl = protocols.choices("drive", "DRIVE_CMD", "ctrl_mode")
        self._fw = protocols.choices("drive", "DRIVE_CMD", "fw_mode")
        self._load = protocols.choices("bench", "LOAD_CMD", "mode")

    def _send(self, name: str, values: Mapping[str, float | int]) -> None:
        m = self._m[name]
        data = bytes(m.encode(dict(values), scaling=True, strict=True))
        if name in faults.RIG_MESSAGES:
            sent = self.link.filter(name, data)
            if sent is None:
                return  # dropped or held back by a fault (rig.drive_link)
            self._send_raw(name, sent, faulted=sent != data)
            return
        self._send_raw(name, data)

    def _send_raw(self, name: str, data: bytes, faulted: bool = False) -> None:
        m = self._m[name]
        msg = can.Message(arbitration_id=m.frame_id, is_extended_id=m.is_extended_frame,
                          data=data, is_fd=bool(m.is_fd), bitrate_switch=False)
        self._put(msg, faulted)
        self.batch.append((msg, faulted))

    def _put(self, msg: can.Message, faulted: bool) -> None:
        if faulted and isinstance(self.bus, sil.BenchPort):
            self.bus.send_faulted(msg)
        else:
            self.bus.send(msg)
        self.tx += 1

    def at(self, period: int) -> None:
        """The sends that follow are before ``period``: frames held back until then go
        first."""
        self.batch = []
        self.link.at(period)
        for name, data, corrupted in self.link.due():
            self._send_raw(name, data, faulted=corrupted)

    def resend(self) -> None:
        """The frames sent since the last ``at()`` again, byte for byte (a lost grant)."""
        for msg, faulted in list(self.batch):
            self._put(msg, faulted)

    def fault(self, values: Mapping[str, float | int]) -> None:
        self.fault_seq = (self.fault_seq + 1) % 256
        self._send("FAULT_CMD", {**values, "seq": self.fault_seq})

    def drive(self, s: DriveState) -> None:
        self._send("DRIVE_LIMITS", {"i_max": s.i_max, "speed_max": s.speed_max,
                                    "accel_max": s.accel})
        self.drive_cmd_only(s)

    def drive_cmd_only(self, s: DriveState) -> None:
        self.alive = (self.alive + 1) % 256
        self._send("DRIVE_CMD", {
            "enable": s.enable, "fault_reset": 0, "ctrl_mode": self._ctrl[s.ctrl_mode],
            "fw_mode": self._fw[s.fw_mode], "alive": self.alive, "speed_ref": s.speed_ref,
            "iq_ref": s.iq_ref,
        })

    def load(self, s: LoadState) -> None:
        self.load_seq = (self.load_seq + 1) % 256
        self._send("LOAD_CMD", {"mode": self._load[s.mode], "seq": self.load_seq,
                                "torque": s.torque, "speed": s.speed, "k_speed": s.k_speed})

    def step(self, run_until: int, *, new: bool = True) -> int:
        if new:
            self.step_seq = (self.step_seq + 1) % 256
        self._send("BENCH_STEP", {"run_until": run_until, "seq": self.step_seq})
        return self.step_seq


# --------------------------------------------------------------------------------------
# What the rig hears on the bus


LISTEN = (
    ("bench", "BENCH_PROGRESS"), ("bench", "BENCH_COUNTERS"), ("bench", "BENCH_REJECTS"),
    ("bench", "BENCH_TRUTH"), ("drive", "DRIVE_STATUS"), ("drive", "HEARTBEAT"),
    ("drive", "TLM_POS"), ("drive", "TLM_CUR"), ("drive", "TLM_REF"), ("drive", "TLM_PARAM"),
    ("drive", "TLM_VOLT"),
)


TLM_IDS = {int(_msg("drive", n).frame_id): n for db, n in LISTEN if n.startswith("TLM_")}
FAULT_STATE = protocols.choices("drive", "DRIVE_STATUS", "state")["fault"]


def listen_filters() -> list[dict[str, int]]:
    return [{"can_id": int(_msg(db, n).frame_id), "can_mask": 0x7FF} for db, n in LISTEN]


class Monitor:
    """Validates and decodes the frames the rig hears (``rig.frames``: unknown IDs, bad
    lengths and out-of-range values are counted rejections); keeps progress, counters and
    the latest telemetry, and feeds the live view."""

    def __init__(self, live: recording.LiveView | None = None) -> None:
        self.decoder = FrameDecoder()
        self._wanted = {int(_msg(db, n).frame_id) for db, n in LISTEN}
        self.progress_period: int | None = None
        self.progress_seq: int | None = None
        self.progress_wall: float = 0.0
        self.progress_frames = 0
        self.latest: dict[str, dict[str, float]] = {}
        self.counter_log: list[tuple[int, dict[str, float]]] = []
        self.rx = 0
        self.faults = 0
        self.grant_resends = 0
        self._last_state: int | None = None
        self.live = live
        self._truth_by_p16: dict[int, float] = {}
        self._raw_tlm: dict[str, can.Message] = {}

    def handle(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        self.rx += 1
        if msg.arbitration_id not in self._wanted:
            return
        # telemetry at the speed-loop rate: without a live view decode only on demand
        if self.live is None and TLM_IDS.get(msg.arbitration_id):
            self._raw_tlm[TLM_IDS[msg.arbitration_id]] = msg
            return
        decoded = self.decoder.decode(msg)
        if decoded is None:
            return
        name = decoded.name
        vals = {k: float(v) for k, v in decoded.signals.items()}
        self.latest[name] = vals
        if name == "BENCH_PROGRESS":
            self.progress_period = int(vals["period"])
            self.progress_seq = int(vals["seq"])
            self.progress_wall = time.monotonic()
            self.progress_frames += 1
        elif name == "BENCH_COUNTERS":
            self.counter_log.append((int(vals["period"]), vals))
        elif name == "DRIVE_STATUS":
            state = int(vals["state"])
            if state == FAULT_STATE and self._last_state != FAULT_STATE:
                self.faults += 1
            self._last_state = state
        elif name == "BENCH_TRUTH":
            self._truth_by_p16[int(vals["period"]) & 0xFFFF] = vals["theta_e"]
            if len(self._truth_by_p16) > 4096:
                self._truth_by_p16.clear()
        if self.live is not None:
            self._to_live(name, vals)

    def _full_period(self, p16: int) -> int:
        base = self.progress_period or 0
        cand = (base & ~0xFFFF) | p16
        if cand > base + 0x8000:
            cand -= 0x10000
        elif cand < base - 0x8000:
            cand += 0x10000
        return max(cand, 0)

    def _to_live(self, name: str, v: Mapping[str, float]) -> None:
        live = self.live
        assert live is not None
        if name == "TLM_POS":
            p = self._full_period(int(v["period"]))
            live.add("speed", p, {"estimated": v["speed_hat"]})
            values = {"θ̂": v["theta_hat"], "θ": math.nan}  # θ: when the truth is known
            th = self._truth_by_p16.get(int(v["period"]))
            if th is not None:
                true_deg = math.degrees(th) % 360.0
                values["θ"] = true_deg
                err = (v["theta_hat"] - true_deg + 180.0) % 360.0 - 180.0
                live.add("error", p, {"θ̂ - θ": err})
            live.add("position", p, values)
        elif name == "TLM_CUR":
            p = self._full_period(int(v["period"]))
            live.add("current", p, {"id": v["id"], "iq": v["iq"]})
            live.add("torque", p, {"T̂e": v["te_hat"]})
        elif name == "TLM_REF":
            p = self._full_period(int(v["period"]))
            live.add("speed_ref", p, {"reference": v["speed_ref"]})
        elif name == "TLM_PARAM":
            p = self._full_period(int(v["period"]))
            live.add("params", p, {"Ld̂ (mH)": v["ld_hat"] * 1e3, "Lq̂ (mH)": v["lq_hat"] * 1e3,
                                   "λ̂m": v["lambda_hat"]})
        elif name == "BENCH_TRUTH":
            p = int(v["period"])
            live.add("speed_true", p, {"true": v["omega_m"] * capture.RPM_PER_RAD_S})
            live.add("torque_true", p, {"Te": v["te"], "TL": v["tl"]})

    def snapshot(self) -> tuple[float | None, float | None]:
        """(speed r/min, position error deg) for the progress line, when the bus shows them."""
        speed = err = None
        truth = self.latest.get("BENCH_TRUTH")
        if truth:
            speed = truth["omega_m"] * capture.RPM_PER_RAD_S
        pos: Mapping[str, Any] | None = self.latest.get("TLM_POS")
        raw = self._raw_tlm.get("TLM_POS")
        if raw is not None:
            d = self.decoder.decode(raw)
            pos = d.signals if d is not None else None
        if pos is not None:
            if speed is None:
                speed = float(pos["speed_hat"])
            th = self._truth_by_p16.get(int(pos["period"]))
            if th is not None:
                err = (float(pos["theta_hat"]) - math.degrees(th) + 180.0) % 360.0 - 180.0
        return speed, err

    def counters(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for name, prefix in (("BENCH_COUNTERS", "bench"), ("BENCH_REJECTS", "rejects")):
            for k, v in self.latest.get(name, {}).items():
                if k != "period":
                    out[f"{prefix}.{k}"] = v
        status = self.latest.get("HEARTBEAT")
        if status:
            out["firmware.isr_overruns_heartbeat"] = status["isr_overruns"]
        drive = self.latest.get("DRIVE_STATUS")
        if drive:
            out["firmware.rx_rejected_status"] = drive["rx_rejected"]
            out["firmware.fault_code_last"] = drive["fault_code"]
        for reason, count in self.decoder.rejected.items():
            out[f"rig.rejected.{reason}"] = float(count)
        return out


# --------------------------------------------------------------------------------------
# The run


def _flatten(prefix: str, value: Any, out: dict[str, float]) -> None:
    if isinstance(value, Mapping):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}", v, out)
    elif isinstance(value, bool):
        out[prefix] = float(value)
    elif isinstance(value, int | float):
        out[prefix] = float(value)


def profile_values(sc: Scenario) -> tuple[Path | None, dict[str, Any]]:
    """The fidelity profile file and its flat ``section.key`` values with the overrides."""
    return profiles.profile_file(sc.profile), profiles.profile_values(sc.profile, sc.overrides)


# Plant configuration keys of the initial rotor state (set only when not zero).
PLANT_INITIAL = {"theta_e_deg": "initial.theta_e_deg", "speed_rpm": "initial.speed_rpm"}


def _fmt_value(v: Any) -> str:
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return format(v, ".17g")
    return str(v)


def plant_sets(sc: Scenario) -> list[str]:
    """The plant's ``section.key=value`` settings over its profile (plant_rt ``--set``)."""
    sets = [f"{k}={_fmt_value(v)}" for k, v in sc.overrides.items()]
    if sc.initial_theta_deg:
        sets.append(f"{PLANT_INITIAL['theta_e_deg']}={sc.initial_theta_deg!r}")
    if sc.initial_speed_rpm:
        sets.append(f"{PLANT_INITIAL['speed_rpm']}={sc.initial_speed_rpm!r}")
    return sets


def firmware_sets(sc: Scenario, values: Mapping[str, Any]) -> list[str]:
    """The firmware's ``name=value`` parameters (fw_host ``--set``): the hardware from the
    profile values, then the scenario's own."""
    sets = [f"{k}={_fmt_value(v)}" for k, v in firmware_settings(values).items()]
    return sets + [f"{k}={_fmt_value(v)}" for k, v in sc.firmware.items()]


def build_argv(
    sc: Scenario, transport: str, channel: str, out: Path, realtime: bool,
    opts: RunOptions,
) -> tuple[list[str], list[str], dict[str, Any]]:
    plant = str(_paths.binary("plant_rt"))
    fw = str(_paths.binary("fw_host"))
    pacing = "--realtime" if realtime else "--lockstep"
    common = ["--bus", transport, "--channel", channel, pacing]
    profile_path, values = profile_values(sc)
    plant_argv = [plant, *common, "--trace", str(out / "plant.trace"),
                  "--ready-file", str(out / "plant.ready")]
    # the file the rig read (pole pairs, ADC scaling for the firmware) is the one the plant uses
    plant_argv += ["--config", str(profile_path)] if profile_path else ["--profile", sc.profile]
    for assignment in plant_sets(sc):
        plant_argv += ["--set", assignment]
    plant_argv += list(opts.extra_plant_args)
    fw_argv = [fw, *common, "--trace", str(out / "fw.trace"),
               "--ready-file", str(out / "fw.ready")]
    if not realtime:
        # paired from the start: the plant's first ADC frame is its start-up period 0, so
        # stray frames on the channel cannot become the firmware's first period
        fw_argv += ["--first-period", "0"]
    for assignment in firmware_sets(sc, values):
        fw_argv += ["--set", assignment]
    fw_argv += list(opts.extra_fw_args)
    return plant_argv, fw_argv, values


def _sha(path: str) -> str:
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return "unavailable"
    return h.hexdigest()[:16]


def versions(plant: str | None = None, fw: str | None = None) -> dict[str, str]:
    out = {"rig": __version__, "python": platform.python_version()}
    for dist in ("numpy", "cantools", "python-can", "rerun-sdk"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    for db in protocols.DATABASES:
        out[f"dbc.{db}"] = str(protocols.database(db).version)
    if plant:
        out["plant_rt.sha256"] = _sha(plant)
    if fw:
        out["fw_host.sha256"] = _sha(fw)
    return out


class _Clock:
    def __init__(self) -> None:
        self.t0 = time.monotonic()
        self.grants: list[tuple[int, float, float]] = []  # (run_until, wall_s, grant wall)
        self.cpu_s: float | None = None  # in-process runs: CPU time of the closed loop

    def wall(self) -> float:
        return time.monotonic() - self.t0


def _recv_until(
    bus: can.BusABC, mon: Monitor, sup: Supervisor, deadline: float, done: Callable[[], bool],
    tick: Callable[[], None] | None = None,
) -> None:
    """Receives and handles frames (watching the children) until done() or the deadline."""
    while not done():
        sup.check()
        left = deadline - time.monotonic()
        if left <= 0:
            return
        msg = bus.recv(timeout=min(RECV_SLICE_S, left))
        while msg is not None:
            mon.handle(msg)
            if done():
                break
            msg = bus.recv(timeout=0)
        if tick is not None:
            tick()


def initial_drive(sc: Scenario) -> DriveState:
    """The drive command before the scenario's first event."""
    return DriveState(ctrl_mode=sc.ctrl_mode, fw_mode=sc.fw_mode, iq_ref=sc.iq_ref,
                      i_max=sc.i_max, speed_max=sc.speed_max, accel=_step_accel())


def send_grant_frames(cmd: Commander, plan: Plan, start: int, drive: DriveState,
                      load: LoadState) -> None:
    """What goes out before the grant that starts at ``start`` (lockstep, bus and in process
    alike): frames the rig held back that are due, its commands, the fault commands."""
    cmd.at(start)
    cmd.drive(drive)
    cmd.load(load)
    for values in plan.fault_cmds.get(start, []):
        cmd.fault(values)


def execute_inproc(sc: Scenario, plan: Plan, bench: sil.SilBench, cmd: Commander,
                   prog: Progress, clock: _Clock, deadline: float) -> int:
    """The lockstep grants on the in-process bench: the same frames before each grant, then
    the bench runs to the grant's end. Returns the number of periods simulated."""
    drive = initial_drive(sc)
    load = LoadState()
    for start, until in plan.grants():
        for fn in plan.drive_events.get(start, []):
            fn(drive)
        if start in plan.load_events:
            load = plan.load_events[start]
        t_grant = time.monotonic()
        send_grant_frames(cmd, plan, start, drive, load)
        try:
            bench.run_until(until)
        except sil.BenchError as exc:
            raise RunError("stall", str(exc)) from exc
        clock.grants.append((until, clock.wall(), time.monotonic() - t_grant))
        prog.update(until * TS, None, None)
        if time.monotonic() > deadline:
            raise RunError("timeout", f"run time-out at period {until}")
    return plan.n_periods


def execute_lockstep(
    sc: Scenario, plan: Plan, bus: can.BusABC, sup: Supervisor, mon: Monitor,
    cmd: Commander, prog: Progress, clock: _Clock, deadline: float, stall_s: float = STALL_S,
) -> int:
    """Runs every grant; returns the number of periods simulated."""
    drive = initial_drive(sc)
    load = LoadState()
    for start, until in plan.grants():
        for fn in plan.drive_events.get(start, []):
            fn(drive)
        if start in plan.load_events:
            load = plan.load_events[start]
        t_grant = time.monotonic()
        send_grant_frames(cmd, plan, start, drive, load)
        cmd.step(until)
        last_change = time.monotonic()
        last_period = mon.progress_period
        last_resend = last_change

        def done(target: int = until) -> bool:
            return mon.progress_period is not None and mon.progress_period >= target

        def tick() -> None:
            speed, err = mon.snapshot()
            sim = (mon.progress_period or 0) * TS
            prog.update(sim, speed, err)
            if live := mon.live:
                live.flush()

        while not done():
            if time.monotonic() > deadline:
                raise RunError("timeout", f"run time-out at period {mon.progress_period} "
                               f"(grant to {until})")
            _recv_until(bus, mon, sup, min(deadline, time.monotonic() + RECV_SLICE_S * 4),
                        done, tick)
            if done():
                break
            now = time.monotonic()
            if mon.progress_period != last_period:
                last_period = mon.progress_period
                last_change = now
            waiting = mon.latest.get("BENCH_PROGRESS", {}).get("state") == 0.0
            if (now - last_change > PROGRESS_RESEND_S and now - last_resend > PROGRESS_RESEND_S
                    and (waiting or mon.progress_frames == 0)):
                # the plant waits for a grant it should have: the frame was lost, send the
                # grant's frames again, byte for byte
                cmd.resend()
                mon.grant_resends += 1
                last_resend = now
            if now - last_change > stall_s:
                raise RunError(
                    "stall",
                    f"lockstep stalled: plant at period {mon.progress_period}, granted {until}, "
                    f"no progress for {stall_s:g} s",
                )
        clock.grants.append((until, clock.wall(), time.monotonic() - t_grant))
        tick()
    return plan.n_periods


def execute_realtime(
    sc: Scenario, plan: Plan, bus: can.BusABC, sup: Supervisor, mon: Monitor,
    cmd: Commander, prog: Progress, clock: _Clock, deadline: float, stall_s: float = STALL_S,
) -> int:
    """Sends the plan's commands on the wall clock; returns the last period commanded."""
    drive = initial_drive(sc)
    load = LoadState()
    events = sorted(set(plan.drive_events) | set(plan.load_events) | set(plan.fault_cmds))
    t_origin = time.monotonic()

    def period_now() -> float:
        if mon.progress_period is not None:
            return mon.progress_period + (time.monotonic() - mon.progress_wall) / TS
        return (time.monotonic() - t_origin) / TS

    cmd.drive(drive)
    cmd.load(load)
    next_cmd = time.monotonic() + CMD_PERIOD_S
    last_period, last_change = mon.progress_period, time.monotonic()
    i = 0
    # the plant's own report ends the run (an estimate could run ahead of a lagging plant)
    while (mon.progress_period or 0) < plan.n_periods:
        if time.monotonic() > deadline:
            raise RunError("timeout", "real-time run time-out")
        now_p = period_now()
        cmd.at(int(now_p))
        changed_drive = changed_load = False
        fault_now: list[dict[str, float | int]] = []
        while i < len(events) and events[i] <= now_p:
            p = events[i]
            for fn in plan.drive_events.get(p, []):
                fn(drive)
                changed_drive = True
            if p in plan.load_events:
                load = plan.load_events[p]
                changed_load = True
            fault_now += plan.fault_cmds.get(p, [])
            i += 1
        for values in fault_now:
            cmd.fault(values)
        if changed_drive:
            cmd.drive(drive)
            next_cmd = time.monotonic() + CMD_PERIOD_S
        if changed_load:
            cmd.load(load)
        if time.monotonic() >= next_cmd:
            cmd.drive_cmd_only(drive)
            next_cmd += CMD_PERIOD_S
        until = time.monotonic() + min(CMD_PERIOD_S, 0.002)
        _recv_until(bus, mon, sup, until, lambda: False)
        if mon.progress_period != last_period:
            last_period, last_change = mon.progress_period, time.monotonic()
        elif time.monotonic() - last_change > stall_s:
            raise RunError("stall", f"real-time plant stopped reporting progress at period "
                           f"{mon.progress_period} for {stall_s:g} s")
        speed, err = mon.snapshot()
        prog.update(period_now() * TS, speed, err)
        if mon.live is not None:
            mon.live.flush()
    return plan.n_periods


KEEP_CHOICES = ("failing", "all")
FULL_RATE_FILES = ("plant.trace", "fw.trace", "capture")


def _prune(out: Path, *, keep_full: bool, keep: str) -> dict[str, Any]:
    """Removes the full-rate traces and capture columns of a run that need not keep them;
    returns what was kept and removed (for result.json)."""
    present = [name for name in FULL_RATE_FILES if (out / name).exists()]
    if keep_full:
        return {"full_rate": bool(present), "policy": keep, "removed": [], "removed_bytes": 0}
    removed_bytes = 0
    for name in present:
        target = out / name
        if target.is_dir():
            removed_bytes += _dir_size(target)
            shutil.rmtree(target)
        else:
            removed_bytes += target.stat().st_size
            target.unlink()
    return {"full_rate": False, "policy": keep, "removed": present,
            "removed_bytes": removed_bytes,
            "note": "passed: full-rate traces and capture removed (rig run --keep-all keeps them)"}


def _dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else 0


FOREIGN_LISTEN_S = 0.25  # how long the rig listens for other traffic before it starts


def _refuse_foreign_nodes(bus: can.BusABC, transport: str, channel: str) -> None:
    """Nobody else may be on the channel: a second run there paces or answers ours (a 180°
    error, 300 000 periods of capture loss). unixcan: no other live socket in the channel
    folder; both transports: no frame within FOREIGN_LISTEN_S."""
    if transport == "unixcan":
        from rig.bus import unixcan

        own = {str(getattr(bus, "socket_path", ""))}
        others = unixcan.live_nodes(channel, own)
        if others:
            pids = sorted({Path(p).name.split("-", 1)[0] for p in others})
            raise EnvironmentProblem(
                f"unixcan channel {channel!r} is in use: {len(others)} other node(s) in "
                f"{unixcan.base_dir() / channel} (pids {', '.join(pids[:8])}"
                f"{', ...' if len(pids) > 8 else ''}); another run on this channel? Use "
                "--channel NAME (a unixcan node reaches at most HILBUS_MAX_PEERS others, hilbus.h)")
    deadline = time.monotonic() + FOREIGN_LISTEN_S
    while (left := deadline - time.monotonic()) > 0:
        msg = bus.recv(timeout=left)
        if msg is not None and not msg.is_error_frame:
            raise EnvironmentProblem(
                f"{transport} channel {channel!r} is in use: a frame 0x{msg.arbitration_id:03X} "
                "arrived before the run started (another run or node on this channel?); use "
                "--channel NAME")


def run_scenario(sc: Scenario, opts: RunOptions) -> RunResult:
    """Runs one scenario into ``opts.out``; always writes result.json and report.md."""
    out = Path(opts.out)
    # before anything starts: a folder that cannot take the results is exit 3, not a
    # traceback or a truncated result.json at the end (output.OutputError)
    output.prepare(out, round(sc.duration / TS))
    if out.exists():
        for name in ("capture", "recording.rrd", "result.json", "report.md", "plant.trace",
                     "fw.trace"):
            target = out / name
            if target.is_dir():
                shutil.rmtree(target)
            else:
                target.unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(OSError):
        shutil.copyfile(sc.file, out / "scenario.toml")
    realtime = opts.realtime
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    result: dict[str, Any] = {
        "schema": "hil-result/1",
        "scenario": sc.name,
        "scenario_file": str(sc.file),
        "description": sc.description,
        "figure": sc.figure,
        "profile": sc.profile,
        "overrides": dict(sc.overrides),
        "firmware_params": dict(sc.firmware),
        "faults": [f.to_json() for f in sc.faults],
        "ctrl_mode": sc.ctrl_mode,
        "fw_mode": sc.fw_mode,
        "mode": "realtime" if realtime else "lockstep",
        "bus": None,
        "channel": None,
        "out_dir": str(out),
        "started": started,
        "status": "error",
        "passed": False,
        "failure": None,
        "criteria": [],
        "counters": {},
        "capture": None,
        "recording": None,
        "timing": {"sim_s": sc.duration},
        "versions": {},
    }
    cap: capture.Capture | None = None
    clock = _Clock()
    plan = Plan.build(sc)
    counters: dict[str, float] = {}
    interrupted: BaseException | None = None
    failure: dict[str, Any] | None = None
    mon: Monitor | None = None
    stops: dict[str, StopReport] = {}
    periods_done = 0
    live: recording.LiveView | None = None
    try:
        if opts.bus == sil.INPROC:
            periods_done = _run_inproc(sc, plan, out, opts, result, clock, counters)
        else:
            try:
                from rig import bus as rigbus

                transport, channel = rigbus.select_transport(opts.bus, opts.channel)
                plant_argv, fw_argv, _values = build_argv(sc, transport, channel, out, realtime,
                                                          opts)
            except FileNotFoundError as exc:
                raise EnvironmentProblem(str(exc)) from exc
            result.update(bus=transport, channel=channel)
            result["versions"] = versions(plant_argv[0], fw_argv[0])
            result["command_lines"] = {"plant": plant_argv, "firmware": fw_argv}
            try:
                bus = rigbus.open_bus(transport, channel, can_filters=listen_filters())
            except (can.CanError, OSError, ValueError) as exc:
                raise EnvironmentProblem(f"cannot open {transport} bus {channel!r}: {exc}") from exc
            _refuse_foreign_nodes(bus, transport, channel)
            if opts.live:
                try:
                    stream = opts.live_stream or recording.spawn_live(f"{sc.name} (live)",
                                                                      opts.live_url)
                    live = recording.LiveView(stream)
                except Exception as exc:  # no display, no viewer binary: run without live view
                    print(f"rig: live view unavailable ({exc}); running without it",
                          file=sys.stderr)
            mon = Monitor(live)
            # the bus reader thread (unixcan) must get the GIL within a sender's patience (2 ms)
            switch = sys.getswitchinterval()
            sys.setswitchinterval(min(switch, 0.0005))
            env = {"HIL_BUS": transport, "HIL_CHANNEL": channel, **opts.env}
            prog = Progress(sc.name, sc.duration, enabled=opts.progress)
            timeout = opts.timeout_s or sc.timeout_s or (
                sc.duration + 30.0 if realtime else 60.0 + 300.0 * sc.duration
            )
            try:
                with Supervisor(out, grace_s=opts.grace_s) as sup:
                    sup.start("plant_rt", plant_argv, ready_file=out / "plant.ready", env=env)
                    sup.start("fw_host", fw_argv, ready_file=out / "fw.ready", env=env)
                    sup.wait_ready(sc.ready_timeout_s)
                    clock.t0 = time.monotonic()
                    deadline = clock.t0 + timeout
                    cmd = Commander(bus, drive_link.DriveLink(plan.link_windows))
                    runner = execute_realtime if realtime else execute_lockstep
                    grace = opts.grace_s
                    try:
                        periods_done = runner(sc, plan, bus, sup, mon, cmd, prog, clock, deadline,
                                              opts.stall_s)
                        if not realtime:
                            # let the firmware finish the last period before the stop signal
                            sup.sleep(0.05)
                    except BaseException:
                        grace = min(grace, 1.0)  # failing: end quickly
                        raise
                    finally:
                        prog.finish()
                        stops = sup.stop(grace_s=grace)
                    counters["rig.tx_frames"] = float(cmd.tx)
                    counters.update(cmd.link.counters())
            finally:
                sys.setswitchinterval(switch)
                bus.shutdown()
                stats = getattr(bus, "stats", None)
                if isinstance(stats, Mapping):
                    _flatten("rig.bus", stats, counters)
    except ChildFailed as exc:
        failure = {"kind": "crash", "message": f"{exc.name}: {exc.what}",
                   "log_tail": exc.log_tail, "child": exc.name}
    except RunError as exc:
        failure = {"kind": exc.kind, "message": str(exc), "log_tail": exc.log_tail}
    except EnvironmentProblem as exc:
        failure = {"kind": "environment", "message": str(exc), "log_tail": ""}
    except (KeyboardInterrupt, Terminated) as exc:
        interrupted = exc
        failure = {"kind": "interrupted", "message": f"interrupted ({type(exc).__name__})",
                   "log_tail": ""}
    wall = clock.wall()
    if failure is None and not stops and opts.bus != sil.INPROC:
        failure = {"kind": "error", "message": "run ended without stopping its programs",
                   "log_tail": ""}
    # a program that did not stop cleanly is a failure too (after a good run)
    for rep in stops.values():
        if rep.counters:
            _flatten("plant" if rep.name == "plant_rt" else "firmware", rep.counters, counters)
        if failure is None and not rep.clean:
            what = ("did not stop within the grace period (killed)" if rep.killed
                    else f"stopped with exit status {rep.returncode}")
            failure = {"kind": "crash", "message": f"{rep.name}: {what}",
                       "log_tail": rep.log_tail, "child": rep.name}
    beyond = max(counters.get("plant.peers_beyond_limit", 0.0),
                 counters.get("firmware.peers_beyond_limit", 0.0))
    if failure is None and beyond > 0:
        failure = {"kind": "environment", "log_tail": "",
                   "message": f"{beyond:g} node(s) on the channel beyond the HILBUS_MAX_PEERS "
                   "(hilbus.h) a unixcan node reaches: frames were not delivered"}
    resyncs = counters.get("firmware.resyncs", 0.0)
    if failure is None and resyncs > 0:
        # the firmware followed an ADC sequence that restarted at period 0: another plant
        # on the channel, or ours restarted; the data after it is not this run's
        failure = {"kind": "lockstep", "log_tail": "",
                   "message": f"fw_host followed a restarted ADC sequence {resyncs:g} time(s) "
                   "(another plant on the channel?)"}
    if mon is not None:
        counters.update(mon.counters())
        counters["rig.grants"] = float(len(clock.grants))
        counters["rig.rx_frames"] = float(mon.rx)
        counters["rig.drive_faults"] = float(mon.faults)
        counters["rig.grant_resends"] = float(mon.grant_resends)
    if live is not None:
        with contextlib.suppress(Exception):
            live.close()

    # merge the traces
    plant_trace, fw_trace = out / "plant.trace", out / "fw.trace"
    traces_exist = plant_trace.exists() and fw_trace.exists()
    small = traces_exist and (
        plant_trace.stat().st_size + fw_trace.stat().st_size
        < MAX_POST_FAILURE_PERIODS * 3 * 72
    )
    loss: capture.LossReport | None = None
    if traces_exist and (failure is None or small) and interrupted is None:
        try:
            # lockstep: exactly the granted periods. Real time: the plant runs from its
            # start, before the firmware is on the bus; the overlap counts, and it must reach
            # the end of the scenario.
            expected = (0, periods_done - 1) if failure is None and not realtime else None
            cap, loss = capture.build(
                out / "capture", capture.default_specs(plant_trace, fw_trace),
                expected=expected, pole_pairs=profiles.pole_pairs(profile_values(sc)[1]),
                speed_reference=lambda t: sc.speed_reference(t, accel_step_limit()),
                # memory per period is bounded by what the run can have produced: the
                # scenario's periods and a minute (real time starts before the firmware)
                max_span=plan.n_periods + int(60.0 / TS),
            )
        except (ValueError, OSError) as exc:
            if failure is None:
                failure = {"kind": "capture", "message": f"cannot read the traces: {exc}",
                           "log_tail": ""}
    elif failure is None:
        failure = {"kind": "capture", "message": "trace files missing "
                   f"({plant_trace.name}: {plant_trace.exists()}, "
                   f"{fw_trace.name}: {fw_trace.exists()})", "log_tail": ""}
    if loss is not None:
        counters["capture.lost"] = float(loss.lost)
        counters["capture.duplicates"] = float(loss.duplicates)
        result["capture"] = {**loss.to_json(), "summary": loss.summary()}
        if failure is None and not loss.ok:
            failure = {"kind": "capture_loss", "message": loss.summary(), "log_tail": ""}
        elif failure is None and realtime and loss.last_period < periods_done - 2:
            failure = {"kind": "capture_loss", "log_tail": "",
                       "message": f"the capture ends at period {loss.last_period}, before the "
                       f"end of the scenario ({periods_done - 1})"}

    result["counters"] = counters
    coverage = _coverage(plan, cap, loss, periods_done, realtime, interrupted, failure)
    reads: list[tuple[str, int, int]] = []
    crit_results = [evaluate_one(cr, cap, counters, coverage, reads) for cr in sc.criteria]
    result["criteria"] = crit_results
    all_ok = all(outcome(c) not in AGAINST for c in crit_results)
    if failure is None:
        result["status"] = "passed" if all_ok else "failed"
        result["passed"] = all_ok
    else:
        result["status"] = "interrupted" if failure["kind"] == "interrupted" else (
            "error" if failure["kind"] == "environment" else "failed")
        result["passed"] = False
    result["failure"] = failure
    reached = periods_done or (mon.progress_period if mon is not None else 0) or 0
    sim_s = reached * TS
    grant_walls = [g[2] for g in clock.grants]
    result["timing"] = {
        "sim_s": sim_s,
        "wall_s": wall,
        "speed_x": sim_s / wall if wall > 0 and sim_s > 0 else None,
        "grants": len(clock.grants),
        "grant_wall_ms_mean": 1e3 * float(np.mean(grant_walls)) if grant_walls else None,
        "grant_wall_ms_max": 1e3 * float(np.max(grant_walls)) if grant_walls else None,
    }
    if clock.cpu_s:
        result["timing"]["cpu_s"] = clock.cpu_s
        result["timing"]["speed_x_cpu"] = sim_s / clock.cpu_s if sim_s > 0 else None
    result["finished"] = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")

    # recording
    rrd = out / "recording.rrd"
    if cap is not None and cap.n and opts.record:
        try:
            timing = None
            if clock.grants:
                g = np.asarray(clock.grants, dtype=np.float64)
                walls = np.diff(np.concatenate([[0.0], g[:, 1]]))
                sims = np.diff(np.concatenate([[0.0], g[:, 0]])) * TS
                timing = recording.TimedSamples(
                    [int(x) for x in g[:, 0]],
                    {"grant_wall_ms": list(g[:, 2] * 1e3),
                     "speed_x": list(np.where(walls > 0, sims / np.maximum(walls, 1e-12), 0.0))},
                )
            cl = mon.counter_log if mon is not None else []
            counter_samples = None
            if cl:
                keys = sorted({k for _, v in cl for k in v if k != "period"})
                counter_samples = recording.TimedSamples(
                    [p for p, _ in cl], {k: [v.get(k, math.nan) for _, v in cl] for k in keys})
            info = recording.write(
                rrd, cap, title=f"{sc.name} ({result['mode']}, {result['bus']})",
                report_markdown=report.scenario_report(result), timing=timing,
                counters=counter_samples, evidence=recording.evidence_ranges(reads),
            )
            size = rrd.stat().st_size
            result["recording"] = {
                "path": rrd.name, "bytes": size,
                "bytes_per_sim_s": size / (cap.n * TS) if cap.n else None,
                "display_step": info["display_step"],
                "evidence_rows": info["evidence_rows"], "evidence": info["evidence"],
                "capture_bytes": _dir_size(out / "capture"),
            }
        except Exception as exc:  # the verdict stands without the recording
            result["recording"] = {"path": None, "error": f"{type(exc).__name__}: {exc}"}
    result["kept"] = _prune(out, keep_full=opts.keep == "all" or not result["passed"],
                            keep=opts.keep)
    if not result["kept"]["full_rate"]:
        cap = None
    output.write_text(out / "result.json", json.dumps(result, indent=1, default=_json_default))
    output.write_text(out / "report.md", report.scenario_report(result))
    res = RunResult(out, result, cap)
    if interrupted is not None:
        raise interrupted
    return res


def _coverage(plan: Plan, cap: capture.Capture | None, loss: capture.LossReport | None,
              periods_done: int, realtime: bool, interrupted: BaseException | None,
              failure: Mapping[str, Any] | None) -> Coverage:
    """What data the run produced, for the verdicts (rig.verdict): the periods the capture
    holds without a hole and whether the run reached its planned end."""
    reached = interrupted is None and periods_done >= plan.n_periods
    why = "" if failure is None else f"{failure['kind']}: {str(failure['message'])[:200]}"
    # a hole (missing, duplicate, stray or short records) could be anywhere; a partial
    # record at the end of a trace is where a killed writer stopped: the range holds before it
    holes = loss is None or not all(m.ok for m in loss.messages)
    if cap is None or loss is None or holes or cap.n == 0:
        if loss is not None and holes:
            why = why or loss.summary()
        return Coverage(plan.n_periods, None, None, reached, why or "no capture")
    first, last = cap.first_period, cap.first_period + cap.n - 1
    if reached and loss.ok and not realtime:
        last = plan.n_periods - 1  # complete by the loss report (the firmware's last ISR)
    return Coverage(plan.n_periods, first, last, reached, why)


def _run_inproc(sc: Scenario, plan: Plan, out: Path, opts: RunOptions, result: dict[str, Any],
                clock: _Clock, counters: dict[str, float]) -> int:
    """The run on the in-process bench: the plant_rt/fw_host configuration of ``build_argv``
    handed to the bench, the lockstep grants, the programs' counters from the bench."""
    if opts.realtime:
        raise RunError("usage", "--realtime needs the bus: the in-process bench runs in "
                       "lockstep only")
    try:
        lib = _paths.library(sil.LIBRARY)
        profile_path, values = profile_values(sc)
    except FileNotFoundError as exc:
        raise EnvironmentProblem(str(exc)) from exc
    psets, fsets = plant_sets(sc), firmware_sets(sc, values)
    result.update(bus=sil.INPROC, channel=None)
    result["versions"] = {**versions(), "silbench.sha256": _sha(str(lib))}
    result["command_lines"] = {"bench": {
        "library": str(lib), "profile": str(profile_path) if profile_path else sc.profile,
        "plant_sets": psets, "fw_sets": fsets}}
    if profile_path is None:
        raise EnvironmentProblem(f"profile {sc.profile!r} not found")
    if opts.live:
        print("rig: no live view on the in-process bench (no telemetry frames); running "
              "without it", file=sys.stderr)
    prog = Progress(sc.name, sc.duration, enabled=opts.progress)
    timeout = opts.timeout_s or sc.timeout_s or 60.0 + 300.0 * sc.duration
    try:
        bench = sil.SilBench(profile_path, psets, fsets, out / "plant.trace", out / "fw.trace")
    except sil.BenchError as exc:
        raise RunError("config", f"in-process bench: {exc}") from exc
    try:
        clock.t0 = time.monotonic()
        cmd = Commander(sil.BenchPort(bench), drive_link.DriveLink(plan.link_windows))
        cpu0 = time.process_time()
        try:
            periods = execute_inproc(sc, plan, bench, cmd, prog, clock, clock.t0 + timeout)
            clock.cpu_s = time.process_time() - cpu0
        finally:
            prog.finish()
            bench_counters = bench.counters()
            for name in ("plant", "firmware"):
                _flatten(name, bench_counters.get(name, {}), counters)
            counters["rig.tx_frames"] = float(cmd.tx)
            counters.update(cmd.link.counters())
            counters["rig.bench_rejected"] = float(len(bench.rejected))
            port = cmd.bus
            if isinstance(port, sil.BenchPort):
                counters["rig.bench_refused_faulted"] = float(len(port.refused_faulted))
    finally:
        try:
            bench.close()
        except sil.BenchError as exc:
            raise RunError("capture", f"in-process bench: {exc}") from exc
    if bench.rejected:
        raise RunError("rejected", "the bench rejected frames of the rig: "
                       + "; ".join(bench.rejected[:3]))
    return periods


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def run_suite(suite: Suite, opts: RunOptions) -> SuiteResult:
    out = Path(opts.out)
    # (each scenario checks its own room again before it starts)
    output.prepare(out, max((round(sc.duration / TS) for sc in suite.scenarios), default=0))
    results: list[RunResult] = []
    entries: list[dict[str, Any]] = []
    summary: dict[str, Any] = {
        "schema": "hil-suite/1", "suite": suite.name, "suite_file": str(suite.file),
        "description": suite.description, "passed": False, "scenarios": entries,
    }
    interrupted: BaseException | None = None
    try:
        for sc in suite.scenarios:
            sub = RunOptions(**{**opts.__dict__, "out": out / sc.name})
            r = run_scenario(sc, sub)
            results.append(r)
            entries.append({
                "name": sc.name, "dir": sc.name, "passed": r.passed, "status": r.status,
                "failed_criteria": [c["name"] for c in r.failed_criteria()],
                "failure": (r.data.get("failure") or {}).get("message"),
                "wall_s": r.data.get("timing", {}).get("wall_s"),
                "profile": sc.profile, "figure": sc.figure, "tags": list(sc.tags),
                "description": sc.description,
                "criteria": [
                    {k: c.get(k) for k in ("name", "metric", "window", "value", "limit",
                                           "comparison", "unit", "outcome", "xfail", "note")}
                    for c in r.criteria
                ],
                "recording": (r.data.get("recording") or {}).get("path"),
            })
    except (KeyboardInterrupt, Terminated) as exc:
        interrupted = exc
    summary["comparisons"] = [evaluate_comparison(cmp, entries) for cmp in suite.comparisons]
    summary["passed"] = (
        interrupted is None and len(results) == len(suite.scenarios)
        and all(r.passed for r in results)
        and all(c["outcome"] in ("pass", "xfail") for c in summary["comparisons"])
    )
    summary["complete"] = len(results) == len(suite.scenarios)
    output.write_text(out / "result.json", json.dumps(summary, indent=1, default=_json_default))
    output.write_text(out / "report.md", report.suite_report(summary))
    if interrupted is not None:
        raise interrupted
    return SuiteResult(out, summary, results)


def evaluate_comparison(cmp: Comparison,
                        entries: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """A suite comparison on the criterion values recorded in the entries of two runs. A run
    that is missing (interrupted suite) or whose criterion was not evaluated leaves the
    comparison not evaluated; a criterion without a value fails it."""

    def criterion(run: str) -> Mapping[str, Any] | None:
        return next((c for e in entries if e["name"] == run
                     for c in e.get("criteria") or [] if c.get("name") == cmp.criterion), None)

    ca, cb = criterion(cmp.a), criterion(cmp.b)
    a = ca.get("value") if ca is not None else None
    b = cb.get("value") if cb is not None else None
    passed = a is not None and b is not None and metrics.compare(a, cmp.relation, b)
    missing = [run for run, c in ((cmp.a, ca), (cmp.b, cb))
               if c is None or outcome(c) == NOT_EVALUATED]
    return {
        "name": cmp.name, "criterion": cmp.criterion, "a": cmp.a, "b": cmp.b,
        "relation": cmp.relation, "value_a": a, "value_b": b,
        "unit": (ca or cb or {}).get("unit") or "", "passed": passed,
        "outcome": NOT_EVALUATED if missing else outcome_of(passed, cmp.xfail),
        "xfail": cmp.xfail,
        "note": f"not evaluated: no value from {', '.join(missing)}" if missing else "",
    }


def exit_code(passed: bool, status: str) -> int:
    if passed:
        return EXIT_PASS
    if status == "error":
        return EXIT_ENV
    return EXIT_FAIL


def default_out(name: str) -> Path:
    """``$HIL_OUT`` (else ``./out``) / ``<name>-<YYYYmmdd-HHMMSS>`` (``rig.outdirs``)."""
    return outdirs.default_out(name)
