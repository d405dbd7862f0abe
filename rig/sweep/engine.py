"""Runs a sweep's tasks on Dask: a local cluster of worker processes (one thread each: the
bench library keeps one configuration scratch per process), or an existing cluster given by
its scheduler address. The same code either way.

Each task may be retried (``retries``): a worker that dies takes its task with it, and the
scheduler gives it to another worker. A task that still fails (its workers kept dying, or
the scheduler gave up on it) is recorded as a failed row with the reason: no point is
dropped. The progress display of every campaign (rig.run.progress: k/N, elapsed, ETA; quiet
where stderr is not a terminal). What
the cluster went through is counted (``Outcome``): the workers lost and the points run again
after losing theirs; a cluster left without any worker for ``no_worker_timeout_s`` ends the
sweep, its unfinished points failed rows saying so, instead of waiting for ever. The local
cluster serves Dask's dashboard on 127.0.0.1 (a free port): ``dashboard_link``."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from rig.run.progress import Display
from rig.sweep import point as sweep_point

Row = dict[str, Any]


@contextmanager
def client(scheduler: str | None, workers: int) -> Iterator[Any]:
    """A Dask client: on ``scheduler`` (tcp://HOST:PORT), else on a local cluster of
    ``workers`` processes that lives as long as the client."""
    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler, timeout="30s") as c:
            yield c
        return
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=dashboard_address(), host="127.0.0.1") as cluster, \
            Client(cluster) as c:
        yield c


def dashboard_address() -> str | None:
    """127.0.0.1 on a free port when Dask's dashboard can be served (it needs bokeh)."""
    import importlib.util

    return "127.0.0.1:0" if importlib.util.find_spec("bokeh") is not None else None


def dashboard_link(c: Any) -> str | None:
    """The cluster's dashboard address, when it serves one."""
    try:
        info = c.scheduler_info()
        if "dashboard" not in (info.get("services") or {}):
            return None
        return str(c.dashboard_link)
    except Exception:  # an older scheduler, a closed client: no link
        return None


NO_WORKER_TIMEOUT_S = 60.0
POLL_S = 1.0


@dataclass
class Outcome:
    """What the cluster went through during a sweep."""

    workers_seen: set[str] = field(default_factory=set)
    workers_lost: set[str] = field(default_factory=set)
    rerun: int = 0  # tasks given to another worker after theirs was lost
    gave_up: str | None = None  # why the sweep ended before every point finished

    def to_json(self) -> dict[str, Any]:
        return {"workers_seen": len(self.workers_seen), "workers_lost": len(self.workers_lost),
                "points_rerun": self.rerun, "gave_up": self.gave_up}


def _workers(c: Any) -> set[str]:
    try:
        return set((c.scheduler_info().get("workers") or {}).keys())
    except Exception:  # the scheduler is unreachable: no worker to count on
        return set()


def _reruns(c: Any, keys: Sequence[str]) -> int:
    """Times the scheduler ran these tasks again after losing the worker that ran them (its
    ``suspicious`` count per task)."""
    def count(dask_scheduler: Any, keys: Sequence[str]) -> int:
        return sum(getattr(dask_scheduler.tasks.get(k), "suspicious", 0) or 0 for k in keys)

    try:
        return int(c.run_on_scheduler(count, keys=list(keys)))
    except Exception:  # a scheduler that cannot run code for us: not counted
        return 0


class NoWorkers(RuntimeError):
    """The cluster had no worker for the whole ``no_worker_timeout_s``: a task not run."""


def map_tasks(c: Any, items: Sequence[Any], fn: Callable[[Any], Any], *, keys: Sequence[str],
              on_result: Callable[[int, Any, BaseException | None], bool],
              args: Sequence[Any] = (), retries: int = 2,
              priorities: Sequence[float] | None = None,
              no_worker_timeout_s: float = NO_WORKER_TIMEOUT_S,
              outcome: Outcome | None = None) -> None:
    """Runs ``fn`` on every item on the cluster and hands each outcome to ``on_result`` as it
    ends, with the item's index: its value, or the exception that ended it (``KilledWorker``
    once the workers running it kept dying, a task error, :class:`NoWorkers` when the cluster
    was left without a worker for ``no_worker_timeout_s``). ``on_result`` returning True
    cancels the items not yet ended (each still gets its ``on_result``: ``CancelledError``).
    ``args``: more arguments of every call (a scattered Future is resolved on the worker).
    ``priorities``: higher starts first (the longest runs first balance the workers).
    ``outcome`` gets what the cluster went through. The sweeps', suites' and mutation
    campaigns' one loop over a cluster."""
    from concurrent.futures import CancelledError

    from distributed import wait

    seen = outcome if outcome is not None else Outcome()
    prio = list(priorities) if priorities is not None else [0.0] * len(items)
    seen.workers_seen |= _workers(c)  # before the first task can start (and its worker die)
    futures = [c.submit(fn, item, *args, key=key, retries=retries, pure=False, priority=p)
               for item, key, p in zip(items, keys, prio, strict=True)]
    index = {f.key: i for i, f in enumerate(futures)}
    pending = set(futures)
    alone_since: float | None = None
    try:
        while pending:
            try:
                wait(list(pending), timeout=POLL_S, return_when="FIRST_COMPLETED")
            except TimeoutError:
                pass  # none finished in this poll: look at the workers
            done = {f for f in pending if f.status != "pending"}
            pending -= done
            now_workers = _workers(c)
            seen.workers_lost |= seen.workers_seen - now_workers
            seen.workers_seen |= now_workers
            halt = False
            for fut in sorted(done, key=lambda f: index[f.key]):
                try:
                    value, exc = fut.result(), None
                except Exception as e:  # KilledWorker, a lost connection, a task error
                    value, exc = None, e
                halt = bool(on_result(index[fut.key], value, exc)) or halt
            if halt:
                c.cancel(list(pending))
                for fut in sorted(pending, key=lambda f: index[f.key]):
                    on_result(index[fut.key], None, CancelledError())
                pending.clear()
                break
            if now_workers or done:
                alone_since = None
                continue
            alone_since = alone_since or time.monotonic()
            if time.monotonic() - alone_since >= no_worker_timeout_s:
                seen.gave_up = (f"the cluster had no worker for {no_worker_timeout_s:g} s "
                                f"({len(pending)} tasks unfinished)")
                c.cancel(list(pending))
                for fut in sorted(pending, key=lambda f: index[f.key]):
                    on_result(index[fut.key], None, NoWorkers(seen.gave_up))
                pending.clear()
    except BaseException:
        c.cancel(list(pending))
        raise
    finally:
        seen.rerun += _reruns(c, list(keys))
        for fut in futures:
            fut.release()


def run_tasks(c: Any, tasks: Sequence[sweep_point.Task],
              fn: Callable[[sweep_point.Task], Row] = sweep_point.run, *, retries: int = 2,
              progress: bool = True, on_row: Callable[[Row], None] | None = None,
              no_worker_timeout_s: float = NO_WORKER_TIMEOUT_S,
              outcome: Outcome | None = None) -> list[Row]:
    """Every task's row, in task order (a failure is a row too); ``outcome`` gets what the
    cluster went through."""
    rows: dict[int, Row] = {}
    line = Display("sweep", len(tasks), unit="point", enabled=progress)

    def got(i: int, value: Any, exc: BaseException | None) -> bool:
        task = tasks[i]
        if exc is None:
            row: Row = value
        elif isinstance(exc, NoWorkers):
            row = sweep_point.failed_row(task, "no_workers", str(exc))
        else:
            row = sweep_point.failed_row(task, type(exc).__name__, str(exc) or repr(exc))
        rows[task.index] = row
        line.done(f"point {task.index}", bool(row.get("passed")))
        if on_row is not None:
            on_row(row)
        return False

    with line:
        map_tasks(c, tasks, fn, keys=[f"sweep-point-{t.index}-{id(tasks)}" for t in tasks],
                  on_result=got, retries=retries, no_worker_timeout_s=no_worker_timeout_s,
                  outcome=outcome)
    return [rows[t.index] for t in tasks]
