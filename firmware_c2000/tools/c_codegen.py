"""Helpers shared by the build-time C generators (gen_params.py, gen_console.py): C string
literals and writing a generated file only when its text changed, so that an unchanged table
does not make the build recompile everything that includes it."""

from __future__ import annotations

from pathlib import Path


def c_string(s: str) -> str:
    """A C string literal for s (backslashes and double quotes escaped)."""
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def write_if_changed(path: Path, text: str) -> None:
    if path.exists() and path.read_text(encoding="utf-8") == text:
        return
    path.write_text(text, encoding="utf-8")
