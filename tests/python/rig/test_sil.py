"""The in-process bench's Python side (rig.bench.sil): configuration errors, frame checks, the
hardware-parameter table shared with the rig, and the CLI's refusal of real time."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from rig import _paths, protocols
from rig.bench import sil
from rig.bench.configuration import FIRMWARE_FROM_PROFILE

PAPER = _paths.data_dir("profiles") / "paper.toml"


def test_bench_hardware_table_is_the_rigs() -> None:
    # the C bench's fw_from_plant table (for C callers) must say what the rig does
    assert sil.hardware_params() == FIRMWARE_FROM_PROFILE


def test_bad_plant_override_names_the_field() -> None:
    with pytest.raises(sil.BenchError, match=r"machine\.rs_ohmx"):
        sil.SilBench(PAPER, ["machine.rs_ohmx=2"], [])


def test_bad_firmware_parameter_names_it() -> None:
    with pytest.raises(sil.BenchError, match="no_such_param"):
        sil.SilBench(PAPER, [], ["no_such_param=1"])


def test_bad_frames_are_rejected_and_counted(tmp_path: Path) -> None:
    with sil.SilBench(PAPER, [], [], tmp_path / "p.trace", tmp_path / "f.trace") as b:
        assert b.frame(0x100, bytes(7), fd=False) == -1  # DRIVE_CMD one byte short
        assert b.frame(0x100, bytes(8), fd=True) == -1  # drive protocol is classic CAN
        assert b.frame(0x300, bytes(8), fd=True) == 1  # not for a bench node
        c = b.counters()
        assert c["firmware"]["rejects"]["bad_length"] == 1
        assert c["firmware"]["rejects"]["wrong_frame_type"] == 1
        assert c["firmware"]["rx_rejected"] == 2
        assert len(b.rejected) == 2 and "length 7" in b.rejected[0]
        assert b.run_until(20) == 20 and b.next_period == 20
        assert b.counters()["firmware"]["isr"] == 20


def test_realtime_on_the_bench_is_a_usage_error() -> None:
    r = subprocess.run([sys.executable, "-m", "rig", "run", "smoke", "--bus", "inproc",
                        "--realtime", "--quiet"], capture_output=True, text=True, check=False)
    assert r.returncode == 2 and "lockstep only" in r.stderr


def test_drive_frames_go_through_fw_hosts_handler() -> None:
    # The bench hands drive frames to fw_host's own handler (drive_protocol.c), so a refusal
    # is counted and worded as fw_host words it: a DRIVE_LIMITS whose i_max is inside the DBC
    # range (10 A) but not below oc_trip_a (9.5 A) names the rule it broke and the values.
    limits = protocols.database("drive").get_message_by_name("DRIVE_LIMITS")
    data = limits.encode({"i_max": 9.8, "speed_max": 3000, "accel_max": 1000})
    with sil.SilBench(PAPER, [], []) as b:
        assert b.frame(limits.frame_id, data, fd=False) == -1
        c = b.counters()["firmware"]
        assert c["rejects"]["refused"] == 1 and c["limits"] == 1 and c["rx_rejected"] == 1
        assert b.rejected == ["firmware rejected (refused): DRIVE_LIMITS refused by the control "
                              "core: i_max 9.800 A (must stay below oc_trip_a), speed_max "
                              "3000 r/min, accel 1000.0 r/min/s"]


def _spin(b: sil.SilBench, periods: int) -> None:
    """Limits, then the drive enabled at 300 r/min, for ``periods`` periods."""
    drive = protocols.database("drive")
    b.frame(0x101, drive.get_message_by_name("DRIVE_LIMITS").encode(
        {"i_max": 4.0, "speed_max": 3000, "accel_max": 3000}), fd=False)
    b.frame(0x100, drive.get_message_by_name("DRIVE_CMD").encode(
        {"enable": 1, "fault_reset": 0, "ctrl_mode": 0, "fw_mode": 0, "alive": 0,
         "speed_ref": 300, "iq_ref": 0}), fd=False)
    assert b.run_until(periods) == periods


def test_the_outbox_holds_the_programs_frames_and_changes_nothing(tmp_path: Path) -> None:
    """What fw_host and plant_rt would send the rig (the live view's source in process): TLM_*
    once per speed-loop period, BENCH_TRUTH every 10th period, in period order; the control
    loop's traces are byte for byte those of a bench without it."""
    periods = 3000
    with sil.SilBench(PAPER, [], [], tmp_path / "p0.trace", tmp_path / "f0.trace") as b:
        _spin(b, periods)
    with sil.SilBench(PAPER, [], [], tmp_path / "p1.trace", tmp_path / "f1.trace") as b:
        b.outbox(1, 10)
        _spin(b, periods // 2)
        frames = b.take_frames()
        assert b.take_frames() == []  # taken: the outbox is empty
        b.run_until(periods)
        frames += b.take_frames()
        assert b.outbox_dropped == 0
    for name in ("p", "f"):
        assert (tmp_path / f"{name}0.trace").read_bytes() == \
            (tmp_path / f"{name}1.trace").read_bytes()
    dbs = {**{m.frame_id: m for m in protocols.database("drive").messages},
           **{m.frame_id: m for m in protocols.database("bench").messages}}
    names = [dbs[i].name for i, _ in frames]
    speed_loop = protocols.timebase().speed_loop_divider
    for tlm in ("TLM_POS", "TLM_CUR", "TLM_REF", "TLM_PARAM", "TLM_VOLT"):
        assert names.count(tlm) == periods // speed_loop, tlm
    assert names.count("BENCH_TRUTH") == periods // 10
    truth = [dbs[i].decode(d) for i, d in frames if dbs[i].name == "BENCH_TRUTH"]
    pos = [dbs[i].decode(d) for i, d in frames if dbs[i].name == "TLM_POS"]
    assert [t["period"] for t in truth] == list(range(0, periods, 10))
    assert [p["period"] for p in pos] == list(range(0, periods, speed_loop))
    # the drive turns (still starting at 0.3 s) and the speed it reports is the plant's
    true_rpm = truth[-1]["omega_m"] * 60.0 / (2.0 * math.pi)
    assert true_rpm > 100.0 and abs(pos[-1]["speed_hat"] - true_rpm) < 15.0
