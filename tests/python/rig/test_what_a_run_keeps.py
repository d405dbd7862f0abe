"""What a run keeps: result.json, report.md and the recording always; the full-rate traces and
capture columns only for a run that did not pass, or for every run with --keep-all. The
recording alone reproduces every criterion's value (its evidence is the rows they read).

The runs are on the in-process bench (no bus): the same files as a bus run, in a second."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from rig import cli
from rig import scenario as sc
from rig.data import metrics
from rig.results import recording

FULL_RATE = ("plant.trace", "fw.trace", "rig.trace", "capture")


def _failing_scenario(tmp_path: Path) -> Path:
    """The smoke scenario with a position limit no drive meets."""
    text = sc.load("smoke").file.read_text()
    text = text.replace("limit = 10.0", "limit = 0.000001")
    path = tmp_path / "smoke_impossible.toml"
    path.write_text(text)
    return path


def test_a_passing_run_keeps_result_report_and_recording(
        hil_run) -> None:  # type: ignore[no-untyped-def]
    r = hil_run("smoke", bus="inproc", keep="failing")
    assert r.passed, r.explain()
    for name in FULL_RATE:
        assert not (r.out_dir / name).exists(), name
    for name in ("result.json", "report.md", "recording.rrd", "scenario.toml"):
        assert (r.out_dir / name).is_file(), name
    kept = json.loads((r.out_dir / "result.json").read_text())["kept"]
    assert kept["full_rate"] is False and kept["policy"] == "failing"
    assert kept["removed"] == list(FULL_RATE) and kept["removed_bytes"] > 1_000_000
    assert r.capture is None
    assert "full-rate traces and capture removed" in (r.out_dir / "report.md").read_text()


def test_the_recording_alone_reproduces_every_criterion(
        hil_run) -> None:  # type: ignore[no-untyped-def]
    r = hil_run("smoke", bus="inproc", keep="failing")
    data = json.loads((r.out_dir / "result.json").read_text())
    manifest, evidence = recording.read_evidence(r.out_dir / "recording.rrd")
    assert set(manifest["columns"]) == {"pos_err_deg", "speed_ref_rpm", "speed_true_rpm"}
    n, first = data["capture"]["periods"], data["capture"]["first_period"]
    assert manifest["first_period"] == first
    cols: dict[str, np.ndarray] = {"period": np.arange(first, first + n)}
    for name, values in evidence.items():
        padded = np.full(n, np.nan)
        padded[: values.size] = values
        cols[name] = padded
    reads: list[tuple[str, int, int]] = []
    for cr, recorded in zip(sc.load("smoke").criteria, data["criteria"], strict=True):
        w = metrics.Window(cols, cr.window[0], cr.window[1], ts=manifest["ts"],
                           first_period=first, counters=data["counters"], reads=reads)
        value = metrics.compute(cr.metric, w, cr.params)
        assert value == recorded["value"], cr.name  # exactly: the same rows, the same values
    # and what they read lies inside what the recording says it holds
    for name, a, b in reads:
        assert any(lo <= a and b <= hi for lo, hi in manifest["rows"][name]), (name, a, b)
        assert not math.isnan(float(np.nanmax(np.abs(cols[name][a:b]))))


def test_a_failing_run_keeps_its_full_rate_data(
        hil_run, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    r = hil_run(_failing_scenario(tmp_path), bus="inproc", keep="failing")
    assert not r.passed
    for name in FULL_RATE:
        assert (r.out_dir / name).exists(), name
    kept = json.loads((r.out_dir / "result.json").read_text())["kept"]
    assert kept == {"full_rate": True, "policy": "failing", "removed": [], "removed_bytes": 0}
    assert r.capture is not None and r.capture.n >= 4999


def test_rig_run_keeps_full_rate_data_only_when_asked(tmp_path: Path,
                                                      hil_binaries: object) -> None:
    plain, kept = tmp_path / "plain", tmp_path / "kept"
    assert cli.main(["run", "smoke", "--bus", "inproc", "--quiet", "--out", str(plain)]) == 0
    assert cli.main(["run", "smoke", "--bus", "inproc", "--quiet", "--keep-all",
                     "--out", str(kept)]) == 0
    assert not any((plain / name).exists() for name in FULL_RATE)
    assert all((kept / name).exists() for name in FULL_RATE)
    assert json.loads((kept / "result.json").read_text())["kept"]["policy"] == "all"
    # the recordings are the same kind either way
    assert recording.entity_rows(plain / "recording.rrd") == recording.entity_rows(
        kept / "recording.rrd")
