"""The versions a run's result records: the rig's (and its checkout's), the libraries', the
wire definitions', and the programs' or the in-process bench library's file digests."""

from __future__ import annotations

import functools
import hashlib
import platform
from importlib import metadata
from pathlib import Path

from rig import __version__, protocols


def sha(path: str | Path) -> str:
    """The first 16 hex digits of a file's SHA-256 (``unavailable`` when unreadable)."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return "unavailable"
    return h.hexdigest()[:16]


def commit() -> str | None:
    """The rig's checkout (``git describe --always --dirty``), when it is one."""
    import subprocess

    try:
        done = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), "describe",
                               "--always", "--dirty", "--abbrev=12"], capture_output=True,
                              text=True, timeout=5, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() or None if done.returncode == 0 else None


def versions(plant: str | None = None, fw: str | None = None) -> dict[str, str]:
    out = dict(_this_process())
    if plant:
        out["plant_rt.sha256"] = sha(plant)
    if fw:
        out["fw_host.sha256"] = sha(fw)
    return out


@functools.lru_cache(maxsize=1)
def _this_process() -> dict[str, str]:
    """What this process runs: the rig and its checkout, the libraries, the wire definitions.
    Asked once per process (a worker runs many scenarios: the packages' metadata and ``git
    describe`` cost ~25 ms of CPU a run), which is also what the process has loaded."""
    out = {"rig": __version__, "python": platform.python_version()}
    checkout = commit()
    if checkout:
        out["rig.commit"] = checkout
    for dist in ("numpy", "cantools", "python-can", "rerun-sdk"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    for db in protocols.DATABASES:
        out[f"dbc.{db}"] = str(protocols.database(db).version)
    return out
