"""The machine a benchmark ran on, beside its figures: a shared machine's figures depend on
its load (``os.getloadavg``: 1, 5 and 15 minute averages of runnable processes)."""

from __future__ import annotations

import os
from typing import Any


def load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def described() -> dict[str, Any]:
    """The CPUs and the load average now (``load_average``; a benchmark adds
    ``load_average_after`` when it ends)."""
    return {"host_cpus": os.cpu_count(), "load_average": load_average()}
