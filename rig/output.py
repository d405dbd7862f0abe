"""The run's output folder: checked before any program starts, written atomically.

A path through a file, a folder under /proc, a read-only folder or a disk without room is
an environment problem (exit 3) found before plant_rt and fw_host start, and a result file
is either complete or not there: written to a temporary name and renamed into place, never
left truncated by a full disk.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

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
