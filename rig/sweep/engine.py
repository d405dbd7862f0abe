"""Runs a sweep's tasks on Dask: a local cluster of worker processes (one thread each: the
bench library keeps one configuration scratch per process), or an existing cluster given by
its scheduler address. The same code either way.

Each task may be retried (``retries``): a worker that dies takes its task with it, and the
scheduler gives it to another worker. A task that still fails (its workers kept dying, or
the scheduler gave up on it) is recorded as a failed row with the reason: no point is
dropped. A progress line on stderr (rewritten on a TTY, every few seconds otherwise)."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TextIO

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
                      dashboard_address=None, host="127.0.0.1") as cluster, \
            Client(cluster) as c:
        yield c


class ProgressLine:
    """``sweep: 12/40 done, 1 not passed, 3.2 points/min, ETA 300 s``"""

    def __init__(self, total: int, stream: TextIO | None = None, enabled: bool = True) -> None:
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = 0.2 if self.tty else 10.0
        self.t0 = time.monotonic()
        self._last = -1e9

    def update(self, done: int, failed: int, *, force: bool = False) -> None:
        now = time.monotonic()
        if not self.enabled or (not force and now - self._last < self.interval):
            return
        self._last = now
        elapsed = now - self.t0
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else float("nan")
        text = (f"sweep: {done}/{self.total} done, {failed} not passed, "
                f"{60.0 * rate:.1f} points/min, ETA {eta:.0f} s")
        if self.tty:
            self.stream.write("\r" + text.ljust(78))
            if done == self.total:
                self.stream.write("\n")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()


def run_tasks(c: Any, tasks: Sequence[sweep_point.Task],
              fn: Callable[[sweep_point.Task], Row] = sweep_point.run, *, retries: int = 2,
              progress: bool = True, on_row: Callable[[Row], None] | None = None) -> list[Row]:
    """Every task's row, in task order (a failure is a row too)."""
    from distributed import as_completed

    futures = c.map(fn, list(tasks), retries=retries, pure=False,
                    key=[f"sweep-point-{t.index}-{id(tasks)}" for t in tasks])
    by_future = dict(zip(futures, tasks, strict=True))
    rows: dict[int, Row] = {}
    line = ProgressLine(len(tasks), enabled=progress)
    failed = 0
    for fut in as_completed(futures):
        task = by_future[fut]
        try:
            row: Row = fut.result()
        except Exception as exc:  # KilledWorker, a lost connection, a task error
            row = sweep_point.failed_row(task, type(exc).__name__, str(exc) or repr(exc))
        finally:
            fut.release()
        rows[task.index] = row
        if not row.get("passed"):
            failed += 1
        if on_row is not None:
            on_row(row)
        line.update(len(rows), failed)
    line.update(len(rows), failed, force=True)
    return [rows[t.index] for t in tasks]
