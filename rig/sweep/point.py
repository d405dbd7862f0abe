"""One point of a sweep, run where the engine puts it (this process, a pool worker, a Dask
worker on another machine): the scenario with the point's values, in a scratch folder that
is deleted afterwards; back comes one flat row (plain Python values) for the table."""

from __future__ import annotations

import math
import os
import tempfile
import traceback
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig import scenario
from rig.run import runner
from rig.sweep import spec


@dataclass(frozen=True)
class Task:
    """Everything a worker needs (picklable): the scenario by name or file, the axes, the
    point's values, the bus, and the metric of the summary."""

    index: int
    scenario: str
    axes: tuple[spec.Axis, ...]
    values: dict[str, float]
    bus: str = "inproc"
    metric: str = "pos_err_max_deg"
    window: tuple[float, float] | None = None
    channel: str | None = None
    scratch: str | None = None  # the folder the point's run goes into (None: the temp dir)


def _label(values: dict[str, float]) -> str:
    return ",".join(f"{k}={v:.6g}" for k, v in values.items())


def _num(v: object) -> str:
    return f"{v:.4g}" if isinstance(v, int | float) else str(v)


def default_window(sc: scenario.Scenario, metric: str) -> tuple[float, float]:
    """The window of the scenario's first criterion on ``metric``, else its second half."""
    for cr in sc.criteria:
        if cr.metric == metric:
            return (cr.window[0], cr.window[1])
    return (sc.duration / 2.0, sc.duration)


def base_row(task: Task) -> dict[str, Any]:
    return {"point": task.index, **{f"param.{k}": v for k, v in task.values.items()}}


def failed_row(task: Task, kind: str, message: str) -> dict[str, Any]:
    """The row of a point that produced no result (recorded, never dropped)."""
    return {**base_row(task), "status": "error", "passed": False, "failure_kind": kind,
            "failure": message, "metric": task.metric, "metric_value": None}


def run(task: Task) -> dict[str, Any]:
    """Runs the point; any exception is its row's failure, not the engine's."""
    try:
        return _run(task)
    except Exception as exc:  # the reason goes into the table
        tail = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return failed_row(task, "exception", tail)


def _run(task: Task) -> dict[str, Any]:
    base = scenario.load(task.scenario)
    if not isinstance(base, scenario.Scenario):
        raise ValueError(f"{task.scenario} is a suite, not a scenario")
    sc = spec.apply(base, task.axes, task.values, _label(task.values))
    window = task.window or default_window(sc, task.metric)
    # on a bus every point needs a channel of its own (points run side by side)
    channel = task.channel if task.bus == "inproc" else (
        task.channel or f"sweep-{os.getpid()}-{task.index}")
    with tempfile.TemporaryDirectory(prefix="rig-sweep-", dir=task.scratch) as tmp:
        result = runner.run_scenario(sc, runner.RunOptions(
            out=Path(tmp) / "run", bus=task.bus, channel=channel, progress=False,
            record=False, figures=False))
        value: float | None = None
        if result.capture is not None:
            with _suppress_metric_errors():
                v = result.metric(task.metric, window)
                value = v if math.isfinite(v) else None
        row = {**base_row(task), "status": result.status, "passed": result.passed}
        failure = result.failure
        row["failure_kind"] = failure.kind if failure is not None else None
        row["failure"] = failure.message if failure is not None else None
        if not result.passed and failure is None:
            failed = result.failed_criteria()
            row["failure_kind"] = "criteria"
            row["failure"] = "; ".join(
                f"{c['name']}: {c['metric']} = {_num(c['value'])} (limit {c['comparison']} "
                f"{_num(c['limit'])})" for c in failed)
        row["metric"] = task.metric
        row["metric_window"] = f"{window[0]:g}..{window[1]:g}"
        row["metric_value"] = value
        for c in result.criteria:
            row[f"crit.{c['name']}"] = c["value"]
            row[f"outcome.{c['name']}"] = c["outcome"]
        timing = result.timing
        row["sim_s"] = timing.sim_s if timing is not None else None
        row["wall_s"] = timing.wall_s if timing is not None else None
        result.capture = None  # close the memory maps before the folder goes
        return row


class _suppress_metric_errors:
    """A metric the capture cannot give (missing data) leaves the value empty."""

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind: type[BaseException] | None, *rest: object) -> bool:
        return kind is not None and issubclass(kind, (KeyError, ValueError))


def tasks(scenario_name: str, axes: Sequence[spec.Axis], points: Sequence[dict[str, float]],
          **options: Any) -> list[Task]:
    return [Task(k, scenario_name, tuple(axes), dict(p), **options)
            for k, p in enumerate(points)]
