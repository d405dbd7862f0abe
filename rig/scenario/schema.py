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


MAX_SHOWN = 40  # schema errors printed for one file (the rest counted)
UNKNOWN_SHOWN = 20  # unknown fields of one table named one by one (the rest counted)


class ScenarioError(ValueError):
    """One or more schema errors; ``str()`` gives one ``file:line: field: message`` per line,
    at most ``MAX_SHOWN`` of them and a count of the rest."""

    def __init__(self, issues: Sequence[Issue]) -> None:
        self.issues = list(issues)
        lines = [str(i) for i in self.issues[:MAX_SHOWN]]
        if len(self.issues) > MAX_SHOWN:
            lines.append(f"... and {len(self.issues) - MAX_SHOWN} more errors")
        super().__init__("\n".join(lines))


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
        unknown = [key for key in data if key not in allowed]
        for key in unknown[:UNKNOWN_SHOWN]:
            self.err(
                (*path, key),
                f"unknown field (allowed here: {', '.join(sorted(allowed))})",
            )
        if len(unknown) > UNKNOWN_SHOWN:
            self.err(path, f"{len(unknown) - UNKNOWN_SHOWN} more unknown fields")
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


MAX_FILE_BYTES = 1 << 20  # a scenario or suite is written by hand: 1 MiB is far beyond one


def read_text(path: Path) -> str:
    """A scenario or suite file as text; not UTF-8, or larger than any such file is, is a
    schema error."""
    with open(path, "rb") as fh:
        raw = fh.read(MAX_FILE_BYTES + 1)
    if len(raw) > MAX_FILE_BYTES:
        raise ScenarioError([Issue(str(path), None, "", f"larger than {MAX_FILE_BYTES} bytes: "
                                   "not a scenario or suite file")])
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
        data = tomllib.loads(text)
    except RecursionError:  # the guard above should have caught it
        raise ScenarioError([Issue(str(file), None, "", "nested too deeply")]) from None
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+)", str(exc))
        raise ScenarioError(
            [Issue(str(file), int(m.group(1)) if m else None, "", f"TOML syntax: {exc}")]
        ) from exc
    except ValueError as exc:  # an integer beyond Python's digit limit, inside tomllib
        m = re.search(r"\d{" + str(MAX_DIGITS) + ",}", text)
        line = text.count("\n", 0, m.start()) + 1 if m else None
        raise ScenarioError([Issue(str(file), line, "", f"a number of more than {MAX_DIGITS} "
                                   "digits")]) from exc
    if _depth(data) > MAX_NESTING:  # table headers and dotted keys nest without brackets
        raise ScenarioError([Issue(str(file), _deep_key_line(text), "",
                                   f"tables nested more than {MAX_NESTING} deep")])
    return data


MAX_DIGITS = 400  # no number a scenario takes has more; Python's own limit is 4300


def _depth(data: Any) -> int:
    """How deep tables and arrays nest in a parsed document (iterative: no recursion)."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(data, 0)]
    while stack:
        node, d = stack.pop()
        deepest = max(deepest, d)
        if isinstance(node, dict):
            stack.extend((v, d + 1) for v in node.values())
        elif isinstance(node, list):
            stack.extend((v, d + 1) for v in node)
    return deepest


def _deep_key_line(text: str) -> int | None:
    """The first line whose table header or key has more dotted parts than MAX_NESTING."""
    for n, line in enumerate(text.splitlines(), 1):
        key = line.split("=", 1)[0] if "=" in line else line
        if key.count(".") >= MAX_NESTING:
            return n
    return None
