"""The .rrd recording: written columnar, read back with rerun-sdk's own reader."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from hiltest_support import Synthetic
from rerun.chunk import RrdReader

from rig import capture, recording


@pytest.fixture
def cap(tmp_path: Path) -> capture.Capture:
    syn = Synthetic(n=2500, error_deg=lambda t: 1.5 * np.sin(2 * math.pi * 30 * t))
    plant, fw = syn.write(tmp_path)
    c, loss = capture.build(tmp_path / "cap", capture.default_specs(plant, fw),
                            expected=(0, 2499), speed_reference=lambda t: 600.0 + 0 * t)
    assert loss.ok
    return c


def test_full_rate_recording_reads_back(tmp_path: Path, cap: capture.Capture) -> None:
    path = tmp_path / "recording.rrd"
    info = recording.write(path, cap, title="t", report_markdown="# report",
                           timing=recording.TimedSamples([1000, 2000, 2500],
                                                         {"speed_x": [1.0, 2.0, 3.0]}))
    assert not info["long_run"]
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    rows = recording.entity_rows(path)
    for s in recording.SERIES:
        assert rows[s.entity] == 2500, s.entity
    for ent in recording.TRAJECTORIES:
        assert rows[ent] == 250, ent
    assert rows["timing/speed_x"] == 3
    # the values are the capture's, at the right periods
    periods, values = recording.read_column(path, "position/error")
    np.testing.assert_array_equal(periods, np.arange(2500))
    np.testing.assert_array_equal(values[:, 0], np.asarray(cap["pos_err_deg"]))
    _, v_speed = recording.read_column(path, "speed/rpm")
    np.testing.assert_allclose(v_speed[:, 0], 600.0)  # first series: the reference
    np.testing.assert_allclose(v_speed[:, 1], cap["speed_true_rpm"])
    # the time line is exact: period * 100 us
    chunk = next(c for c in reader.stream() if c.entity_path == "/position/theta")
    batch = chunk.to_record_batch()
    sim = batch.column("sim_time").to_numpy().astype("int64")
    per = batch.column("period").to_numpy()
    np.testing.assert_array_equal(sim, per * 100_000)


def test_long_runs_decimate_the_secondary_series(tmp_path: Path, cap: capture.Capture) -> None:
    path = tmp_path / "long.rrd"
    info = recording.write(path, cap, full_rate_max_s=0.1)
    assert info["long_run"]
    rows = recording.entity_rows(path)
    core = {s.entity for s in recording.SERIES if s.core}
    assert core == {"position/theta", "position/error", "speed/rpm", "speed/error"}
    for s in recording.SERIES:
        assert rows[s.entity] == (2500 if s.entity in core else 250), s.entity
    full = tmp_path / "full.rrd"
    recording.write(full, cap)
    assert path.stat().st_size < full.stat().st_size


def test_live_view_is_decimated(tmp_path: Path) -> None:
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("live_test")
    rec.save(path)
    live = recording.LiveView(rec, min_interval=100)
    for p in range(0, 5000, 10):  # TLM at 1 kHz of simulated time
        live.add("speed", p, {"estimated": p * 0.1})
    live.add("speed", 4995, {"estimated": 0.0})  # too soon after 4900: dropped
    live.close()
    rec.flush()
    recording._finalize(rec)
    assert live.rows == {"speed": 50}
    assert recording.entity_rows(path) == {"live/speed": 50}
