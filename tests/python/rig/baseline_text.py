"""Edits of a baseline file's text for tests: one criterion's line with every number scaled
(a baseline that says the drive did better or worse than it does, consistent in itself)."""

from __future__ import annotations

import re

KEYS = ("value", "lo", "hi", "sd", "min", "max")


def scaled(text: str, name: str, factor: float) -> str:
    """``text`` with the line of criterion ``name`` scaled by ``factor`` (value, band, sd,
    range and every seed's value)."""
    out = []
    for line in text.splitlines():
        if line.startswith((f'"{name}" ', f"{name} ")):
            head, _, rest = line.partition("{")
            for key in KEYS:
                rest = re.sub(rf"\b{key} = ([-0-9.e+]+)",
                              lambda m, k=key: f"{k} = {float(m.group(1)) * factor!r}", rest)
            rest = re.sub(r"values = \[([^\]]*)\]", lambda m: "values = [" + ", ".join(
                repr(float(x) * factor) for x in m.group(1).split(",")) + "]", rest)
            line = head + "{" + rest
        out.append(line)
    return "\n".join(out) + "\n"
