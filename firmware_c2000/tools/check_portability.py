#!/usr/bin/env python3
"""Portability checks of the control core (C28x rules, docs/design.md section 6).

``scan CORE_DIR``
    Static scan of ``CORE_DIR/src`` and ``CORE_DIR/include`` (comments and literals removed):
    fails on heap use, stdio and other hosted headers, 8-bit types, plain ``int``/``unsigned``/
    ``short``/``long``/``signed``/``size_t``/``double`` (the core uses explicit widths and
    ``real_t``), ``char`` other than ``const char *`` string pointers, ``float`` outside
    ``fw_types.h``, unbounded ``while (1)``/``for (;;)`` loops and direct recursion.

``compile --cc CC --sources a.c,b.c --includes dir1,dir2``
    Compiles every source freestanding: ``CC -std=c99 -ffreestanding -Wall -Wextra -Werror
    -Wpedantic -c``.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

RULES: list[tuple[str, re.Pattern[str]]] = [
    ("heap", re.compile(r"\b(malloc|calloc|realloc|free|alloca)\s*\(")),
    (
        "hosted header",
        re.compile(r"#\s*include\s*<(stdio|stdlib|string|time|signal|setjmp|pthread|unistd)\.h>"),
    ),
    ("stdio", re.compile(r"\b(f?printf|s?n?printf|puts|putchar|fopen|fwrite|fread|scanf)\s*\(")),
    ("8-bit type", re.compile(r"\bu?int(_least|_fast)?8_t\b")),
    ("plain integer type", re.compile(r"\b(int|unsigned|short|long|signed)\b")),
    ("width-varying type", re.compile(r"\b(size_t|ptrdiff_t|wchar_t)\b")),
    ("double", re.compile(r"\bdouble\b")),
    ("unbounded loop", re.compile(r"\bwhile\s*\(\s*(1|true)\s*\)|\bfor\s*\(\s*;\s*;\s*\)")),
]
CHAR_OK = re.compile(r"\bconst\s+char\s*\*")
CHAR_ANY = re.compile(r"\bchar\b")
FLOAT_KW = re.compile(r"\bfloat\b")
FUNC_DEF = re.compile(r"^[A-Za-z_][\w\s\*]*?\b([A-Za-z_]\w*)\s*\([^;{}]*\)\s*\{", re.MULTILINE)


@dataclass(frozen=True)
class Violation:
    path: Path
    line: int
    rule: str
    text: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.rule}: {self.text.strip()}"


def strip_code(src: str) -> str:
    """Blank out comments, string and character literals, keeping line structure."""
    out: list[str] = []
    i = 0
    n = len(src)
    while i < n:
        c = src[i]
        if src.startswith("/*", i):
            j = src.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
        elif src.startswith("//", i):
            j = src.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif c in "\"'":
            j = i + 1
            while j < n and src[j] != c:
                j += 2 if src[j] == "\\" else 1
            out.append(c + " " * (min(j, n) - i - 1) + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def _function_bodies(code: str) -> list[tuple[str, int, int]]:
    """(name, body_start, body_end) of every function definition (brace matching)."""
    result: list[tuple[str, int, int]] = []
    for m in FUNC_DEF.finditer(code):
        name = m.group(1)
        if name in ("if", "for", "while", "switch", "return", "sizeof"):
            continue
        start = m.end() - 1
        depth = 0
        for j in range(start, len(code)):
            if code[j] == "{":
                depth += 1
            elif code[j] == "}":
                depth -= 1
                if depth == 0:
                    result.append((name, start, j))
                    break
    return result


def scan_file(path: Path) -> list[Violation]:
    raw = path.read_text(encoding="utf-8")
    code = strip_code(raw)
    lines = code.splitlines()
    raw_lines = raw.splitlines()
    found: list[Violation] = []
    for lineno, line in enumerate(lines, start=1):
        if re.match(r"\s*#\s*include\s*<", line):
            # a header name is not code: only the hosted-header rule applies
            if RULES[1][1].search(line):
                found.append(Violation(path, lineno, RULES[1][0], raw_lines[lineno - 1]))
            continue
        for rule, pattern in RULES:
            if pattern.search(line):
                found.append(Violation(path, lineno, rule, raw_lines[lineno - 1]))
        if CHAR_ANY.search(CHAR_OK.sub("", line)):
            found.append(Violation(path, lineno, "char arithmetic", raw_lines[lineno - 1]))
        if path.name != "fw_types.h" and FLOAT_KW.search(line):
            found.append(Violation(path, lineno, "float outside real_t", raw_lines[lineno - 1]))
    for name, start, end in _function_bodies(code):
        body = code[start + 1 : end]
        if re.search(rf"\b{re.escape(name)}\s*\(", body):
            lineno = code.count("\n", 0, start) + 1
            found.append(Violation(path, lineno, "recursion", f"{name} calls itself"))
    return found


def scan(core_dir: Path) -> int:
    files = sorted((core_dir / "src").glob("*.c")) + sorted((core_dir / "include").glob("*.h"))
    if not files:
        print(f"check_portability: no sources under {core_dir}", file=sys.stderr)
        return 2
    violations = [v for f in files for v in scan_file(f)]
    for v in violations:
        print(v)
    print(f"check_portability scan: {len(files)} files, {len(violations)} violations")
    return 1 if violations else 0


def compile_all(cc: str, sources: list[str], includes: list[str]) -> int:
    flags = ["-std=c99", "-ffreestanding", "-Wall", "-Wextra", "-Werror", "-Wpedantic"]
    inc = [f"-I{d}" for d in includes if d]
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        for i, src in enumerate(s for s in sources if s):
            obj = Path(tmp) / f"{i}.o"
            cmd = [cc, *flags, *inc, "-c", src, "-o", str(obj)]
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                failures += 1
                print(" ".join(cmd))
                print(proc.stdout + proc.stderr)
    print(f"check_portability compile ({cc}): {len(sources)} sources, {failures} failed")
    return 1 if failures else 0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    p_scan = sub.add_parser("scan")
    p_scan.add_argument("core_dir", type=Path)
    p_cc = sub.add_parser("compile")
    p_cc.add_argument("--cc", required=True)
    p_cc.add_argument("--sources", required=True)
    p_cc.add_argument("--includes", required=True)
    args = parser.parse_args(argv)
    if args.mode == "scan":
        return scan(args.core_dir)
    return compile_all(args.cc, args.sources.split(","), args.includes.split(","))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
