"""Runs a scenario: once (``rig.run.single``), or once per seed of its own and decided over
all of them (``rig.run.multi_seed``, ``[run] seeds``), then, when a value lies beyond its
baseline's band, again at fresh seeds to confirm it (``rig.regression.confirm``); and what
``rig run`` exits with."""

from __future__ import annotations

from pathlib import Path

from rig import outputs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_OK
from rig.results.result import RunResult
from rig.run.multi_seed import run_over_own_seeds
from rig.run.options import RunOptions
from rig.run.single import run_single
from rig.scenario import Scenario

__all__ = ["RunOptions", "default_out", "exit_code", "run_scenario"]


def run_scenario(sc: Scenario, opts: RunOptions) -> RunResult:
    """Runs one scenario into ``opts.out``; always writes result.json and report.md."""
    result = run_over_own_seeds(sc, opts) if sc.seeds else run_single(sc, opts)
    if opts.confirm and opts.baseline != "off" and not opts.realtime:
        from rig.regression import confirm

        confirm.confirm(sc, result, opts)
    return result


def exit_code(passed: bool, status: str) -> int:
    if passed:
        return EXIT_OK
    if status == "error":
        return EXIT_ENV
    return EXIT_FAIL


def default_out(name: str) -> Path:
    """``$HIL_OUT`` (else ``./out``) / ``<name>-<YYYYmmdd-HHMMSS>`` (``rig.outputs``)."""
    return outputs.default_out(name)
