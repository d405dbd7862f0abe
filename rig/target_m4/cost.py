"""The ISR's cost on the emulated Cortex-M4F as a value of a run: the instructions of every
journalled period, in total and by step of ``fw_core_isr``, for the criteria of
``rig.data.metrics`` (``isr_instructions_median``, ``isr_instructions_max``).

A run on the in-process bench whose scenario has such criteria journals the core over their
windows (``journal_windows``) into ``isr.journal``; after the run the journal is replayed on
the image with every instruction counted (``measure``). The counts are a function of the
image and the journal alone (the emulator is deterministic), so they are kept in a cache per
firmware build: ``<cache>/isr-cost/<target>-<image digest>/<journal digest>.npz``. A run whose
firmware and inputs did not change (the same build and seed: the gate again after a change of
the rig's Python, a confirmation's seeds met before) replays nothing. The cache is
``$HIL_CACHE`` (else ``$XDG_CACHE_HOME/hil-rig``, else ``~/.cache/hil-rig``); only the most
recently used ``KEEP_BUILDS`` builds' folders are kept.

The replay also checks the image's outputs against the host's, period by period. Identical
outputs are the rule (the same compiler's rounding on both). A host that rounds differently
(fused multiply-add, another compiler) gives outputs that differ in their last bits: when every
period still took the host's path (``replay.Comparison.same_path``: the same state machine
states, gate enables and conversions, compares within a few ticks, in all but 1 % of the
periods) the counts stand, with the differences said in ``IsrCosts.differs``; a run whose
target left the host's path has no cost values (``TargetMismatch``), since they would not be
the cost of the same computation.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.target_m4 import emulator, replay
from rig.target_m4.journal import Journal

TARGET = emulator.DEFAULT_TARGET  # the part the gate's cost criteria are measured on
KEEP_BUILDS = 8
COLUMN = "isr.instructions"  # the capture-aligned columns the metrics read
STEP_PREFIX = "isr.step."
JOURNAL_NAME = "isr.journal"
TS = 1e-4  # s per ISR (rig.target_m4.record.TS)


class TargetMismatch(RuntimeError):
    """The image's outputs differ from the host's on the run's journal."""


@dataclass(frozen=True)
class IsrCosts:
    """Per journalled period: the ADC period it handled, its instructions, by step."""

    periods: np.ndarray  # int64
    instructions: np.ndarray  # int64
    steps: np.ndarray  # int64, one row per period, one column per step
    step_names: tuple[str, ...]
    cached: bool = False
    differs: str = ""  # on the host's path, but not to the bit: how far (else "")

    def columns(self, first_period: int, n: int) -> dict[str, np.ndarray]:
        """Capture-aligned columns (row i: period first_period + i; NaN where the period
        was not journalled)."""
        out = {COLUMN: np.full(n, np.nan)}
        for name in self.step_names:
            out[STEP_PREFIX + name] = np.full(n, np.nan)
        rows = self.periods - first_period
        ok = (rows >= 0) & (rows < n)
        out[COLUMN][rows[ok]] = self.instructions[ok]
        for j, name in enumerate(self.step_names):
            out[STEP_PREFIX + name][rows[ok]] = self.steps[ok, j]
        return out


def journal_windows(windows: Sequence[tuple[float, float]], duration: float
                    ) -> list[tuple[int, int]]:
    """ISR index windows (start, length) that hold the periods of the time windows
    (merged where they overlap; a period more on each side: the ISR of period k is the
    k-th or the (k+1)-th call)."""
    spans = sorted((max(0, round(t0 / TS) - 1), round(min(t1, duration) / TS) + 2)
                   for t0, t1 in windows)
    merged: list[list[int]] = []
    for a, b in spans:
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return [(a, b - a) for a, b in merged]


def cache_root() -> Path:
    env = os.environ.get("HIL_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "hil-rig"


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:20]


def _prune(folder: Path, keep: Path) -> None:
    """Keeps the KEEP_BUILDS most recently used builds' folders."""
    try:
        builds = sorted((p for p in folder.iterdir() if p.is_dir()),
                        key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return
    for old in builds[KEEP_BUILDS:]:
        if old != keep:
            shutil.rmtree(old, ignore_errors=True)


def measure(journal: Path, target: str = TARGET, cache: Path | None = None) -> IsrCosts:
    """The instructions of every ISR of ``journal`` on ``target``'s image, from the cache
    when this build has replayed this journal before."""
    image = emulator.image_path(target)
    root = (cache or cache_root()) / "isr-cost"
    build = root / f"{target}-{_digest(image)}"
    hit = build / f"{_digest(journal)}.npz"
    if hit.is_file():
        try:
            with np.load(hit) as z:
                costs = IsrCosts(z["periods"], z["instructions"], z["steps"],
                                 tuple(str(s) for s in z["step_names"]), cached=True,
                                 differs=str(z["differs"]) if "differs" in z else "")
            os.utime(build)
            return costs
        except (OSError, ValueError, KeyError):
            pass  # a damaged entry: measured again
    m4 = emulator.M4Core(image, count=True, target=target)
    comp = replay.replay(Journal(journal), m4, journal.parent.name)
    if not comp.same_path:
        why = (f"{comp.off_path} of {comp.periods} periods off it (first: "
               + "; ".join(comp.off_path_examples[:2]) + ")" if comp.off_path else
               f"{comp.status_differences} command statuses differ")
        raise TargetMismatch(f"the {target} image left the host's path: {why}")
    costs = _costs(comp, Journal(journal))
    if not comp.identical:
        costs = dataclasses.replace(costs, differs=_differs(comp))
    try:
        build.mkdir(parents=True, exist_ok=True)
        tmp = build / f".{hit.stem}.{os.getpid()}.{time.monotonic_ns()}.npz"
        np.savez(tmp, periods=costs.periods, instructions=costs.instructions,
                 steps=costs.steps, step_names=np.array(costs.step_names),
                 differs=np.array(costs.differs))
        tmp.replace(hit)
        _prune(root, build)
    except OSError:
        pass  # no cache: measured again next time
    return costs


def _differs(comp: replay.Comparison) -> str:
    """How a replay on the host's path differs from the host's outputs."""
    return (f"the image's outputs differ from the host's in their last bits, on the host's "
            f"path: the core state in {comp.state_differences} of {comp.periods} periods, the "
            f"PWM in {comp.pwm_differences}, and {comp.off_path} period(s) off the path "
            f"(another state, or compares beyond {replay.PATH_TICKS} ticks; at most "
            f"{replay.OFF_PATH_SHARE:.0%} may be): a build that rounds differently")


def _costs(comp: replay.Comparison, journal: Journal) -> IsrCosts:
    """The replay's per-ISR counts with the ADC period each ISR handled (the next one after
    an ISR without data)."""
    periods: list[int] = []
    last = -1
    for rec in journal.records():
        if rec.tag != "I":
            continue
        isr = journal.isr(rec)
        k = int.from_bytes(isr.adc[:4], "little") if isr.has_adc else last + 1
        periods.append(k)
        last = k
    if len(periods) != len(comp.costs):
        raise TargetMismatch(f"{len(periods)} ISRs in the journal, {len(comp.costs)} replayed")
    steps = np.array([c.steps for c in comp.costs], dtype=np.int64).reshape(
        len(comp.costs), len(comp.steps))
    return IsrCosts(np.array(periods, dtype=np.int64),
                    np.array([c.instructions for c in comp.costs], dtype=np.int64),
                    steps, comp.steps)
