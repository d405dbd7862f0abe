"""Scenario runs on the in-process bench spread over worker processes (``rig run SUITE
--jobs N``, ``rig baseline record``).

Each run is the same ``run_scenario`` as in one process, into its own folder; the results
are read back from those folders. The workers ignore SIGINT (Ctrl-C reaches the whole
process group: the parent decides) and turn SIGTERM into :class:`Terminated`, so a run
that is stopped still writes its partial ``result.json``: on an interrupt the parent
cancels the runs that have not started, sends SIGTERM to the running ones, waits for them
to write what they have and then re-raises."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from rig.results.result import Failure, RunResult
from rig.run.options import RunOptions
from rig.run.runner import run_scenario
from rig.scenario import Scenario
from rig.supervisor import Terminated

# how long stopped workers get to write their partial results
STOP_GRACE_S = 20.0


@dataclass(frozen=True)
class Job:
    scenario: Scenario
    opts: RunOptions


def _worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def terminated(signum: int, frame: FrameType | None) -> None:
        raise Terminated(signal.Signals(signum).name)

    signal.signal(signal.SIGTERM, terminated)


def _run(job: Job) -> tuple[str, int]:
    run_scenario(job.scenario, job.opts)
    return str(job.opts.out), os.getpid()


def _load(out: Path) -> RunResult | None:
    try:
        return RunResult.load(out)
    except (OSError, ValueError):
        return None


def _crashed(job: Job, exc: BaseException) -> RunResult:
    """A run whose worker process died before it wrote its result (the bench crashed, in
    this run or in another one of the same worker pool)."""
    return RunResult(
        out_dir=Path(job.opts.out), scenario=job.scenario.name,
        scenario_file=str(job.scenario.file), profile=job.scenario.profile, status="error",
        failure=Failure("crash", f"the worker process died before the run wrote its result "
                        f"({exc})"))


def _raised(job: Job, exc: BaseException) -> RunResult:
    """A run that raised ``exc`` in its worker before it wrote its result."""
    return RunResult(
        out_dir=Path(job.opts.out), scenario=job.scenario.name,
        scenario_file=str(job.scenario.file), profile=job.scenario.profile, status="error",
        failure=Failure("exception", f"the run raised {type(exc).__name__}: {exc} before it "
                        "wrote its result (a worker of the in-process pool)"))


def run_jobs(jobs: Sequence[Job], workers: int,
             results: list[RunResult | None],
             on_done: Callable[[Job, RunResult | None], None] | None = None,
             stop: Callable[[Job, RunResult | None], bool] | None = None) -> None:
    """Runs ``jobs`` on ``workers`` processes, filling ``results`` (as long as ``jobs``) in
    their order as they end (None: the run wrote no result, e.g. it was cancelled); on an
    interrupt it holds what the runs wrote before the exception is re-raised. ``on_done``
    sees each run as it ends; when ``stop`` returns True for one, the runs not yet started
    are cancelled and the running ones finish."""
    if not jobs:
        return
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=max(1, min(workers, len(jobs))), mp_context=ctx,
                               initializer=_worker_init)
    pending: dict[Future[tuple[str, int]], int] = {
        pool.submit(_run, job): i for i, job in enumerate(jobs)}
    try:
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            halt = False
            for fut in done:
                i = pending.pop(fut)
                if fut.cancelled():
                    continue
                results[i] = _load(Path(jobs[i].opts.out))
                exc = fut.exception()
                if results[i] is None and isinstance(exc, BrokenProcessPool):
                    results[i] = _crashed(jobs[i], exc)
                elif results[i] is None and exc is not None:
                    # the run raised before it wrote a result (an import missing from the
                    # install, a bug of the rig): that run is an error, named, and the suite
                    # goes on to its verdict instead of ending in a traceback
                    results[i] = _raised(jobs[i], exc)
                if on_done is not None:
                    on_done(jobs[i], results[i])
                halt = halt or (stop is not None and stop(jobs[i], results[i]))
            if halt:
                for fut in list(pending):
                    if fut.cancel():
                        pending.pop(fut)
    except BaseException:
        for fut in pending:
            fut.cancel()
        _stop_workers(pool)
        deadline = time.monotonic() + STOP_GRACE_S
        for fut, i in pending.items():
            if fut.cancelled():
                continue
            try:
                fut.exception(timeout=max(0.0, deadline - time.monotonic()))
            except Exception:
                pass
            results[i] = _load(Path(jobs[i].opts.out))
        pool.shutdown(wait=False, cancel_futures=True)
        _kill_workers(pool)
        raise
    pool.shutdown(wait=True)


def _workers(pool: ProcessPoolExecutor) -> list[multiprocessing.process.BaseProcess]:
    procs = getattr(pool, "_processes", None) or {}
    return list(procs.values())


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    for p in _workers(pool):
        if p.is_alive() and p.pid is not None:
            try:
                os.kill(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass


def _kill_workers(pool: ProcessPoolExecutor) -> None:
    for p in _workers(pool):
        if p.is_alive():
            p.kill()
