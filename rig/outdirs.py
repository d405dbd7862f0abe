"""Where runs write, and which old runs ``rig clean`` may remove.

``rig run`` and ``rig sweep`` without ``--out`` write to ``$HIL_OUT`` (else ``./out``) in a new
folder ``<name>-<YYYYmmdd-HHMMSS>`` (``-2``, ``-3``, ... when runs start in the same second:
each run makes its own folder, atomically): these are the folders that pile up. ``./hil main`` and
``./hil test`` write to fixed folders (``out/paper``, ``out/ci/...``) that the next run
replaces. A run folder holds a ``result.json`` (``hil-result/1`` or ``hil-suite/1``) or a
``sweep.json``.

``rig clean`` never removes what a user asked to keep: a folder holding a file named ``KEEP``
(anywhere inside it, a suite's scenario folder too),
a folder outside the output root, and (unless ``--all``) a folder the user named with
``--out``. It removes nothing without ``--yes``.
"""

from __future__ import annotations

import datetime as dt
import itertools
import json
import os
import re
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

STAMP_FORMAT = "%Y%m%d-%H%M%S"
AUTO_NAME = re.compile(r".+-(\d{8}-\d{6})(?:-\d+)?")
KEEP_MARKER = "KEEP"
RUN_SCHEMAS = ("hil-result/1", "hil-suite/1")
# written into a run's folder before anything else: the folder is the rig's (a run killed
# before its result.json was written is still recognised as one)
RUN_MARKER = ".hil-run"


def default_root() -> Path:
    return Path(os.environ.get("HIL_OUT", "out"))


def default_out(name: str) -> Path:
    """A new folder for a run without ``--out``, made here: ``<root>/<name>-<YYYYmmdd-HHMMSS>``,
    with ``-2``, ``-3``, ... when that exists already (runs started in the same second, in
    parallel: ``mkdir`` without ``exist_ok`` makes each folder one run's alone). When the
    folder cannot be made at all, its path is returned unmade: ``rig.output.prepare`` then
    says why (exit 3)."""
    root = default_root()
    base = f"{name}-{dt.datetime.now().strftime(STAMP_FORMAT)}"
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError:
        return root / base
    for n in itertools.count(1):
        path = root / (base if n == 1 else f"{base}-{n}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        except OSError:
            return path
        return path
    raise AssertionError("unreachable")


@dataclass(frozen=True)
class RunDir:
    path: Path
    kind: str  # "scenario", "suite" or "sweep"
    name: str
    when: dt.datetime
    bytes: int
    passed: bool | None
    auto_named: bool  # made by rig run / rig sweep without --out
    keep: bool  # holds a KEEP file
    full_rate: bool  # still holds traces or capture columns

    @property
    def age_days(self) -> float:
        return (dt.datetime.now() - self.when).total_seconds() / 86400.0


def _size(path: Path) -> int:
    total = 0
    for p in path.rglob("*"):
        try:
            if p.is_file() and not p.is_symlink():
                total += p.stat().st_size
        except OSError:
            continue
    return total


def _run_schema(result: Path) -> str | None:
    """The schema of a run's result.json (a regular file, not a link), else None."""
    try:
        if not result.is_file() or result.is_symlink():
            return None
        data = json.loads(result.read_text())
    except (OSError, ValueError):
        return None
    schema = data.get("schema") if isinstance(data, dict) else None
    return schema if schema in RUN_SCHEMAS else None


def is_run_folder(path: Path) -> bool:
    """A folder an earlier ``rig run`` wrote: its marker, or a run's result.json."""
    marker = path / RUN_MARKER
    return (marker.is_file() and not marker.is_symlink()) or (
        _run_schema(path / "result.json") is not None)


def _describe(path: Path) -> RunDir | None:
    result, sweep = path / "result.json", path / "sweep.json"
    kind, name, passed = "", path.name, None
    if result.is_file():
        try:
            data = json.loads(result.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(data, dict) or data.get("schema") not in RUN_SCHEMAS:
            return None
        kind = "suite" if data["schema"] == "hil-suite/1" else "scenario"
        name = str(data.get("suite") or data.get("scenario") or path.name)
        passed = bool(data.get("passed"))
        marker = result
    elif sweep.is_file():
        kind, marker = "sweep", sweep
    else:
        return None
    m = AUTO_NAME.fullmatch(path.name)
    when = dt.datetime.fromtimestamp(marker.stat().st_mtime)
    full = any(path.rglob("*.trace")) or any(path.rglob("capture/meta.json"))
    return RunDir(path=path, kind=kind, name=name, when=when, bytes=_size(path), passed=passed,
                  auto_named=m is not None, keep=holds_keep(path), full_rate=full)


def holds_keep(path: Path) -> bool:
    """A ``KEEP`` file in the folder or in any folder below it (a suite's scenario folder: the
    suite is removed as one, so a KEEP inside keeps all of it). Symbolic links are not
    followed (``Path.rglob``)."""
    return (path / KEEP_MARKER).exists() or any(path.rglob(KEEP_MARKER))


def find_runs(root: Path) -> Iterator[RunDir]:
    """Run folders under ``root`` (a suite's scenario folders belong to the suite)."""
    if not root.is_dir():
        return
    stack = [root]
    while stack:
        folder = stack.pop()
        run = _describe(folder) if folder != root else None
        if run is not None:
            yield run
            continue
        try:
            children = sorted(p for p in folder.iterdir() if p.is_dir() and not p.is_symlink())
        except OSError:
            continue
        stack.extend(reversed(children))


def select(runs: list[RunDir], *, keep_last: int, older_than_days: float | None,
           include_named: bool) -> list[RunDir]:
    """The runs ``rig clean`` would remove: never a KEEP folder; only auto-named folders unless
    ``include_named``; never the newest ``keep_last`` of those; and with ``older_than_days``
    only those older than that."""
    candidates = [r for r in runs if not r.keep and (r.auto_named or include_named)]
    candidates.sort(key=lambda r: r.when, reverse=True)
    chosen = candidates[max(0, keep_last):]
    if older_than_days is not None:
        chosen = [r for r in chosen if r.age_days > older_than_days]
    return sorted(chosen, key=lambda r: r.when)


def remove(run: RunDir, root: Path) -> None:
    """Removes a run folder that lies inside ``root`` (checked again here)."""
    path, base = run.path.resolve(), root.resolve()
    if base not in path.parents:
        raise ValueError(f"{run.path} is not inside {root}")
    if holds_keep(path):
        raise ValueError(f"{run.path} holds a {KEEP_MARKER} file")
    shutil.rmtree(path)
