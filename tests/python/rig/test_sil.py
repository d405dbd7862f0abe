"""The in-process bench's Python side (rig.bench.sil): configuration errors, frame checks, the
hardware-parameter table shared with the rig, and the CLI's refusal of real time."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from rig import _paths
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
