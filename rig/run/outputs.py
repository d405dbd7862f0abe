"""A run's folder: made ready before anything starts (``rig.output``: a folder that cannot
take the results is exit 3, not a traceback at the end), the full-rate data removed when the
run need not keep it, ``result.json`` and ``report.md`` written whole."""

from __future__ import annotations

import contextlib
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from rig import capture, output, report
from rig.run.result import Kept, RunResult
from rig.scenario import Scenario

FULL_RATE_FILES = ("plant.trace", "fw.trace", "rig.trace", "capture")
RUN_FILES = ("capture", "recording.rrd", "result.json", "report.md", "plant.trace", "fw.trace",
             "rig.trace", "figure.png")
FIGURE_GLOB = "criterion-*.png"  # rig.figures: a picture per criterion that did not pass


def prepare(out: Path, sc: Scenario) -> None:
    """The folder checked for room, the outputs of an earlier run in it removed, the
    scenario file copied in."""
    output.prepare(out, round(sc.duration / capture.TS))
    if out.exists():
        for name in RUN_FILES:
            target = out / name
            if target.is_dir():
                shutil.rmtree(target)
            else:
                target.unlink(missing_ok=True)
        for picture in out.glob(FIGURE_GLOB):
            picture.unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(OSError):
        shutil.copyfile(sc.file, out / "scenario.toml")


def dir_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else 0


def prune(out: Path, *, keep_full: bool, keep: str) -> Kept:
    """Removes the full-rate traces and capture columns of a run that need not keep them;
    returns what was kept and removed (for result.json)."""
    present = [name for name in FULL_RATE_FILES if (out / name).exists()]
    if keep_full:
        return Kept(full_rate=bool(present), policy=keep)
    removed_bytes = 0
    for name in present:
        target = out / name
        if target.is_dir():
            removed_bytes += dir_size(target)
            shutil.rmtree(target)
        else:
            removed_bytes += target.stat().st_size
            target.unlink()
    return Kept(full_rate=False, policy=keep, removed=present,
                removed_bytes=removed_bytes,
                note="passed: full-rate traces and capture removed (rig run --keep-all keeps "
                "them)")


def json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_result(result: RunResult) -> None:
    """result.json and report.md, each written whole or not at all."""
    data = result.to_json()
    output.write_text(result.out_dir / "result.json",
                      json.dumps(data, indent=1, default=json_default))
    output.write_text(result.out_dir / "report.md", report.scenario_report(data))
