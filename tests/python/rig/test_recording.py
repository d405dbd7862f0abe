"""The .rrd recording: written columnar, read back with rerun-sdk's own reader."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from hiltest_support import Synthetic
from rerun.chunk import RrdReader

from rig.data import capture
from rig.results import recording


@pytest.fixture
def cap(tmp_path: Path) -> capture.Capture:
    syn = Synthetic(n=2500, error_deg=lambda t: 1.5 * np.sin(2 * math.pi * 30 * t))
    plant, fw = syn.write(tmp_path)
    c, loss = capture.build(tmp_path / "cap", capture.default_specs(plant, fw),
                            expected=(0, 2499), speed_reference=lambda t: 600.0 + 0 * t)
    assert loss.ok
    return c


def test_display_series_are_decimated_and_read_back(tmp_path: Path,
                                                   cap: capture.Capture) -> None:
    path = tmp_path / "recording.rrd"
    info = recording.write(path, cap, title="t", report_markdown="# report",
                           timing=recording.TimedSamples([1000, 2000, 2500],
                                                         {"speed_x": [1.0, 2.0, 3.0]}))
    assert info["display_step"] == 10 and info["evidence_rows"] == 0
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    rows = recording.entity_rows(path)
    for s in recording.SERIES:
        assert rows[s.entity] == 250, s.entity
    for ent in recording.TRAJECTORIES:
        assert rows[ent] == 250, ent
    assert rows["timing/speed_x"] == 3
    assert recording.EVIDENCE_ENTITY not in rows
    # the values are the capture's, at the right periods (every 10th)
    periods, values = recording.read_column(path, "position/error")
    np.testing.assert_array_equal(periods, np.arange(0, 2500, 10))
    np.testing.assert_array_equal(values[:, 0], np.asarray(cap["pos_err_deg"])[::10])
    _, v_speed = recording.read_column(path, "speed/rpm")
    np.testing.assert_allclose(v_speed[:, 0], 600.0)  # first series: the reference
    np.testing.assert_allclose(v_speed[:, 1], np.asarray(cap["speed_true_rpm"])[::10])
    # the time line is exact: period * 100 us
    chunk = next(c for c in reader.stream() if c.entity_path == "/position/theta")
    batch = chunk.to_record_batch()
    sim = batch.column("sim_time").to_numpy().astype("int64")
    per = batch.column("period").to_numpy()
    np.testing.assert_array_equal(sim, per * 100_000)


def test_long_runs_are_displayed_coarser(tmp_path: Path, cap: capture.Capture) -> None:
    path = tmp_path / "long.rrd"
    info = recording.write(path, cap, display_max_rows=100)
    assert info["display_step"] == 25  # 2500 periods in at most 100 rows
    rows = recording.entity_rows(path)
    for s in recording.SERIES:
        assert rows[s.entity] == 100, s.entity
    assert recording.display_step(356_000) == 178
    assert recording.display_step(20_000) == 10


def test_evidence_is_full_rate_exactly_where_it_was_read(tmp_path: Path,
                                                        cap: capture.Capture) -> None:
    path = tmp_path / "evidence.rrd"
    reads = [("pos_err_deg", 100, 400), ("pos_err_deg", 300, 900), ("speed_true_rpm", 2000, 2500),
             ("truth.id", 50, 60)]
    info = recording.write(path, cap, evidence=recording.evidence_ranges(reads))
    assert info["evidence"] == {"pos_err_deg": [[100, 900]], "speed_true_rpm": [[2000, 2500]],
                                "truth.id": [[50, 60]]}
    assert info["evidence_rows"] == 800 + 500 + 10
    assert recording.entity_rows(path)[recording.EVIDENCE_ENTITY] == 1310
    manifest, cols = recording.read_evidence(path)
    assert manifest["rows"]["pos_err_deg"] == [[100, 900]]
    pos = cols["pos_err_deg"]
    np.testing.assert_array_equal(pos[100:900], np.asarray(cap["pos_err_deg"])[100:900])
    assert np.isnan(pos[:100]).all() and np.isnan(pos[900:]).all()
    speed = cols["speed_true_rpm"]
    np.testing.assert_array_equal(speed[2000:2500], np.asarray(cap["speed_true_rpm"])[2000:])
    np.testing.assert_array_equal(cols["truth.id"][50:60],
                                  np.asarray(cap["truth.id"], dtype=np.float64)[50:60])
    assert np.isnan(cols["truth.id"][60:]).all()


def test_merge_ranges() -> None:
    assert recording.merge_ranges([(5, 9), (0, 3), (3, 4), (8, 12), (20, 20)]) == [(0, 4),
                                                                                    (5, 12)]


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


def test_live_view_keeps_one_row_shape_per_entity(tmp_path: Path) -> None:
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("live_test")
    rec.save(path)
    live = recording.LiveView(rec, min_interval=1)
    live.add("position", 0, {"θ est": 1.0, "θ": 2.0})
    live.add("position", 1, {"θ est": 3.0})  # the truth of this period not heard yet
    live.add("position", 2, {"θ est": 4.0, "θ": 5.0, "other": 6.0})
    live.close()
    rec.flush()
    recording._finalize(rec)
    periods, values = recording.read_column(path, "live/position")
    np.testing.assert_array_equal(periods, [0, 1, 2])
    np.testing.assert_array_equal(values, [[2.0, 1.0], [np.nan, 3.0], [5.0, 4.0]])  # θ, θ̂


def test_viewer_labels_have_no_combining_marks() -> None:
    """The Rerun viewer's font drops combining marks: "θ̂" was drawn as "θ", the estimate
    indistinguishable from the truth. Every string the recording and the live view give the
    viewer (series labels, view names, entity paths) is free of them ("θ est")."""
    import ast
    import unicodedata

    from rig.run import live

    for module in (recording, live):
        tree = ast.parse(Path(module.__file__).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                marks = [c for c in node.value if unicodedata.combining(c)]
                assert not marks, f"{module.__name__}:{node.lineno}: {node.value!r}"
    labels = [label for s in recording.SERIES for label in s.names]
    assert "θ est" in labels and "θ est - θ (deg el.)" in labels
