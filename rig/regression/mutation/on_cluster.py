"""A mutation campaign on a Dask cluster (``rig mutate --cluster tcp://HOST:PORT``): the
unmutated tree's control first, then the null-seed runs and the mutants, each a task that
any worker may take.

This process packs the checkout's files (what a local campaign copies, ~1 MB compressed) and
hands the pack to the cluster once; each worker unpacks it into a tree of its own
(``/tmp/rig-mutate-*``, short: the C bus tests put Unix sockets under the build folder),
configures and builds it on its first task and keeps it for the next ones (one task at a
time per tree: a lock). A task applies its mutant, judges it exactly as
:func:`rig.regression.mutation.campaign.judge` does, restores the file and sends back its
verdict and its gate folder, which lands in ``OUT/<id>`` here as it would locally.

A worker must run this very rig (``rig.run.cluster.check_workers``: the gate's Python and
baselines are the worker's own). A lost worker's task goes to another worker; a cluster
left without any worker for ``no_worker_timeout_s`` ends the campaign (:class:`ClusterError`,
the verdicts that arrived kept)."""

from __future__ import annotations

import atexit
import contextlib
import functools
import hashlib
import io
import shutil
import tarfile
import tempfile
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.regression.mutation import campaign
from rig.regression.mutation.catalogue import Mutant
from rig.regression.mutation.worktree import BuildError, MutationTree, tracked_files
from rig.run import cluster
from rig.run.cluster import ClusterError


def pack_source(repo: Path) -> bytes:
    """The checkout's files a mutant build needs (``tracked_files``), packed."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz", compresslevel=6) as tar:
        for rel in tracked_files(repo):
            if (repo / rel).is_file():
                tar.add(repo / rel, arcname=rel, recursive=False)
    return buf.getvalue()


@dataclass
class _Tree:
    tree: MutationTree
    lock: threading.Lock


_TREES: dict[str, _Tree] = {}
_TREES_LOCK = threading.Lock()


def _tree(source: bytes, digest: str, jobs: int) -> _Tree:
    """This worker's tree of ``source`` (unpacked, configured and built on first use)."""
    with _TREES_LOCK:
        got = _TREES.get(digest)
        if got is not None:
            return got
        work = Path(tempfile.mkdtemp(prefix="rig-mutate-"))
        atexit.register(shutil.rmtree, work, True)
        tree = MutationTree(work, jobs=jobs)
        with tarfile.open(fileobj=io.BytesIO(source), mode="r:gz") as tar:
            tar.extractall(tree.src, filter="data")
        step = tree.configure()
        if not step.ok:
            raise BuildError(f"cmake configure failed on the worker:\n{step.log[-2000:]}")
        got = _TREES[digest] = _Tree(tree, threading.Lock())
        return got


@dataclass(frozen=True)
class Work:
    """One task of a campaign: the control (``kind`` control), the unmutated gate at a seed
    (null) or a mutant."""

    kind: str  # control | null | mutant
    name: str  # the folder under OUT: _control, _seed-N (null_run's) or the mutant's id
    mutant: Mutant | None = None
    seed: int | None = None


@dataclass(frozen=True)
class Done:
    verdict: campaign.Verdict | None  # None for the control
    problems: list[str]  # the control's
    packed: cluster.Packed | None  # the task's folder under OUT


def _do(work: Work, source: bytes, *, digest: str, expected: str, gate: campaign.Gate,
        detectors: Sequence[str], both: bool) -> Done:
    """Runs one task on this worker (the Dask task function)."""
    who, mine = cluster.worker_fingerprint()
    if mine != expected:
        raise ClusterError(f"worker {who} runs another rig (fingerprint {mine}, expected "
                           f"{expected})")
    held = _tree(source, digest, gate.jobs)
    scratch = Path(tempfile.mkdtemp(prefix="rig-mutate-out-", dir=cluster._scratch_root()))
    try:
        with held.lock:
            if work.kind == "control":
                problems = campaign.control(held.tree, gate, scratch, detectors)
                verdict = None
                # control() writes OUT/_control
            elif work.kind == "null":
                assert work.seed is not None
                problems, verdict = [], campaign.null_run(work.seed, held.tree, gate, scratch)
            else:
                assert work.mutant is not None
                problems = []
                verdict = campaign.judge(work.mutant, held.tree, gate, scratch, both,
                                         detectors)
        folder = scratch / work.name
        packed = cluster.Packed(cluster.pack(folder), str(folder), who) \
            if folder.is_dir() else None
        return Done(verdict, problems, packed)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _unpacked(done: Done, out: Path, name: str) -> None:
    if done.packed is not None:
        dest = out / name
        if dest.exists():
            shutil.rmtree(dest)
        dest.mkdir(parents=True)
        cluster.unpack(done.packed.data, dest, (done.packed.folder, str(dest)))


def run(address: str, mutants: Sequence[Mutant], gate: campaign.Gate, out: Path, *,
        both: bool, detectors: Sequence[str], null_seeds: Sequence[int],
        no_worker_timeout_s: float, progress: Callable[[str], None]) -> tuple[
            list[str], list[campaign.Verdict]]:
    """The campaign on the cluster at ``address``: the control's problems (nothing else runs
    when there are any) and the verdicts in the order a local campaign gives them."""

    from rig import _paths
    from rig.sweep import engine

    source = pack_source(_paths.repo_dir())
    digest = hashlib.sha256(source).hexdigest()[:16]
    progress(f"rig mutate: the checkout packed ({len(source) / 1e6:.1f} MB, {digest}); "
             f"on the cluster at {address}")
    with contextlib.ExitStack() as stack:
        try:
            c = stack.enter_context(engine.client(address, 0))
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"cannot reach the cluster at {address}: {exc}") from exc
        return _run(c, source, digest, mutants, gate, out, both=both, detectors=detectors,
                    null_seeds=null_seeds, no_worker_timeout_s=no_worker_timeout_s,
                    progress=progress)


def _run(c: Any, source: bytes, digest: str, mutants: Sequence[Mutant], gate: campaign.Gate,
         out: Path, *, both: bool, detectors: Sequence[str], null_seeds: Sequence[int],
         no_worker_timeout_s: float, progress: Callable[[str], None]) -> tuple[
             list[str], list[campaign.Verdict]]:
    from concurrent.futures import CancelledError

    from rig.sweep import engine

    cluster.check_workers(c)
    src = c.scatter(source, broadcast=False)  # sent once; each task names it
    task = functools.partial(_do, digest=digest, expected=cluster.fingerprint(),
                             gate=gate, detectors=list(detectors), both=both)
    outcome = engine.Outcome()

    def one(works: list[Work], on_done: Callable[[int, Done], None]) -> None:
        failed: list[str] = []

        def got(i: int, done: Done | None, exc: BaseException | None) -> bool:
            if isinstance(exc, CancelledError):
                return False
            if done is None:
                failed.append(f"{works[i].name}: {type(exc).__name__}: {exc}")
                return isinstance(exc, engine.NoWorkers | ClusterError | BuildError)
            _unpacked(done, out, works[i].name)
            on_done(i, done)
            return False

        tag = hashlib.sha256(f"{id(works)}-{digest}".encode()).hexdigest()[:8]
        engine.map_tasks(c, works, task, keys=[f"rig-mutate-{tag}-{w.name}" for w in works],
                         args=(src,), on_result=got, retries=1,
                         no_worker_timeout_s=no_worker_timeout_s, outcome=outcome)
        if failed:
            cluster.say_outcome(outcome)
            raise ClusterError("the cluster did not judge " + "; ".join(failed)[:1200])

    problems: list[str] = []
    one([Work("control", "_control")],
        lambda i, d: problems.extend(d.problems))
    if problems:
        return problems, []
    works = ([Work("null", f"_seed-{s}", seed=s) for s in null_seeds]
             if "gate" in detectors else [])
    works += [Work("mutant", m.id, mutant=m) for m in mutants]
    verdicts: dict[int, campaign.Verdict] = {}

    def arrived(i: int, done: Done) -> None:
        assert done.verdict is not None
        verdicts[i] = done.verdict
        ordered = [verdicts[k] for k in sorted(verdicts)]
        campaign.write(out, ordered, gate, detectors)
        campaign.say_one(done.verdict, len(verdicts), len(works), progress)

    one(works, arrived)
    cluster.say_outcome(outcome)
    return [], [verdicts[k] for k in sorted(verdicts)]
