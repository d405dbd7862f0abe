"""A Dask cluster on 127.0.0.1 for the tests: a scheduler and single-threaded workers (each
with its nanny), started as processes in sessions of their own and stopped with their
process groups."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path


def stop(procs: list[subprocess.Popen[bytes]]) -> None:
    """SIGTERM to each process group (a nanny and its worker), SIGKILL after 5 s."""
    for p in procs:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGTERM)
    deadline = time.monotonic() + 5.0
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=10)


def scheduler_address(sched_file: Path, deadline: float) -> str:
    """The address in the scheduler's file, once the file holds all of it: the scheduler
    creates the file before it has written it (on a loaded machine it was read empty)."""
    while True:
        try:
            return str(json.loads(sched_file.read_text())["address"])
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            assert time.monotonic() < deadline, "scheduler did not start"
            time.sleep(0.1)


QUIET = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "start_new_session": True}


@dataclass
class Cluster:
    address: str
    scheduler: subprocess.Popen[bytes]
    workers: list[subprocess.Popen[bytes]] = field(default_factory=list)
    env: Mapping[str, str] | None = None

    def add_worker(self) -> subprocess.Popen[bytes]:
        w = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", self.address, "--host",
             "127.0.0.1", "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
            env=dict(self.env) if self.env is not None else None, **QUIET)  # type: ignore[call-overload]
        self.workers.append(w)
        return w

    def wait_for_workers(self, n: int) -> None:
        from distributed import Client

        with Client(self.address, timeout="30s") as c:
            c.wait_for_workers(n, timeout=120)


@contextlib.contextmanager
def cluster(tmp: Path, workers: int = 2,
            env: Mapping[str, str] | None = None) -> Iterator[Cluster]:
    """A scheduler and ``workers`` workers (``env``: the workers' environment)."""
    tmp.mkdir(parents=True, exist_ok=True)
    sched_file = tmp / "scheduler.json"
    scheduler = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", "0", "--no-dashboard", "--scheduler-file", str(sched_file)], **QUIET)  # type: ignore[call-overload]
    c = Cluster("", scheduler, env=env)
    try:
        c.address = scheduler_address(sched_file, time.monotonic() + 60)
        assert c.address.startswith("tcp://127.0.0.1:")
        for _ in range(workers):
            c.add_worker()
        if workers:
            c.wait_for_workers(workers)
        yield c
    finally:
        stop(c.workers)
        stop([scheduler])
