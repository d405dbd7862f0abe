"""Runs commissioning steps on a bench and writes ``commissioning.json`` and
``commissioning.md`` into the run folder (with ``bus.log``, the recording, and on a virtual
bench the programs' logs).

Any way out of a step (a failed check, a time-out, a lost link, Ctrl-C, SIGTERM) stops the
run and goes through the session's safe stop before the programs stop and the report is
written; an interrupt is re-raised afterwards.
"""

from __future__ import annotations

import datetime as dt
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.bench.description import BenchDescription
from rig.commissioning import report
from rig.commissioning.results import StepResult
from rig.commissioning.session import BenchSession, ChannelRefused
from rig.commissioning.steps import ALL, STEPS
from rig.supervisor import Terminated, terminate_as_exception

RESULTS = "commissioning.json"
REPORT = "commissioning.md"


@dataclass
class CommissioningRun:
    run_dir: Path
    data: dict[str, Any]
    steps: list[StepResult] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return bool(self.data.get("passed"))

    def step(self, name: str) -> StepResult:
        for s in self.steps:
            if s.step == name:
                return s
        raise KeyError(name)

    def value(self, key: str) -> float:
        for s in self.steps:
            for q in s.quantities:
                if q.key == key:
                    return q.value
        raise KeyError(key)

    @property
    def report_path(self) -> Path:
        return self.run_dir / REPORT


def expand(names: Sequence[str]) -> list[str]:
    out: list[str] = []
    for n in names:
        for step in (ALL if n == "all" else (n,)):
            if step not in STEPS:
                raise ValueError(f"unknown step {step!r}; steps: {', '.join(STEPS)}, all")
            if step not in out:
                out.append(step)
    return out


def default_run_dir(desc: BenchDescription) -> Path:
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("out") / f"commission-{desc.name}-{stamp}"


def commission(desc: BenchDescription, steps: Sequence[str], run_dir: Path,
               log: Callable[[str], None] | None = None) -> CommissioningRun:
    say = log or (lambda _m: None)
    names = expand(steps)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    session = BenchSession(desc, run_dir, say)
    results: list[StepResult] = []
    data: dict[str, Any] = {
        "schema": "hil-commissioning/1", "bench": desc.name,
        "bench_file": str(desc.file) if desc.file else None, "steps_requested": names,
        "virtual": desc.virtual is not None, "clock": desc.clock.mode,
        "can": f"{desc.can.transport} {desc.can.channel}",
        "console": desc.console.port or None, "modbus": desc.modbus.endpoint(),
        "recording": str(session.recording), "results": str(run_dir / RESULTS),
        "started": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "passed": False, "interrupted": False, "error": None, "refused": False,
    }
    if desc.virtual is not None:
        data["virtual_profile"] = desc.virtual.profile
        data["virtual_overrides"] = dict(desc.virtual.plant)
    t_wall = time.monotonic()
    interrupted: BaseException | None = None
    with terminate_as_exception():
        try:
            try:
                session.start()
                data["can"] = session.link.where + (
                    " (the session's own channel; name one with --set can.channel=NAME)"
                    if session.channel_own else "")
                data["console"] = desc.console.port or session.endpoints.console_port
                if session.endpoints.modbus_port is not None:
                    data["modbus"] = (f"modbus tcp {desc.modbus.host}:"
                                      f"{session.endpoints.modbus_port} (virtual)")
                for name in names:
                    step = STEPS[name]
                    r = StepResult(name, step.title)
                    results.append(r)
                    say(f"step {name}: {step.title}")
                    watch = session.elapsed()
                    try:
                        step.run(session, r)
                        r.passed = all(c.passed for c in r.checks)
                    except Exception as exc:
                        r.error = f"{type(exc).__name__}: {exc}"
                        r.passed = False
                    finally:
                        r.bench_s, r.wall_s = watch()
                    say(f"step {name}: {'passed' if r.passed else 'FAILED'}"
                        + (f" ({r.error})" if r.error else ""))
                    if not r.passed:
                        break
            except (KeyboardInterrupt, Terminated) as exc:
                interrupted = exc
                data["interrupted"] = True
                data["error"] = f"interrupted ({type(exc).__name__})"
                if results and results[-1].error is None and not results[-1].passed:
                    results[-1].error = data["error"]
            except ChannelRefused as exc:
                data["refused"] = True  # nothing was started (exit 3)
                data["error"] = str(exc)
            except Exception as exc:
                data["error"] = f"{type(exc).__name__}: {exc}"
            finally:
                if session.started:
                    say("safe stop: drive disabled, load zeroed")
                    data["safety"] = session.safe_stop()
                data["programs"] = session.close()
        except (KeyboardInterrupt, Terminated) as exc:  # a second interrupt while stopping
            interrupted = interrupted or exc
            data["interrupted"] = True
    data["bench_s"] = sum(r.bench_s for r in results)
    data["wall_s"] = time.monotonic() - t_wall
    data["passed"] = (not data["interrupted"] and data["error"] is None
                      and len(results) == len(names) and all(r.passed for r in results))
    data["steps"] = [r.to_json() for r in results]
    data["identified"] = {q.key: q.value for r in results for q in r.quantities}
    data["written"] = dict(session.written)
    (run_dir / RESULTS).write_text(json.dumps(data, indent=1, default=str))
    (run_dir / REPORT).write_text(report.render(data, results))
    run = CommissioningRun(run_dir, data, results)
    if interrupted is not None:
        raise interrupted
    return run
