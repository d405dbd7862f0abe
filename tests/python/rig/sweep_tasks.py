"""A sweep task for the Dask test that kills its own worker process the first time it runs
one chosen point (a marker file remembers it), then runs the point as ``rig sweep`` does.
The workers cannot import tests/: the test registers this module for pickling by value."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rig.sweep import point as sweep_point


def die_once_at(marker: str, victim: int) -> Callable[[sweep_point.Task], dict[str, Any]]:
    def run(task: sweep_point.Task) -> dict[str, Any]:
        if task.index == victim and not Path(marker).exists():
            Path(marker).write_text(str(os.getpid()))
            os._exit(9)  # the worker process dies with the task in hand
        return sweep_point.run(task)

    return run
