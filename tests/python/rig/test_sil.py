"""The in-process bench's Python side (rig.bench.sil): configuration errors, frame checks, the
hardware-parameter table shared with the rig, and the CLI's refusal of real time."""

from __future__ import annotations

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
