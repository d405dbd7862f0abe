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
from rig.regression.baseline import HIGHER, LOWER
from rig.results.result import RunResult
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


def criterion_on(sc: scenario.Scenario, metric: str) -> scenario.Criterion | None:
    """The scenario's first criterion on ``metric`` (None: no criterion reads it)."""
    return next((cr for cr in sc.criteria if cr.metric == metric), None)


def default_window(sc: scenario.Scenario, metric: str) -> tuple[float, float]:
    """The window of the scenario's first criterion on ``metric``, else its second half."""
    cr = criterion_on(sc, metric)
    return (cr.window[0], cr.window[1]) if cr is not None else (sc.duration / 2.0, sc.duration)


def metric_params(sc: scenario.Scenario, metric: str) -> dict[str, float]:
    """The parameters the scenario's criterion gives ``metric`` (a recovery's band, ...), so
    the summary reads the metric as the criterion of the same name does; none without one."""
    cr = criterion_on(sc, metric)
    return {k: float(v) for k, v in cr.params.items()} if cr is not None else {}


def worst_of_seeds(values: Sequence[float | None], side: str) -> float | None:
    """The worst seed's value: the smallest when higher is better, else the largest; a seed
    without a number makes the point's value empty (it is worse than any number)."""
    if not values or any(v is None for v in values):
        return None
    nums = [float(v) for v in values if v is not None]
    return min(nums) if side == HIGHER else max(nums)


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
        params = metric_params(sc, task.metric)
        seed_values: list[float | None] = []
        if result.seeds:  # decided over its own seeds: each seed's run has its capture
            for entry in result.seeds:
                folder = result.out_dir / entry["dir"]
                seed_values.append(_metric_of(RunResult.load(folder), task.metric, window,
                                              params)
                                   if (folder / "result.json").is_file() else None)
            cr = criterion_on(sc, task.metric)
            value = worst_of_seeds(seed_values, cr.side() if cr is not None else LOWER)
        else:
            value = _metric_of(result, task.metric, window, params)
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
        if seed_values:
            row["metric_seeds"] = ", ".join(
                f"{e['seed']}: " + ("—" if v is None else f"{v:.6g}")
                for e, v in zip(result.seeds or [], seed_values, strict=True))
        for c in result.criteria:
            row[f"crit.{c['name']}"] = c["value"]
            row[f"outcome.{c['name']}"] = c["outcome"]
        timing = result.timing
        row["sim_s"] = timing.sim_s if timing is not None else None
        row["wall_s"] = timing.wall_s if timing is not None else None
        return row


def _metric_of(result: RunResult, metric: str, window: tuple[float, float],
               params: dict[str, float]) -> float | None:
    """``metric`` of one run over ``window`` (None: no capture, no data, not finite); the
    run's capture is closed afterwards (its folder is deleted with the point)."""
    value: float | None = None
    if result.capture is not None:
        with _suppress_metric_errors():
            v = result.metric(metric, window, **params)
            value = v if math.isfinite(v) else None
        result.capture = None
    return value


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
