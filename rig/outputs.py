"""The rig's output folders: where runs write, which folder a run may take and how it
leaves it, and which old runs ``rig clean`` may remove.

Where: ``rig run`` and ``rig sweep`` without ``--out`` write to ``$HIL_OUT`` (else ``./out``)
in a new folder ``<name>-<YYYYmmdd-HHMMSS>`` (``-2``, ``-3``, ... when runs start in the same
second: each run makes its own folder, atomically): these are the folders that pile up.
``./hil main`` and ``./hil test`` write to fixed folders (``out/paper``, ``out/ci/...``) that
the next run replaces. A run folder holds a ``result.json`` (``hil-result/1`` or
``hil-suite/1``) or a ``sweep.json``.

Taking a folder: checked before any program starts (a path through a file, a folder under
/proc, a read-only folder or a disk without room is an environment problem, exit 3, not a
traceback at the end). A run may write over only a new or empty folder, or one an earlier
run of the rig wrote (``is_run_folder``), and there only the files a run writes
(``RUN_FILES`` and the programs' logs); a folder holding anything else is refused before
anything starts. Only the files of the earlier run go: its fixed ones, and those it wrote
under names it chose as it ran (the criteria's pictures), which its marker lists; a file of
the user's that merely matches such a name stays. A run locks its folder while it runs: a
second run into it at the same time is refused at once. No symbolic link is followed there:
a link in place of a run's file is removed, not its target. A result file is either
complete or not there: written to a temporary name and renamed into place, never left
truncated by a full disk. A run that need not keep its full-rate data has it removed at the
end (``prune``).

``rig clean`` never removes what a user asked to keep: a folder holding a file named ``KEEP``
(anywhere inside it, a suite's scenario folder too) or lying in a folder that holds one (up
to the output root),
a folder outside the output root, and (unless ``--all``) a folder the user named with
``--out``. It removes nothing without ``--yes``.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import fnmatch
import itertools
import json
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

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
    folder cannot be made at all, its path is returned unmade: ``prepare`` then
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


# What a run writes per simulated PWM period, generously: the two traces (3 records of 72
# bytes), the capture's columns and the recording.
BYTES_PER_PERIOD = 1024
BYTES_FIXED = 16 << 20


class OutputError(OSError):
    """The output folder cannot take the run's results."""


def prepare(folder: Path, periods: int = 0) -> None:
    """Creates ``folder`` and checks it takes a file and has room for ``periods``."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the output folder {folder}: "
                          f"{exc.strerror or exc}") from exc
    if not folder.is_dir():
        raise OutputError(f"the output folder {folder} is not a directory")
    try:
        fd, probe = tempfile.mkstemp(prefix=".rig-write-check-", dir=folder)
        try:
            os.write(fd, b"x" * 4096)
            os.fsync(fd)
        finally:
            os.close(fd)
            os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"cannot write into the output folder {folder}: "
                          f"{exc.strerror or exc}") from exc
    need = BYTES_FIXED + BYTES_PER_PERIOD * max(0, periods)
    free = shutil.disk_usage(folder).free
    if free < need:
        raise OutputError(f"the output folder {folder} has {free / 1e6:.1f} MB free; this run "
                          f"needs about {need / 1e6:.0f} MB")


def write_text(path: Path, text: str) -> None:
    """Writes ``path`` whole or not at all (a temporary file renamed into place)."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from exc


FULL_RATE_FILES = ("plant.trace", "fw.trace", "rig.trace", "capture", "isr.journal")
RUN_FILES = ("capture", "recording.rrd", "result.json", "report.md", "plant.trace", "fw.trace",
             "rig.trace", "figure.png", "scenario.toml", "confirm")
FIGURE_GLOB = "criterion-*.png"  # rig.results.figures: a picture per criterion that did not pass
# what a run may write under names it does not know in advance (the criteria's pictures, the
# logs of a program): the marker lists those it wrote (``Claim.record``), and only they go
RUN_PATTERNS = ("*.stdout.log", "*.stderr.log", "*.ready", FIGURE_GLOB)
SHOWN_ENTRIES = 6


def _entries(folder: Path) -> list[str]:
    """What a folder holds (the write check's probe files aside); [] when it does not exist."""
    try:
        names = os.listdir(folder)
    except FileNotFoundError:
        return []
    except NotADirectoryError:
        raise OutputError(f"the output folder {folder} is not a directory") from None
    except OSError as exc:
        raise OutputError(f"cannot read the output folder {folder}: "
                                 f"{exc.strerror or exc}") from exc
    return sorted(n for n in names if not n.startswith(".rig-write-check-"))


def check_claim(out: Path, what: str = "output folder") -> None:
    """Refuses (OutputError, exit 3) a folder the run may not write into: one that holds
    anything and is not an earlier run of the rig. Nothing is changed."""
    names = _entries(out)
    if names and not is_run_folder(out):
        shown = ", ".join(n + ("/" if (out / n).is_dir() and not (out / n).is_symlink() else "")
                          for n in names[:SHOWN_ENTRIES])
        more = f" and {len(names) - SHOWN_ENTRIES} more" if len(names) > SHOWN_ENTRIES else ""
        raise OutputError(
            f"the {what} {out} holds files that are not a run of the rig ({shown}{more}); "
            "nothing was changed: give --out a new or empty folder, or one an earlier run "
            "wrote")


def _remove(target: Path) -> None:
    """Removes a run's file or folder; a symbolic link is removed itself, never followed."""
    try:
        st = os.lstat(target)
    except FileNotFoundError:
        return
    if stat.S_ISDIR(st.st_mode):
        shutil.rmtree(target)  # (removes links inside it, never what they point to)
    else:
        target.unlink()


def program_files() -> tuple[str, ...]:
    """The files the programs of a run on the bus write into its folder by name (their logs,
    ``rig.supervisor``; their ready files, ``rig.bench.virtual``; the rig's live log of the
    bus, ``rig.bus.can_log``): opened for writing by name, so whatever stands there (a link
    above all) goes before a program starts."""
    from rig.bench import virtual
    from rig.bus import can_log
    from rig.supervisor import log_names

    programs = (virtual.PLANT, virtual.FIRMWARE, virtual.LOADBENCH)
    return (*(n for p in programs for n in log_names(p)), *virtual.READY_FILES.values(),
            *(f"bus{suffix}" for suffix in can_log.FORMATS.values()))


def _matches_run_pattern(name: str) -> bool:
    return "/" not in name and name not in (".", "..") and any(
        fnmatch.fnmatchcase(name, pattern) for pattern in RUN_PATTERNS)


def _marker(out: Path) -> dict[str, Any]:
    """What the marker of a run's folder says (``Claim``): {} when it says nothing (an older
    rig's empty marker), is missing, is not a regular file or not the rig's."""
    marker = out / RUN_MARKER
    try:
        if marker.is_symlink() or not marker.is_file():
            return {}
        data = json.loads(marker.read_text(encoding="utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


class FolderInUse(OutputError):
    """Another run holds the folder (``claim``'s lock)."""


@dataclass
class Claim:
    """A folder a run has made its own: locked against a second run into it at once (an
    advisory lock on the folder, released by ``release`` or when the process ends), and what
    the run found there that matches the names it writes (``RUN_PATTERNS``: the user's,
    never removed) so that ``record`` lists in the marker only what this run wrote."""

    folder: Path
    found: frozenset[str]
    _fd: int | None = None

    def record(self) -> None:
        """Lists in the marker the files of ``RUN_PATTERNS`` this run wrote (the next run into
        the folder removes those and no others)."""
        try:
            names = os.listdir(self.folder)
        except OSError:
            return
        wrote = sorted(n for n in names if _matches_run_pattern(n) and n not in self.found)
        with contextlib.suppress(OutputError):
            write_text(self.folder / RUN_MARKER,
                       json.dumps({"pid": os.getpid(), "wrote": wrote}) + "\n")

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> Claim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _lock(out: Path) -> int:
    """An exclusive lock on the folder (flock on the folder itself), or FolderInUse."""
    try:
        fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError as exc:
        raise OutputError(f"cannot open the output folder {out}: {exc.strerror or exc}") from exc
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        pid = _marker(out).get("pid")
        who = f" (pid {pid})" if isinstance(pid, int) else ""
        raise FolderInUse(
            f"the output folder {out} is in use by another run of the rig{who}; refused, "
            "nothing was changed: give --out another folder, or wait for that run") from None
    except OSError as exc:
        os.close(fd)
        raise OutputError(f"cannot lock the output folder {out}: {exc.strerror or exc}") from exc
    return fd


def claim(out: Path, periods: int, scenario_file: Path | None = None) -> Claim:
    """Makes ``out`` this run's: checked (``check_claim``), locked (a second run into it at the
    same time is refused at once: ``FolderInUse``), checked for room (``prepare``), the files
    of an earlier run in it removed (its fixed ones, ``RUN_FILES`` and ``program_files``, and
    those its marker lists: never a file of the user's that merely matches a run's name
    pattern), marked as a run's folder (``RUN_MARKER``: this process, nothing written yet),
    and the scenario file copied in (when given). Release the claim when the run is done."""
    check_claim(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError:
        prepare(out, periods)  # says why
    fd = _lock(out)
    try:
        prepare(out, periods)
        earlier = _marker(out).get("wrote")
        listed = [n for n in earlier if isinstance(n, str) and _matches_run_pattern(n)] \
            if isinstance(earlier, list) else []
        try:
            for name in (*RUN_FILES, *program_files(), *listed):
                _remove(out / name)
            marker = out / RUN_MARKER
            if marker.is_symlink() or (marker.exists() and not marker.is_file()):
                _remove(marker)
            write_text(marker, json.dumps({"pid": os.getpid(), "wrote": []}) + "\n")
            found = frozenset(n for n in os.listdir(out) if _matches_run_pattern(n))
        except OSError as exc:
            raise OutputError(f"cannot clear the earlier run's files in {out}: "
                              f"{exc.strerror or exc}") from exc
    except BaseException:
        os.close(fd)
        raise
    if scenario_file is not None:
        with contextlib.suppress(OSError):
            shutil.copyfile(scenario_file, out / "scenario.toml")
    return Claim(out, found, fd)


def claim_suite(out: Path, names: Sequence[str], periods: int) -> Claim:
    """A suite's folder claimed like a run's (its summary files replaced) and each scenario's
    folder in it checked before the first scenario starts: a refusal never comes half-way
    through a suite. A scenario's folder may not be a symbolic link."""
    check_claim(out)
    for name in names:
        sub = out / name
        if sub.is_symlink():
            raise OutputError(f"the scenario folder {sub} is a symbolic link; refused "
                                     "(a run never writes through a link)")
        check_claim(sub, "scenario folder")
    return claim(out, periods)


def dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else 0


@dataclass(frozen=True)
class Kept:
    """What the run kept of its full-rate data (traces, capture columns) and what it
    removed (``rig run``'s ``--keep-all``)."""

    full_rate: bool
    policy: str
    removed: list[str] = field(default_factory=list)
    removed_bytes: int = 0
    note: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if k != "note" or v is not None}


def prune(out: Path, *, keep_full: bool, keep: str) -> Kept:
    """Removes the full-rate traces and capture columns of a run that need not keep them;
    returns what was kept and removed (for result.json)."""
    present = [name for name in FULL_RATE_FILES if (out / name).exists()]
    if keep_full:
        return Kept(full_rate=bool(present), policy=keep)
    removed_bytes = 0
    for name in present:
        target = out / name
        if target.is_dir():
            removed_bytes += dir_size(target)
            shutil.rmtree(target)
        else:
            removed_bytes += target.stat().st_size
            target.unlink()
    return Kept(full_rate=False, policy=keep, removed=present,
                removed_bytes=removed_bytes,
                note=("a confirmation run: full-rate traces and capture removed (only its "
                      "values are needed)") if keep == "none" else
                "passed: full-rate traces and capture removed (rig run --keep-all keeps "
                "them)")


def json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


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


def _describe(path: Path, root: Path | None = None) -> RunDir | None:
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
                  auto_named=m is not None, keep=holds_keep(path, root), full_rate=full)


def holds_keep(path: Path, root: Path | None = None) -> bool:
    """A ``KEEP`` file in the folder, in any folder below it (a suite's scenario folder: the
    suite is removed as one, so a KEEP inside keeps all of it) or, with ``root``, in any
    folder above it up to and including ``root`` (``touch out/archive/KEEP`` keeps every run
    filed under ``out/archive``). Symbolic links are not followed (``Path.rglob``)."""
    if (path / KEEP_MARKER).exists() or any(path.rglob(KEEP_MARKER)):
        return True
    return root is not None and any(
        (above / KEEP_MARKER).exists() for above in _folders_above(path, root))


def _folders_above(path: Path, root: Path) -> list[Path]:
    """The folders from ``path``'s parent up to ``root`` (both as given; none when ``path``
    is not below ``root``)."""
    if root not in path.parents:
        return []
    out = []
    for above in path.parents:
        out.append(above)
        if above == root:
            break
    return out


def find_runs(root: Path) -> Iterator[RunDir]:
    """Run folders under ``root`` (a suite's scenario folders belong to the suite)."""
    if not root.is_dir():
        return
    stack = [root]
    while stack:
        folder = stack.pop()
        run = _describe(folder, root) if folder != root else None
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
    if holds_keep(path, base):
        raise ValueError(f"{run.path} holds a {KEEP_MARKER} file, or a folder above it does")
    shutil.rmtree(path)
