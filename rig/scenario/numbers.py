"""Numbers as a user's file gives them: TOML integers are unbounded in Python, so a value is
checked for the float range before it is used, and shown shortened in a message."""

from __future__ import annotations

import math
from typing import Any


def finite(v: Any) -> float | None:
    """A TOML number as a finite float; None for anything else (a bool, a string, nan, inf,
    an integer beyond the float range: TOML integers are unbounded in Python)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    try:
        f = float(v)
    except OverflowError:
        return None
    return f if math.isfinite(f) else None


def shown(v: Any, limit: int = 40) -> str:
    """A value as a message shows it: repr, shortened (a 400-digit integer is not quoted)."""
    if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 128:
        return f"an integer of {len(str(abs(v)))} digits"
    text = repr(v)
    return text if len(text) <= limit else text[: limit - 3] + "..."
