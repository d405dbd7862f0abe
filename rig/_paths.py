"""Where the rig finds its compiled programs, shared libraries and data files.

Binaries are built by the package install (scikit-build-core drives CMake) and shipped in
``rig/_bin`` and ``rig/_lib``. When Python runs from a source checkout the package directory
has no ``_bin``; the installed distribution's copy is used then. ``HIL_BIN_DIR`` overrides
both (a CMake build directory during development).
"""

from __future__ import annotations

import os
from importlib import metadata
from pathlib import Path

_PKG = Path(__file__).resolve().parent
_REPO = _PKG.parent
_DIST = "sensorless-hil"


def _installed_pkg_dir() -> Path | None:
    try:
        dist = metadata.distribution(_DIST)
    except metadata.PackageNotFoundError:
        return None
    path = Path(str(dist.locate_file("rig")))
    return path if path.is_dir() else None


def _search_dirs(sub: str) -> list[Path]:
    dirs: list[Path] = []
    env = os.environ.get("HIL_BIN_DIR")
    if env:
        dirs.append(Path(env))
    dirs.append(_PKG / sub)
    installed = _installed_pkg_dir()
    if installed is not None:
        dirs.append(installed / sub)
    return dirs


def _find(sub: str, name: str) -> Path:
    tried = _search_dirs(sub)
    for d in tried:
        candidate = d / name
        if candidate.is_file():
            return candidate
    where = ", ".join(str(d) for d in tried)
    raise FileNotFoundError(
        f"{name} not found (looked in {where}); install the package first: ./hil install"
    )


def repo_dir() -> Path:
    """The source checkout the package runs from (its git work tree, for provenance)."""
    return _REPO


def binary(name: str) -> Path:
    """Path of a compiled program (``plant_rt``, ``fw_host``, ...)."""
    return _find("_bin", name)


def library(name: str) -> Path:
    """Path of a compiled shared library (``libplant_core.so``, ...)."""
    return _find("_lib", name)


def data_dir(kind: str) -> Path:
    """``protocols`` or ``profiles``: the checkout's own files when running from source."""
    source = {"protocols": _REPO / "protocols", "profiles": _REPO / "plant_rt" / "profiles"}
    if kind not in source:
        raise ValueError(f"unknown data kind {kind!r}")
    if (source[kind]).is_dir() and (_REPO / "pyproject.toml").is_file():
        return source[kind]
    for base in (_PKG, _installed_pkg_dir()):
        if base is not None and (base / "_data" / kind).is_dir():
            return base / "_data" / kind
    raise FileNotFoundError(f"data folder {kind!r} not found; install the package: ./hil install")
