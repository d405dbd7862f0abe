"""Where a key of a TOML text is, so a schema error names its line.

tomllib gives values without positions; once it has accepted a text, a small token scanner
maps every key path (and every array element) to its line: ``("speed", 1, "duration")`` is
the ``duration`` of the second ``[[speed]]`` table or of the second inline table in
``speed = [...]``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from functools import cache

Path_ = tuple[str | int, ...]

_PUNCT = set("[]{}=,")
_ATOM_END = set(" \t\r\n[]{}=,#\"'")


def _tokens(text: str) -> Iterator[tuple[str, str, int]]:
    """(kind, value, line): kind is 'punct', 'str', 'atom' or 'nl'."""
    i, line, n = 0, 1, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            yield "nl", c, line
            line += 1
            i += 1
        elif c in " \t\r":
            i += 1
        elif c == "#":
            while i < n and text[i] != "\n":
                i += 1
        elif c in _PUNCT:
            yield "punct", c, line
            i += 1
        elif c in "\"'":
            start_line = line
            triple = text.startswith(c * 3, i)
            quote = c * 3 if triple else c
            j = i + len(quote)
            buf: list[str] = []
            while j < n and not text.startswith(quote, j):
                if text[j] == "\\" and c == '"' and j + 1 < n:
                    buf.append(text[j : j + 2])
                    line += text[j : j + 2].count("\n")
                    j += 2
                    continue
                if text[j] == "\n":
                    line += 1
                buf.append(text[j])
                j += 1
            if triple:
                while text.startswith(c, j + 3):  # up to two extra quotes belong to the string
                    j += 1
            i = j + len(quote)
            yield "str", "".join(buf), start_line
        else:
            j = i
            while j < n and text[j] not in _ATOM_END:
                j += 1
            yield "atom", text[i:j], line
            i = j


class _Locator:
    def __init__(self, text: str) -> None:
        self.lines: dict[Path_, int] = {}
        self._toks = list(_tokens(text))
        self._i = 0
        self._aot: dict[Path_, int] = {}
        try:
            self._document()
        except IndexError:
            pass

    def _peek(self, k: int = 0) -> tuple[str, str, int]:
        j = self._i + k
        return self._toks[j] if j < len(self._toks) else ("eof", "", 0)

    def _next(self) -> tuple[str, str, int]:
        tok = self._peek()
        self._i += 1
        return tok

    def _skip_nl(self) -> None:
        while self._peek()[0] == "nl":
            self._i += 1

    def _key(self) -> list[str]:
        parts: list[str] = []
        while True:
            kind, val, _ = self._peek()
            if kind == "str":
                parts.append(val)
            elif kind == "atom":
                parts.extend(p for p in val.split(".") if p)
            else:
                return parts
            self._i += 1

    def _resolve(self, parts: Sequence[str]) -> Path_:
        out: list[str | int] = []
        for p in parts:
            out.append(p)
            key = tuple(out)
            if key in self._aot:
                out.append(self._aot[key] - 1)
        return tuple(out)

    def _document(self) -> None:
        header: Path_ = ()
        while self._peek()[0] != "eof":
            self._skip_nl()
            kind, val, line = self._peek()
            if kind == "eof":
                break
            if kind == "punct" and val == "[":
                self._i += 1
                is_aot = self._peek()[0] == "punct" and self._peek()[1] == "["
                if is_aot:
                    self._i += 1
                parts = self._key()
                while self._peek()[0] == "punct" and self._peek()[1] == "]":
                    self._i += 1
                if is_aot:
                    base = (*self._resolve(parts[:-1]), parts[-1])
                    idx = self._aot.get(base, 0)
                    self._aot[base] = idx + 1
                    header = (*base, idx)
                    self.lines.setdefault(base, line)
                else:
                    header = self._resolve(parts)
                self.lines[header] = line
                continue
            if kind in ("atom", "str"):
                parts = self._key()
                path = header + tuple(parts)
                self.lines.setdefault(path, line)
                if self._peek()[1] == "=":
                    self._i += 1
                    self._value(path)
                    continue
            # anything unexpected: skip to the end of the line
            while self._peek()[0] not in ("nl", "eof"):
                self._i += 1

    def _value(self, path: Path_) -> None:
        self._skip_nl()
        kind, val, line = self._peek()
        if kind == "punct" and val == "[":
            self._i += 1
            idx = 0
            while True:
                self._skip_nl()
                kind, val, line = self._peek()
                if kind == "eof" or (kind == "punct" and val == "]"):
                    self._i += 1
                    return
                if kind == "punct" and val == ",":
                    self._i += 1
                    continue
                self.lines.setdefault((*path, idx), line)
                self._value((*path, idx))
                idx += 1
        elif kind == "punct" and val == "{":
            self._i += 1
            while True:
                self._skip_nl()
                kind, val, line = self._peek()
                if kind == "eof" or (kind == "punct" and val == "}"):
                    self._i += 1
                    return
                if kind == "punct" and val == ",":
                    self._i += 1
                    continue
                parts = self._key()
                if not parts:
                    self._i += 1
                    continue
                sub = path + tuple(parts)
                self.lines.setdefault(sub, line)
                if self._peek()[1] == "=":
                    self._i += 1
                    self._value(sub)
        else:
            self._i += 1


def too_deep(text: str, limit: int) -> int | None:
    """The line where arrays and inline tables nest deeper than ``limit``, else None (a
    guard before tomllib, which recurses once per level and gives up with RecursionError)."""
    depth = 0
    for kind, value, line in _tokens(text):
        if kind != "punct":
            continue
        if value in "[{":
            depth += 1
            if depth > limit:
                return line
        elif value in "]}":
            depth = max(0, depth - 1)
    return None


def locate(text: str, path: Path_) -> int | None:
    """Line (1-based) of the key or element at ``path``, else of its nearest located parent."""
    lines = _locator(text).lines
    p = tuple(path)
    while p:
        if p in lines:
            return lines[p]
        p = p[:-1]
    return None


@cache
def _locator(text: str) -> _Locator:
    return _Locator(text)
