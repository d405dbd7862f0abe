"""The mutation catalogue (``tests/mutants/catalogue.toml``): each mutant an id, a class, a
one-line description, a file and a patch (``find`` must occur exactly once in the file and
becomes ``replace``), or ``equivalent = "why"`` when no behaviour can tell it apart.

Two kinds of mutant: the harmful ones (classes sign, gain, table, check, stale, unit: a bug
the gate must catch; cost: work added with the same outputs, which the gate catches by the
ISR's instructions on the target, rig.target_m4.cost) and the ``benign`` ones (a change of
rounding only: a reassociation, a reciprocal multiply, an expanded product, a build with
fused multiply-add; the gate must let them pass, and the share it fails is its false-alarm
rate).

A catalogue is input from a user: every field is checked for its type, an id is a plain name,
and a mutant patches only a regular text file inside the tree (no absolute path, no ``..``,
no link out of it, no device or FIFO, at most ``MAX_FILE_BYTES``); anything else is a
:class:`CatalogueError` that names the file and the mutant.
"""

from __future__ import annotations

import os
import re
import stat
import tomllib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from rig import _paths

CATALOGUE = Path("tests") / "mutants" / "catalogue.toml"
HARMFUL = ("sign", "gain", "table", "check", "stale", "unit", "cost")
BENIGN = "benign"
CLASSES = (*HARMFUL, BENIGN)
KEYS = ("id", "class", "file", "description", "find", "replace", "equivalent")
ID = re.compile(r"[a-z0-9][a-z0-9_-]{0,63}")
MAX_FILE_BYTES = 4 << 20


class CatalogueError(ValueError):
    """A catalogue that cannot be read, or a mutant that does not apply."""


@dataclass(frozen=True)
class Mutant:
    id: str
    cls: str
    file: str
    description: str
    find: str
    replace: str
    equivalent: str = ""

    @property
    def benign(self) -> bool:
        return self.cls == BENIGN

    def apply(self, text: str) -> str:
        """The file's text with the mutation (exactly one match, or CatalogueError)."""
        n = text.count(self.find)
        if n != 1:
            raise CatalogueError(f"mutant {self.id}: `find` occurs {n} times in {self.file} "
                                 "(must be exactly once)")
        return text.replace(self.find, self.replace)


def default_path() -> Path:
    return _paths.repo_dir() / CATALOGUE


def inside(root: Path, rel: str) -> Path:
    """``root / rel`` for a relative path that stays inside ``root`` (no absolute path, no
    ``..``, no link leading out), or CatalogueError."""
    p = PurePosixPath(rel)
    if not rel or p.is_absolute() or ".." in p.parts or "\0" in rel:
        raise CatalogueError(f"file {rel!r} must be a path inside the tree (relative, "
                             "without ..)")
    target = root / rel
    real_root = root.resolve()
    try:
        real = target.resolve(strict=True)
    except (OSError, RuntimeError) as exc:
        raise CatalogueError(f"file {rel!r}: {getattr(exc, 'strerror', None) or exc}"
                             ) from exc
    if real != real_root and real_root not in real.parents:
        raise CatalogueError(f"file {rel!r} leads out of the tree (to {real})")
    return target


def read_text(path: Path, rel: str) -> str:
    """A regular file's text, read without blocking on a FIFO or growing without bound."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
    except OSError as exc:
        raise CatalogueError(f"file {rel!r}: {exc.strerror or exc}") from exc
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise CatalogueError(f"file {rel!r} is not a regular file")
        if st.st_size > MAX_FILE_BYTES:
            raise CatalogueError(f"file {rel!r} is {st.st_size} bytes (at most "
                                 f"{MAX_FILE_BYTES})")
        data = os.read(fd, MAX_FILE_BYTES + 1)
    finally:
        os.close(fd)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CatalogueError(f"file {rel!r} is not UTF-8 text") from exc


def _field(raw: dict[str, Any], key: str, where: str, required: bool = True) -> str:
    v = raw.get(key)
    if v is None and not required:
        return ""
    if v is None:
        raise CatalogueError(f"{where}: missing {key!r}")
    if not isinstance(v, str):
        raise CatalogueError(f"{where}: {key} must be a string (got {type(v).__name__})")
    return v


def load(path: Path | None = None, root: Path | None = None) -> list[Mutant]:
    """The catalogue, each mutant checked against the file it patches under ``root``."""
    path = path or default_path()
    root = root or _paths.repo_dir()
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, ValueError,
            RecursionError) as exc:
        raise CatalogueError(f"{path}: {exc}") from exc
    mutants = data.get("mutant")
    if mutants is None:
        raise CatalogueError(f"{path}: no [[mutant]] entries")
    if not isinstance(mutants, list):
        raise CatalogueError(f"{path}: `mutant` must be an array of tables ([[mutant]])")
    out: list[Mutant] = []
    seen: set[str] = set()
    for i, raw in enumerate(mutants):
        where = f"{path}: mutant #{i + 1}"
        if not isinstance(raw, dict):
            raise CatalogueError(f"{where}: must be a table")
        m = Mutant(*(_field(raw, k, where, required=k != "equivalent") for k in KEYS))
        where = f"{where} ({m.id[:64]})"
        unknown = set(raw) - set(KEYS)
        if unknown:
            raise CatalogueError(f"{where}: unknown keys {sorted(unknown)[:10]}")
        if not ID.fullmatch(m.id):
            raise CatalogueError(f"{where}: id must be lower-case letters, digits, - and _ "
                                 "(at most 64)")
        if m.id in seen:
            raise CatalogueError(f"{where}: id {m.id!r} appears twice")
        seen.add(m.id)
        if m.cls not in CLASSES:
            raise CatalogueError(f"{where}: class {m.cls!r} is not one of {CLASSES}")
        if m.find == m.replace:
            raise CatalogueError(f"{where}: the patch changes nothing")
        try:
            m.apply(read_text(inside(root, m.file), m.file))
        except CatalogueError as exc:
            raise CatalogueError(f"{where}: {exc}") from exc
        out.append(m)
    if not out:
        raise CatalogueError(f"{path}: no [[mutant]] entries")
    return out
