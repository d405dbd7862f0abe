"""What a run produced: the content of ``result.json`` as a typed object, the capture it
kept, and the questions tests ask of them (``criterion``, ``metric``, ``explain``).

``to_json`` gives ``result.json`` (schema ``hil-result/1``, the keys in their order);
``RunResult.load`` reads a run folder back. A criterion stays the mapping ``rig.results.verdict``
writes (``name``, ``metric``, ``window``, ``value``, ``limit``, ``outcome``, ...).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, TypeVar

from rig import outputs
from rig.data import capture, metrics
from rig.outputs import Kept
from rig.results import report
from rig.results.verdict import AGAINST, outcome
from rig.scenario import Scenario

SCHEMA = "hil-result/1"
Criterion = dict[str, Any]


T = TypeVar("T")


def _from_json(cls: type[T], d: dict[str, Any] | None) -> T | None:
    """A section of result.json as its dataclass (None when absent; unknown keys ignored)."""
    if not d:
        return None
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    return cls(**{k: v for k, v in d.items() if k in names})


@dataclass(frozen=True)
class Failure:
    """Why a run failed besides its criteria: ``kind`` (crash, stall, timeout, capture,
    capture_loss, lockstep, environment, interrupted, ...), what happened, the log's tail
    and, for a crash, the program."""

    kind: str
    message: str
    log_tail: str = ""
    child: str | None = None

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        if self.child is None:
            del out["child"]
        return out


@dataclass(frozen=True)
class Timing:
    """Simulated and wall time of a run; the grants of a lockstep run; CPU time in process."""

    sim_s: float
    wall_s: float | None = None
    speed_x: float | None = None
    grants: int | None = None
    grant_wall_ms_mean: float | None = None
    grant_wall_ms_max: float | None = None
    cpu_s: float | None = None
    speed_x_cpu: float | None = None

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        if self.cpu_s is None:  # on the bus: the programs' CPU time is not the rig's
            del out["cpu_s"], out["speed_x_cpu"]
        return out


@dataclass
class RunResult:
    """One scenario run; ``capture`` holds its full-rate columns while the run keeps them."""

    out_dir: Path
    scenario: str = ""
    scenario_file: str = ""
    description: str = ""
    figure: str = ""
    profile: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    firmware_params: dict[str, Any] = field(default_factory=dict)
    faults: list[dict[str, Any]] = field(default_factory=list)
    ctrl_mode: str = ""
    fw_mode: str = ""
    mode: str = "lockstep"  # lockstep | realtime
    bus: str | None = None  # the transport, or inproc
    channel: str | None = None
    started: str = ""
    status: str = "error"  # passed | failed | error | interrupted
    passed: bool = False
    failure: Failure | None = None
    criteria: list[Criterion] = field(default_factory=list)
    counters: dict[str, float] = field(default_factory=dict)
    capture_loss: dict[str, Any] | None = None  # result.json's "capture": the loss report
    recording: dict[str, Any] | None = None
    timing: Timing | None = None
    versions: dict[str, str] = field(default_factory=dict)
    command_lines: dict[str, Any] | None = None  # the programs' (or the bench's) settings
    finished: str = ""
    kept: Kept | None = None
    # the comparison with the baseline (rig.regression.baseline)
    baseline: dict[str, Any] | None = None
    seeds: list[dict[str, Any]] | None = None  # a run over the scenario's own seeds: each one
    figures: dict[str, Any] | None = None  # rig.results.figures: the pictures in the run folder
    # criteria of the scenario this run does not judge, each with why (the ISR's cost on the
    # target, measured on the in-process bench only, on a run on a bus)
    left_out: list[dict[str, str]] | None = None
    # unixcan: the other nodes on the channel and what each missed, the lockstep's waits, the
    # rig's own live log of the bus (rig.run.bus_report)
    bus_report: dict[str, Any] | None = None
    # the ISR's cost counted on a target whose outputs were not the host's to the bit but on
    # its path (rig.target_m4.cost): how they differed ("" when identical or not measured)
    isr_cost_differs: str = ""
    capture: capture.Capture | None = field(default=None, compare=False, repr=False)

    @classmethod
    def of_scenario(cls, sc: Scenario, out_dir: Path, **given: Any) -> RunResult:
        """The result of a run of ``sc`` (into ``out_dir``), named as the scenario names it."""
        return cls(
            out_dir=out_dir, scenario=sc.name, scenario_file=str(sc.file),
            description=sc.description, figure=sc.figure, profile=sc.profile,
            overrides=dict(sc.overrides), firmware_params=dict(sc.firmware),
            faults=[f.to_json() for f in sc.faults], ctrl_mode=sc.ctrl_mode, fw_mode=sc.fw_mode,
            **given)

    # -- result.json ---------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "schema": SCHEMA, "scenario": self.scenario, "scenario_file": self.scenario_file,
            "description": self.description, "figure": self.figure, "profile": self.profile,
            "overrides": dict(self.overrides), "firmware_params": dict(self.firmware_params),
            "faults": list(self.faults), "ctrl_mode": self.ctrl_mode, "fw_mode": self.fw_mode,
            "mode": self.mode, "bus": self.bus, "channel": self.channel,
            "out_dir": str(self.out_dir), "started": self.started, "status": self.status,
            "passed": self.passed,
            "failure": self.failure.to_json() if self.failure is not None else None,
            "criteria": list(self.criteria), "counters": dict(self.counters),
            "capture": self.capture_loss, "recording": self.recording,
            "timing": self.timing.to_json() if self.timing is not None else None,
            "versions": dict(self.versions),
        }
        if self.command_lines is not None:
            out["command_lines"] = self.command_lines
        out["finished"] = self.finished
        if self.kept is not None:
            out["kept"] = self.kept.to_json()
        if self.baseline is not None:
            out["baseline"] = self.baseline
        if self.seeds is not None:
            out["seeds"] = self.seeds
        if self.figures is not None:
            out["figures"] = self.figures
        if self.left_out:
            out["left_out"] = self.left_out
        if self.bus_report is not None:
            out["bus_report"] = self.bus_report
        if self.isr_cost_differs:
            out["isr_cost_differs"] = self.isr_cost_differs
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any], out_dir: Path,
                  cap: capture.Capture | None = None) -> RunResult:
        return cls(
            out_dir=out_dir, scenario=str(data.get("scenario", "")),
            scenario_file=str(data.get("scenario_file", "")),
            description=str(data.get("description", "")), figure=str(data.get("figure", "")),
            profile=str(data.get("profile", "")), overrides=dict(data.get("overrides") or {}),
            firmware_params=dict(data.get("firmware_params") or {}),
            faults=list(data.get("faults") or []), ctrl_mode=str(data.get("ctrl_mode", "")),
            fw_mode=str(data.get("fw_mode", "")), mode=str(data.get("mode", "lockstep")),
            bus=data.get("bus"), channel=data.get("channel"),
            started=str(data.get("started", "")), status=str(data.get("status")),
            passed=bool(data.get("passed")), failure=_from_json(Failure, data.get("failure")),
            criteria=list(data.get("criteria") or []),
            counters=dict(data.get("counters") or {}), capture_loss=data.get("capture"),
            recording=data.get("recording"), timing=_from_json(Timing, data.get("timing")),
            versions=dict(data.get("versions") or {}), command_lines=data.get("command_lines"),
            finished=str(data.get("finished", "")), kept=_from_json(Kept, data.get("kept")),
            baseline=data.get("baseline"), seeds=data.get("seeds"),
            figures=data.get("figures"), left_out=data.get("left_out"),
            bus_report=data.get("bus_report"),
            isr_cost_differs=str(data.get("isr_cost_differs") or ""), capture=cap,
        )

    @classmethod
    def load(cls, out_dir: str | Path) -> RunResult:
        """A run folder's result.json, with its capture when the run kept it."""
        d = Path(out_dir)
        data = json.loads((d / "result.json").read_text())
        cap = capture.Capture(d / "capture") if (d / "capture" / "meta.json").exists() else None
        return cls.from_json(data, d, cap)

    def __repr__(self) -> str:  # short: pytest shows it in a failed assertion
        return f"RunResult({self.scenario}: {self.status}, report {self.report_path})"

    @property
    def report_path(self) -> Path:
        return Path(self.out_dir) / "report.md"

    # -- questions -----------------------------------------------------------------------
    def failed_criteria(self) -> list[Criterion]:
        """Criteria that count against the run: failed or not evaluated (an XFAIL does not,
        an XPASS does not)."""
        return [c for c in self.criteria if outcome(c) in AGAINST]

    def expected_failures(self) -> list[Criterion]:
        return [c for c in self.criteria if outcome(c) in ("xfail", "xpass")]

    def criterion(self, name: str) -> Criterion:
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
                              counters=self.counters)

    def metric(self, name: str, window: tuple[float, float] | None = None,
               **params: float) -> float:
        """Any metric over any window of the capture (for custom assertions in tests)."""
        w = self.window(*(window or (0.0, None)))  # type: ignore[arg-type]
        return metrics.compute(name, w, params)

    def explain(self) -> str:
        """Why the run did not pass, as ``rig run --junit`` says it: the run's own verdict,
        then each criterion that failed, was not evaluated or moved against its baseline."""
        from rig.results import junit

        data = self.to_json()
        lines = [f"{self.scenario}: {self.status} (report: {self.report_path})"]
        run = junit.run_verdict(data)
        if run is not None:
            lines.append(f"  {run[2]}")
            if self.failure is not None and self.failure.log_tail:
                lines += ["    " + x for x in self.failure.log_tail.splitlines()[-15:]]
        file = (self.baseline or {}).get("file")
        for c in self.criteria:
            verdict = junit.criterion_verdict(c, file)
            if verdict is None or verdict[0] == "skipped":
                continue
            mark = "NOT EVALUATED" if verdict[0] == "error" else "FAIL"
            lines.append(f"  {mark} {c['name']}: {verdict[2]} ({junit.window_text(c)})")
        return "\n".join(lines)

    def assert_passed(self) -> None:
        if not self.passed:
            raise AssertionError(self.explain())


def write_result(result: RunResult) -> None:
    """result.json and report.md, each written whole or not at all."""
    data = result.to_json()
    outputs.write_text(result.out_dir / "result.json",
                       json.dumps(data, indent=1, default=outputs.json_default))
    outputs.write_text(result.out_dir / "report.md", report.scenario_report(data))
