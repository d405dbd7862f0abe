"""Why a run stops early, besides a program's exit (``rig.supervisor.ChildFailed``) and an
interrupt."""

from __future__ import annotations


class RunError(RuntimeError):
    """The run could not go on: stall, time-out, bus error. ``kind`` names the reason."""

    def __init__(self, kind: str, message: str, log_tail: str = "") -> None:
        self.kind = kind
        self.log_tail = log_tail
        super().__init__(message)


class EnvironmentProblem(RuntimeError):
    """The run cannot start here (programs not built, bus unavailable)."""
