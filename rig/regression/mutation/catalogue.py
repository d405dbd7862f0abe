"""The mutation catalogue (``tests/mutants/catalogue.toml``): each mutant an id, a class, a
one-line description, a file and a patch (``find`` must occur exactly once in the file and
becomes ``replace``), or ``equivalent = "why"`` when no behaviour can tell it apart."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from rig import _paths

CATALOGUE = Path("tests") / "mutants" / "catalogue.toml"
CLASSES = ("sign", "gain", "table", "check", "stale", "unit")


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

    def apply(self, text: str) -> str:
        """The file's text with the mutation (exactly one match, or CatalogueError)."""
        n = text.count(self.find)
        if n != 1:
            raise CatalogueError(f"mutant {self.id}: `find` occurs {n} times in {self.file} "
                                 "(must be exactly once)")
        return text.replace(self.find, self.replace)


def default_path() -> Path:
    return _paths.repo_dir() / CATALOGUE


def load(path: Path | None = None, root: Path | None = None) -> list[Mutant]:
    """The catalogue, each mutant checked against the file it patches under ``root``."""
    path = path or default_path()
    root = root or _paths.repo_dir()
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CatalogueError(f"{path}: {exc}") from exc
    out: list[Mutant] = []
    seen: set[str] = set()
    for i, raw in enumerate(data.get("mutant") or []):
        where = f"{path}: mutant #{i + 1}"
        try:
            m = Mutant(str(raw["id"]), str(raw["class"]), str(raw["file"]),
                       str(raw["description"]), str(raw["find"]), str(raw["replace"]),
                       str(raw.get("equivalent", "")))
        except KeyError as exc:
            raise CatalogueError(f"{where}: missing {exc}") from exc
        unknown = set(raw) - {"id", "class", "file", "description", "find", "replace",
                              "equivalent"}
        if unknown:
            raise CatalogueError(f"{where} ({m.id}): unknown keys {sorted(unknown)}")
        if m.id in seen:
            raise CatalogueError(f"{where}: id {m.id!r} appears twice")
        seen.add(m.id)
        if m.cls not in CLASSES:
            raise CatalogueError(f"{where} ({m.id}): class {m.cls!r} is not one of {CLASSES}")
        if m.find == m.replace:
            raise CatalogueError(f"{where} ({m.id}): the patch changes nothing")
        target = root / m.file
        try:
            m.apply(target.read_text(encoding="utf-8"))
        except OSError as exc:
            raise CatalogueError(f"{where} ({m.id}): {target}: {exc.strerror}") from exc
        out.append(m)
    if not out:
        raise CatalogueError(f"{path}: no [[mutant]] entries")
    return out
