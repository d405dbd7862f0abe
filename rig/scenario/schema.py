"""Schema errors with their position (``file:line: field: message``) and the checker that
reads a scenario or suite document's fields, collecting every error instead of stopping
at the first."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.scenario.numbers import finite, shown
from rig.scenario.positions import Path_, locate, too_deep

__all__ = ["Checker", "Issue", "ScenarioError", "finite", "shown"]

MAX_NESTING = 32  # arrays and inline tables in a scenario or suite file (they need 3)
BOM = "\ufeff"


@dataclass(frozen=True)
class Issue:
    file: str
    line: int | None
    field: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line else self.file
        if self.field:
            return f"{where}: {self.field}: {self.message}"
        return f"{where}: {self.message}"


class ScenarioError(ValueError):
    """One or more schema errors; ``str()`` gives one ``file:line: field: message`` per line."""

    def __init__(self, issues: Sequence[Issue]) -> None:
        self.issues = list(issues)
        super().__init__("\n".join(str(i) for i in self.issues))


def field_name(path: Path_) -> str:
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else part
    return out


class Checker:
    def __init__(self, file: Path, text: str) -> None:
        self.file = file
        self.text = text
        self.issues: list[Issue] = []

    def err(self, path: Path_, message: str) -> None:
        line = locate(self.text, path)
        self.issues.append(Issue(str(self.file), line, field_name(path), message))

    def table(self, data: Any, path: Path_, allowed: Iterable[str]) -> dict[str, Any]:
        if not isinstance(data, dict):
            self.err(path, f"must be a table, not {type(data).__name__}")
            return {}
        allowed = set(allowed)
        for key in data:
            if key not in allowed:
                self.err(
                    (*path, key),
                    f"unknown field (allowed here: {', '.join(sorted(allowed))})",
                )
        return data

    def number(
        self,
        data: Mapping[str, Any],
        path: Path_,
        key: str,
        default: float | None = None,
        *,
        minimum: float | None = None,
        maximum: float | None = None,
        positive: bool = False,
    ) -> float:
        p = (*path, key)
        if key not in data:
            if default is None:
                self.err(p, "required number is missing")
                return 0.0
            return default
        v = finite(data[key])
        if v is None:
            self.err(p, f"must be a finite number, not {shown(data[key])}")
            return default if default is not None else 0.0
        if positive and v <= 0:
            self.err(p, f"must be > 0, not {v!r}")
        if minimum is not None and v < minimum:
            self.err(p, f"must be >= {minimum:g}, not {v!r}")
        if maximum is not None and v > maximum:
            self.err(p, f"must be <= {maximum:g}, not {v!r}")
        return float(v)

    def string(
        self,
        data: Mapping[str, Any],
        path: Path_,
        key: str,
        default: str | None = None,
        choices: Iterable[str] | None = None,
    ) -> str:
        p = (*path, key)
        if key not in data:
            if default is None:
                self.err(p, "required string is missing")
                return ""
            return default
        v = data[key]
        if not isinstance(v, str):
            self.err(p, f"must be a string, not {v!r}")
            return default or ""
        if choices is not None:
            options = list(choices)
            if v.lower() not in options:
                self.err(p, f"{v!r} is not one of: {', '.join(options)}")
                return default or ""
            return v.lower()
        return v


def read_text(path: Path) -> str:
    """A scenario or suite file as text; not UTF-8 is a schema error at its line."""
    raw = path.read_bytes()
    try:
        # a byte order mark (editors on Windows write one) is not part of the TOML text
        return raw.decode("utf-8").removeprefix(BOM)
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise ScenarioError([Issue(str(path), line, "",
                                   f"not UTF-8 (byte 0x{raw[exc.start]:02x}): TOML files "
                                   "are UTF-8")]) from None


def parse_toml(file: Path, text: str) -> dict[str, Any]:
    """The document; a syntax error is a schema error at its line."""
    text = text.removeprefix(BOM)
    deep = too_deep(text, MAX_NESTING)
    if deep is not None:
        raise ScenarioError([Issue(str(file), deep, "", f"arrays or inline tables nested more "
                                   f"than {MAX_NESTING} deep")])
    try:
        return tomllib.loads(text)
    except RecursionError:  # the guard above should have caught it
        raise ScenarioError([Issue(str(file), None, "", "nested too deeply")]) from None
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+)", str(exc))
        raise ScenarioError(
            [Issue(str(file), int(m.group(1)) if m else None, "", f"TOML syntax: {exc}")]
        ) from exc
