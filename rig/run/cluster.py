"""A suite's scenario runs on a Dask cluster (``rig run SUITE --cluster tcp://HOST:PORT``):
the same :class:`rig.run.parallel.Job` as on the local process pool, run by the same
``run_scenario`` on a worker, and collected the same way: from the run's folder here.

A worker runs its job in a scratch folder of its own (the machines need not share a file
system), packs the folder the run left (``result.json``, ``report.md``, the confirmation's
runs, the traces of a run that did not pass) and sends it back; this process unpacks it into
the job's folder, the paths in its JSON and Markdown files named as they are here. The
confirmation of a flag at fresh seeds (``rig.regression.confirm``) runs inside
``run_scenario``: on the worker that ran the scenario.

A worker must run this very rig: before the first job every worker's *fingerprint* (a digest
of the rig's Python files, baselines, scenarios, profiles, wire definitions and the
in-process bench library) is compared with this one's, and every job checks it again on the
worker that takes it (a worker may join later). A mismatch stops the suite (exit 3): its
results would not be this checkout's.

Lost workers: Dask gives a lost worker's runs to another one (``distributed``'s
``allowed-failures``, then the run is a crash); a cluster left without any worker for
``no_worker_timeout_s`` ends the suite, its runs not yet done failed with that reason."""

from __future__ import annotations

import functools
import hashlib
import io
import os
import shutil
import tarfile
import tempfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig import _paths

if TYPE_CHECKING:
    from rig.run.parallel import Job

# the files whose content makes a run's result: what a worker must share with this process
FINGERPRINT_SUFFIXES = (".py", ".toml", ".csv", ".dbc", ".json")


class ClusterError(RuntimeError):
    """The cluster cannot run this suite (unreachable, another rig on a worker)."""


def _files(root: Path, suffixes: Iterable[str]) -> list[Path]:
    if not root.is_dir():
        return []
    return sorted(p for p in root.rglob("*") if p.is_file() and p.suffix in suffixes
                  and "__pycache__" not in p.parts)


@functools.lru_cache(maxsize=1)
def fingerprint() -> str:
    """A digest of what makes this rig's results: its package's Python and data files, the
    baselines it judges against (``$HIL_BASELINE_DIR`` too), the wire definitions, the plant
    profiles and the in-process bench library (by content, so two checkouts of the same
    commit and build agree wherever they live)."""
    from rig.bench import sil
    from rig.regression import baseline

    h = hashlib.sha256()
    pkg = Path(__file__).resolve().parent.parent
    roots = [(pkg, FINGERPRINT_SUFFIXES), (baseline.folder_of(), (".toml",)),
             (_paths.data_dir("protocols"), (".dbc", ".csv")),
             (_paths.data_dir("profiles"), (".toml",))]
    for root, suffixes in roots:
        for f in _files(root, suffixes):
            h.update(f.relative_to(root).as_posix().encode() + b"\0")
            h.update(f.read_bytes())
    try:
        h.update(_paths.library(sil.LIBRARY).read_bytes())
    except FileNotFoundError:
        h.update(b"no bench library")
    return h.hexdigest()[:16]


def worker_fingerprint() -> tuple[str, str]:
    """(host:pid, fingerprint) of the worker this runs on."""
    import socket

    return f"{socket.gethostname()}:{os.getpid()}", fingerprint()


def check_workers(c: Any) -> None:
    """Every worker runs this rig, or :class:`ClusterError` names the ones that do not."""
    mine = fingerprint()
    got = c.run(worker_fingerprint)
    other = sorted(f"{addr} ({who}: {fp})" for addr, (who, fp) in got.items() if fp != mine)
    if other:
        raise ClusterError(f"{len(other)} of {len(got)} workers run another rig than this one "
                           f"(fingerprint {mine}): {', '.join(other)[:600]}; install this "
                           "checkout there (same commit, same build)")


def _scratch_root() -> str | None:
    """The worker's own folder (the nanny removes it with the worker), else the temp dir."""
    try:
        from distributed import get_worker

        return str(get_worker().local_directory)
    except (ImportError, ValueError, AttributeError):
        return None


def pack(folder: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz", compresslevel=1) as tar:
        tar.add(folder, arcname=".")
    return buf.getvalue()


def unpack(data: bytes, dest: Path, renamed: tuple[str, str]) -> None:
    """The folder packed by :func:`pack` into ``dest``; in its JSON and Markdown files the
    worker's folder ``renamed[0]`` becomes ``renamed[1]``, the folder's name here."""
    old, new = renamed
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        tar.extractall(dest, filter="data")
    for f in dest.rglob("*"):
        if f.is_file() and f.suffix in (".json", ".md"):
            text = f.read_text(encoding="utf-8")
            if old in text:
                f.write_text(text.replace(old, new), encoding="utf-8")


@dataclass(frozen=True)
class Packed:
    """A job's run folder as the worker left it, and which folder it was there."""

    data: bytes
    folder: str
    worker: str


def run_on_worker(job: Job, expected: str) -> Packed:
    """Runs ``job`` here (a Dask worker) into a scratch folder and returns the folder packed.
    Refuses (:class:`ClusterError`) when this worker's rig is not the one that sent it."""
    from rig.run.runner import run_scenario

    who, mine = worker_fingerprint()
    if mine != expected:
        raise ClusterError(f"worker {who} runs another rig (fingerprint {mine}, expected "
                           f"{expected})")
    scratch = Path(tempfile.mkdtemp(prefix="rig-cluster-", dir=_scratch_root()))
    try:
        out = scratch / Path(job.opts.out).name
        run_scenario(job.scenario, replace(job.opts, out=out))
        return Packed(pack(out), str(out), who)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def collect(job: Job, packed: Packed, claim: Callable[[Path], None]) -> None:
    """A job's packed folder into the job's folder here (claimed first, as a run claims it)."""
    dest = Path(job.opts.out)
    claim(dest)
    unpack(packed.data, dest, (packed.folder, str(dest)))


def run_jobs(c: Any, jobs: Sequence[Job], order: Sequence[float],
             on_result: Callable[[int, Packed | None, BaseException | None], bool], *,
             no_worker_timeout_s: float, retries: int = 1) -> Any:
    """The jobs on the cluster behind client ``c``, longest first (``order``: each job's
    expected work); ``on_result`` as :func:`rig.sweep.engine.map_tasks`. Returns what the
    cluster went through (``rig.sweep.engine.Outcome``)."""
    from rig.sweep import engine

    check_workers(c)
    mine = fingerprint()
    outcome = engine.Outcome()
    tag = hashlib.sha256(f"{os.getpid()}-{id(jobs)}".encode()).hexdigest()[:8]
    engine.map_tasks(c, list(jobs), functools.partial(run_on_worker, expected=mine),
                     keys=[f"rig-run-{tag}-{i}-{Path(j.opts.out).name}"
                           for i, j in enumerate(jobs)],
                     on_result=on_result, retries=retries, priorities=order,
                     no_worker_timeout_s=no_worker_timeout_s, outcome=outcome)
    return outcome


def say_outcome(outcome: Any) -> None:
    """What the cluster went through, when it was more than running the jobs."""
    import sys

    if outcome.workers_lost or outcome.rerun or outcome.gave_up:
        print(f"rig: the cluster lost {len(outcome.workers_lost)} workers; {outcome.rerun} "
              "runs went to another worker"
              + (f"; {outcome.gave_up}" if outcome.gave_up else ""), file=sys.stderr)
