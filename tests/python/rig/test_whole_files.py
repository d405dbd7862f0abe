"""Issue 36.7: a run's recording and pictures are whole or absent. A full disk left a 0-byte
``figure.png`` and ``recording.rrd``; a SIGTERM while the recording was written left
``recording: null`` in result.json beside a written ``recording.rrd``.

The full disk is a small tmpfs filled to its last byte (mounted as root; the tests skip
elsewhere)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from rig import cli
from rig.data import capture
from rig.results import figures, recording


@pytest.fixture(scope="module")
def kept_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("whole") / "smoke"
    assert cli.main(["run", "smoke", "--bus", "inproc", "--keep-all", "--quiet", "--no-record",
                     "--no-figures", "--out", str(out)]) == 0
    return out


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[Path]:
    if os.geteuid() != 0:
        pytest.skip("mounts a tmpfs (root only)")
    where = tmp_path / "full"
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(where)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        fd = os.open(where / "filler", os.O_WRONLY | os.O_CREAT)
        try:
            for size in (4096, 1):
                with contextlib.suppress(OSError):
                    while True:
                        os.write(fd, b"x" * size)
        finally:
            os.close(fd)
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=False)


def test_a_full_disk_leaves_no_empty_recording_or_picture(kept_run: Path,
                                                          full_disk: Path) -> None:
    cap = capture.Capture(kept_run / "capture")
    result = json.loads((kept_run / "result.json").read_text())
    with pytest.raises((RuntimeError, OSError)):
        recording.write(full_disk / "recording.rrd", cap, title="full")
    with pytest.raises(OSError):
        figures.write(full_disk, cap, result)
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]


def test_recording_and_pictures_are_whole_where_there_is_room(kept_run: Path,
                                                              tmp_path: Path) -> None:
    cap = capture.Capture(kept_run / "capture")
    result = json.loads((kept_run / "result.json").read_text())
    info = recording.write(tmp_path / "recording.rrd", cap, title="room")
    assert info["path"] == str(tmp_path / "recording.rrd")
    assert recording.entity_rows(tmp_path / "recording.rrd")  # readable back
    figures.write(tmp_path, cap, result)
    assert (tmp_path / "figure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure.png", "recording.rrd"]


@pytest.mark.parametrize("when", ["while recording", "after the recording"])
def test_sigterm_in_the_post_processing_leaves_result_json_true_to_the_folder(
        tmp_path: Path, when: str) -> None:
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "rig", "run", "table2_1000rpm_1nm",
                             "--bus", "inproc", "--out", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    def recording_started() -> bool:
        return (out / "recording.rrd").exists() or any(out.glob(".recording.tmp-*"))

    def recording_done() -> bool:
        return (out / "recording.rrd").exists()

    wait = recording_started if when == "while recording" else recording_done
    deadline = time.monotonic() + 300
    while not wait():
        if proc.poll() is not None:
            pytest.fail(f"the run ended before the moment to stop it: {proc.communicate()[0]}")
        assert time.monotonic() < deadline
        time.sleep(0.001)
    proc.send_signal(signal.SIGTERM)
    text, _ = proc.communicate(timeout=120)
    data = json.loads((out / "result.json").read_text())
    rrd = out / "recording.rrd"
    if proc.returncode == 130:  # (the signal came before the run's end)
        assert data["status"] == "interrupted", text
    assert (data["recording"] is None) == (not rrd.exists()), (data["recording"], text)
    if rrd.exists():
        assert data["recording"]["bytes"] == rrd.stat().st_size > 0
        assert recording.entity_rows(rrd)  # a whole recording, not one cut short
    for f in (data.get("figures") or {}).get("files") or []:
        assert (out / f["path"]).stat().st_size > 0
    assert not [p.name for p in out.iterdir() if ".tmp-" in p.name]
