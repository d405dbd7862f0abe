"""The portability scan (firmware_c2000/tools/check_portability.py) passes on the core and
fails on each kind of violation it is meant to catch."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
TOOL = ROOT / "firmware_c2000" / "tools" / "check_portability.py"


def scan(core: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(TOOL), "scan", str(core)], capture_output=True, text=True, check=False
    )


def test_the_core_is_clean() -> None:
    proc = scan(ROOT / "firmware_c2000" / "core")
    assert proc.returncode == 0, proc.stdout


CLEAN = """#include <stdint.h>
#include "fw_types.h"
/* int, char, malloc(), printf() in a comment are fine */
static const char *name = "int char double";
int16_t add(int16_t a, int16_t b) { return (int16_t)(a + b); }
"""


@pytest.mark.parametrize(
    ("snippet", "rule"),
    [
        ("void *p(void) { return malloc(4); }", "heap"),
        ("#include <stdio.h>", "hosted header"),
        ('void f(void) { printf("x"); }', "stdio"),
        ("uint8_t x;", "8-bit type"),
        ("int x;", "plain integer type"),
        ("unsigned y;", "plain integer type"),
        ("long z;", "plain integer type"),
        ("char c = 'a' + 1;", "char arithmetic"),
        ("double d;", "double"),
        ("float f;", "float outside real_t"),
        ("void g(void) { while (1) { } }", "unbounded loop"),
        ("int16_t r(int16_t n) { return n ? r((int16_t)(n - 1)) : 0; }", "recursion"),
    ],
)
def test_each_violation_is_caught(tmp_path: Path, snippet: str, rule: str) -> None:
    (tmp_path / "src").mkdir()
    (tmp_path / "include").mkdir()
    (tmp_path / "src" / "ok.c").write_text(CLEAN, encoding="utf-8")
    assert scan(tmp_path).returncode == 0
    (tmp_path / "src" / "bad.c").write_text(CLEAN + snippet + "\n", encoding="utf-8")
    proc = scan(tmp_path)
    assert proc.returncode == 1
    assert f": {rule}:" in proc.stdout
