"""Where scenarios and suites are: the scenario folder of the package, its suites, and
the file an entry of a suite names; and the files code generates there, written or checked."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

# the folder of the rig package (this module is rig/scenario/files.py)
SCENARIO_DIR = Path(__file__).resolve().parent.parent / "scenarios"
SUITE_DIR = SCENARIO_DIR / "suites"
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def suite_path(entry: str, base: Path) -> Path | None:
    """The file of a suite an ``include`` names (next to the including suite, or in
    SUITE_DIR, or a path)."""
    for cand in (base / f"{entry}.toml", SUITE_DIR / f"{entry}.toml", Path(entry)):
        if cand.is_file():
            return cand
    return None


def scenario_path(entry: str, base: Path) -> Path | None:
    """The file of a scenario a suite names (next to the suite, a path, or in
    SCENARIO_DIR)."""
    p = Path(entry)
    for cand in (base / p, base / f"{entry}.toml", p, SCENARIO_DIR / p,
                 SCENARIO_DIR / f"{entry}.toml"):
        if cand.is_file():
            return cand
    return None


def scenario_files() -> list[Path]:
    return sorted(SCENARIO_DIR.glob("*.toml"))


def suite_files() -> list[Path]:
    return sorted(SUITE_DIR.glob("*.toml"))


def scenario_names() -> list[str]:
    return [p.stem for p in scenario_files()]


def validate_name(name: str) -> bool:
    return bool(_NAME_RE.match(name))


def write_generated(files: Mapping[str, str], folder: Path, check: bool) -> list[str]:
    """Writes each generated file (name: text) into ``folder``; with ``check``, writes
    nothing and returns the names of those missing or different there (stale)."""
    if not check:
        for name, text in files.items():
            (folder / name).write_text(text)
        return []
    return [name for name, text in files.items()
            if not (folder / name).is_file() or (folder / name).read_text() != text]
