"""A run's folder: made ready before anything starts (``rig.output``: a folder that cannot
take the results is exit 3, not a traceback at the end), the full-rate data removed when the
run need not keep it, ``result.json`` and ``report.md`` written whole.

What a run may write over: only a new or empty folder, or one an earlier run of the rig
wrote (``rig.outdirs.is_run_folder``), and there only the files a run writes (``RUN_FILES``
and the programs' logs); a folder holding anything else is refused before anything starts.
No symbolic link is followed there: a link in place of a run's file is removed, not its
target.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rig import capture, outdirs, output, report
from rig.run.result import Kept, RunResult
from rig.scenario import Scenario

FULL_RATE_FILES = ("plant.trace", "fw.trace", "rig.trace", "capture")
RUN_FILES = ("capture", "recording.rrd", "result.json", "report.md", "plant.trace", "fw.trace",
             "rig.trace", "figure.png", "scenario.toml")
FIGURE_GLOB = "criterion-*.png"  # rig.figures: a picture per criterion that did not pass
# the programs' logs and ready files (rig.supervisor, rig.link.bench): opened for writing by
# name, so a link there must go before a program follows it; the criteria's pictures
RUN_PATTERNS = ("*.stdout.log", "*.stderr.log", "*.ready", FIGURE_GLOB)
SHOWN_ENTRIES = 6


def _entries(folder: Path) -> list[str]:
    """What a folder holds (the write check's probe files aside); [] when it does not exist."""
    try:
        names = os.listdir(folder)
    except FileNotFoundError:
        return []
    except NotADirectoryError:
        raise output.OutputError(f"the output folder {folder} is not a directory") from None
    except OSError as exc:
        raise output.OutputError(f"cannot read the output folder {folder}: "
                                 f"{exc.strerror or exc}") from exc
    return sorted(n for n in names if not n.startswith(".rig-write-check-"))


def check_claim(out: Path, what: str = "output folder") -> None:
    """Refuses (OutputError, exit 3) a folder the run may not write into: one that holds
    anything and is not an earlier run of the rig. Nothing is changed."""
    names = _entries(out)
    if names and not outdirs.is_run_folder(out):
        shown = ", ".join(n + ("/" if (out / n).is_dir() and not (out / n).is_symlink() else "")
                          for n in names[:SHOWN_ENTRIES])
        more = f" and {len(names) - SHOWN_ENTRIES} more" if len(names) > SHOWN_ENTRIES else ""
        raise output.OutputError(
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


def claim(out: Path, periods: int) -> None:
    """Makes ``out`` this run's: checked (``check_claim``), checked for room
    (``rig.output.prepare``), the files of an earlier run in it removed, and marked as a
    run's folder (``rig.outdirs.RUN_MARKER``)."""
    check_claim(out)
    output.prepare(out, periods)
    try:
        for name in RUN_FILES:
            _remove(out / name)
        for pattern in RUN_PATTERNS:
            for target in out.glob(pattern):
                _remove(target)
        marker = out / outdirs.RUN_MARKER
        if marker.is_symlink() or not marker.is_file():
            _remove(marker)
            marker.touch()
    except OSError as exc:
        raise output.OutputError(f"cannot clear the earlier run's files in {out}: "
                                 f"{exc.strerror or exc}") from exc


def claim_suite(out: Path, names: Sequence[str], periods: int) -> None:
    """A suite's folder claimed like a run's (its summary files replaced) and each scenario's
    folder in it checked before the first scenario starts: a refusal never comes half-way
    through a suite. A scenario's folder may not be a symbolic link."""
    check_claim(out)
    for name in names:
        sub = out / name
        if sub.is_symlink():
            raise output.OutputError(f"the scenario folder {sub} is a symbolic link; refused "
                                     "(a run never writes through a link)")
        check_claim(sub, "scenario folder")
    claim(out, periods)


def prepare(out: Path, sc: Scenario) -> None:
    """The folder claimed for the run (``claim``), the scenario file copied in."""
    claim(out, round(sc.duration / capture.TS))
    with contextlib.suppress(OSError):
        shutil.copyfile(sc.file, out / "scenario.toml")


def dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else 0


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
                note="passed: full-rate traces and capture removed (rig run --keep-all keeps "
                "them)")


def json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_result(result: RunResult) -> None:
    """result.json and report.md, each written whole or not at all."""
    data = result.to_json()
    output.write_text(result.out_dir / "result.json",
                      json.dumps(data, indent=1, default=json_default))
    output.write_text(result.out_dir / "report.md", report.scenario_report(data))
