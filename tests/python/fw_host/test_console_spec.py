"""protocols/console.md (prose) and protocols/console.json (table) say the same thing."""

from __future__ import annotations

import json
import re
from typing import Any

from rig import protocols

DIR = protocols.path("drive").parent
SPEC: dict[str, Any] = json.loads((DIR / "console.json").read_text())
DOC = (DIR / "console.md").read_text()


def table_rows(heading: str) -> list[list[str]]:
    """Rows of the first markdown table after a heading."""
    part = DOC.split(heading, 1)[1]
    rows = []
    for line in part.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip("|"))]
            if not set("".join(cells)) <= set("-: "):
                rows.append(cells)
        elif rows:
            break
    return rows[1:]  # without the header


def test_commands_agree() -> None:
    rows = table_rows("## Commands")
    doc_names = [r[0].strip("`").split()[0] for r in rows]
    assert doc_names == [c["name"] for c in SPEC["commands"]]
    for row, cmd in zip(rows, SPEC["commands"], strict=True):
        words = row[0].strip("`").split()
        assert len(words) - 1 == len(cmd["args"]), cmd["name"]
        for arg in cmd["args"]:
            if arg["type"] == "choice":
                for choice in arg["choices"]:
                    assert f"`{choice}`" in row[1], (cmd["name"], choice)


def test_error_codes_agree() -> None:
    rows = table_rows("## Error codes")
    assert [(int(r[0]), r[1]) for r in rows] == [(e["code"], e["name"])
                                                 for e in SPEC["errors"]]


def test_line_rules_agree() -> None:
    assert f"| maximum line | {SPEC['max_line']} characters" in DOC
    assert f"# SCI console protocol (version {SPEC['version']})" in DOC
    assert f'"{SPEC["data_prefix"]}"' in DOC
