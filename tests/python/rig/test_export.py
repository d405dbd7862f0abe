"""rig export: the MDF4 file and the CAN logs, read back with asammdf, python-can and cantools
and compared with the capture value for value; every frame of the run is in them (the VIO
wires, the drive protocol, the bench commands), the CAN log replays with can.player and
decodes with cantools, the MDF4's bus-logging group decodes with asammdf's
extract_bus_logging; a damaged run folder or a destination that is not a file is an error
that leaves nothing behind."""

from __future__ import annotations

import collections
import datetime as dt
import json
import math
import os
import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from asammdf import MDF

from rig import cli, protocols
from rig.data import capture, export
from rig.data.trace import HEADER_SIZE, RECORD_SIZE, TraceFile, frame_ids
from rig.results.result import RunResult

PREFIX = {"BENCH_TRUTH": "truth", "BENCH_TRUTH_MAG": "mag", "FW_TRACE": "fw"}
WHOLE_BUS = {"VIO_ADC_0", "VIO_PWM", "BENCH_TRUTH", "BENCH_TRUTH_MAG", "FW_TRACE", "DRIVE_CMD",
             "DRIVE_LIMITS", "LOAD_CMD", "BENCH_STEP"}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    out = tmp_path_factory.mktemp("export") / "smoke"
    assert cli.main(["run", "smoke", "--bus", "inproc", "--keep-all", "--quiet", "--out",
                     str(out)]) == 0
    r = RunResult.load(out)
    assert r.passed and r.capture is not None
    return r


def _dbc() -> cantools.database.can.Database:
    db = cantools.database.can.Database()
    for name in protocols.DATABASES:
        db.add_dbc_file(str(protocols.path(name)))
    return db


def _trace_records(run_dir: Path) -> dict[str, int]:
    """Records per message over the three traces, counted from the files themselves."""
    names = {int(m.frame_id): m.name for m in _dbc().messages}
    out: collections.Counter[str] = collections.Counter()
    for f in ("plant.trace", "fw.trace", "rig.trace"):
        ids = frame_ids(TraceFile.open(run_dir / f).records()["can_id"]).tolist()
        out.update(names[i] for i in ids)
    return dict(out)


def test_mf4_holds_the_capture_value_for_value(run: RunResult, tmp_path: Path) -> None:
    cap = run.capture
    assert cap is not None
    dest = tmp_path / "smoke.mf4"
    assert cli.main(["export", str(run.out_dir), "--mf4", str(dest)]) == 0
    db = _dbc()
    by_column = {f"{PREFIX[m.name]}.{s.name}": (f"{m.name}.{s.name}", s)
                 for m in db.messages if m.name in PREFIX for s in m.signals}
    t = np.asarray(cap["period"], dtype=np.float64) * capture.TS
    with MDF(dest) as mdf:
        assert mdf.version == "4.10"
        names = {ch.name for g in mdf.groups for ch in g.channels} - {"time", "CAN_DataFrame"}
        names = {n for n in names if not n.startswith("CAN_DataFrame.")}
        want_names = {by_column[c][0] if c in by_column else c
                      for c in cap.keys()} - {"period"}
        assert names == want_names  # MESSAGE.signal; the rig's derived columns by their name
        for column in cap.keys():
            if column == "period":
                continue
            name, sig = by_column.get(column, (column, None))
            got = mdf.get(name, raw=True)
            want = np.asarray(cap[column])
            assert got.samples.dtype == want.dtype, column
            np.testing.assert_array_equal(got.samples, want, err_msg=column)
            np.testing.assert_array_equal(got.timestamps, t, err_msg=column)
            unit = (sig.unit or "") if sig is not None else capture.DERIVED_UNITS.get(column)
            assert got.unit == unit, column
        assert mdf.get("FW_TRACE.theta_hat").unit == "rad"
        assert mdf.get("pos_err_deg").unit == "deg"
        # the firmware's state reads as text: DRIVE_STATUS.state's value table
        table = db.get_message_by_name("DRIVE_STATUS").get_signal_by_name("state").choices
        raw = mdf.get("FW_TRACE.state", raw=True).samples
        text = mdf.get("FW_TRACE.state").samples
        assert {int(r): bytes(x).decode() for r, x in zip(raw, text, strict=True)} == {
            int(r): str(table[int(r)]) for r in np.unique(raw)}
        assert "RUN" in {bytes(x).decode() for x in text}
        # the file starts when the run started; its header says which run it is
        assert mdf.header.start_time == dt.datetime.fromisoformat(run.started)
        props = {e.get("name"): e.text for e in ET.fromstring(mdf.header.comment).iter("e")}
        # asammdf's own header fields are filled (they were empty)
        assert mdf.header.author and mdf.header.project == export.PROJECT
        assert "smoke" in mdf.header.subject and "ideal" in mdf.header.subject
        assert mdf.header.description.startswith("smoke: ")
    result = json.loads((run.out_dir / "result.json").read_text())
    assert props["scenario"] == "smoke" and props["profile"] == "ideal"
    assert props["bus"] == "inproc" and props["status"] == "passed"
    for k, v in result["versions"].items():
        assert props[f"version.{k}"] == v
    assert props["commit"] == result["versions"].get("rig.commit", "unknown")


def test_mf4_frames_decode_with_extract_bus_logging(run: RunResult, tmp_path: Path) -> None:
    cap = run.capture
    assert cap is not None
    dest = tmp_path / "smoke.mf4"
    assert cli.main(["export", str(run.out_dir), "--mf4", str(dest)]) == 0
    dbcs = [(str(protocols.path(n)), 0) for n in protocols.DATABASES]
    with MDF(dest) as mdf:
        decoded = mdf.extract_bus_logging({"CAN": dbcs})
    groups = {str(g.channel_group.comment).split(" - message ")[1].split()[0]: i
              for i, g in enumerate(decoded.groups)}
    assert set(groups) == WHOLE_BUS  # the in-process run's frames: every message it carried
    truth = decoded.get("theta_e", group=groups["BENCH_TRUTH"])
    np.testing.assert_array_equal(truth.samples.astype(np.float32), cap["truth.theta_e"])
    np.testing.assert_allclose(truth.timestamps, np.asarray(cap["period"]) * capture.TS)
    hat = decoded.get("theta_hat", group=groups["FW_TRACE"])
    np.testing.assert_array_equal(hat.samples.astype(np.float32), cap["fw.theta_hat"])
    speed_ref = decoded.get("speed_ref", group=groups["DRIVE_CMD"])
    assert len(speed_ref.samples) == _trace_records(run.out_dir)["DRIVE_CMD"]
    assert speed_ref.samples.max() == pytest.approx(300.0)  # the smoke's target


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log"])
def test_can_log_holds_every_frame_value_for_value(run: RunResult, tmp_path: Path,
                                                   suffix: str) -> None:
    cap = run.capture
    assert cap is not None
    dest = tmp_path / f"frames{suffix}"
    assert cli.main(["export", str(run.out_dir), "--can-log", str(dest)]) == 0
    frames = list(can.LogReader(dest))
    db = _dbc()
    counts = collections.Counter(db.get_message_by_frame_id(f.arbitration_id).name
                                 for f in frames)
    assert dict(counts) == _trace_records(run.out_dir)  # every traced frame, once
    assert set(counts) == WHOLE_BUS
    n = cap.n
    # the first frame is the rig's first command, at period 0 (ASC keeps times relative)
    t0 = frames[0].timestamp
    if suffix != ".asc":
        assert t0 == dt.datetime.fromisoformat(run.started).timestamp()
    seen = {name: np.zeros(n, dtype=bool) for name in PREFIX}
    channel_of = {"BENCH_TRUTH": 0, "BENCH_TRUTH_MAG": 0, "VIO_ADC_0": 0, "VIO_PWM": 0,
                  "FW_TRACE": 1}
    stamps = [f.timestamp for f in frames]
    assert stamps == sorted(stamps)
    for f in frames:
        msg = db.get_message_by_frame_id(f.arbitration_id)
        assert int(str(f.channel).removeprefix("can")) == channel_of.get(msg.name, 2)
        values = msg.decode(bytes(f.data), decode_choices=False)
        assert isinstance(values, dict)
        if "period" in values and msg.get_signal_by_name("period").length == 32:
            assert round((f.timestamp - t0) / capture.TS) == int(values["period"]), msg.name
        if msg.name not in PREFIX:
            continue
        assert f.is_fd and len(f.data) == 64
        row = int(values["period"]) - cap.first_period
        for sig, v in values.items():
            if sig == "period":
                continue
            want = float(cap[f"{PREFIX[msg.name]}.{sig}"][row])
            assert v == want or (math.isnan(v) and math.isnan(want)), (msg.name, sig, row)
        seen[msg.name][row] = True
    assert all(s.all() for s in seen.values())  # every period of every message
    # the drive commands of a grant are at its first period, before that period's frames
    grants = [round((f.timestamp - t0) / capture.TS) for f in frames
              if db.get_message_by_frame_id(f.arbitration_id).name == "DRIVE_CMD"]
    steps = [db.decode_message(f.arbitration_id, bytes(f.data))["run_until"] for f in frames
             if db.get_message_by_frame_id(f.arbitration_id).name == "BENCH_STEP"]
    assert grants == [0, *steps[:-1]]


def test_can_player_replays_the_log_and_cantools_decodes_it(
        run: RunResult, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dest = tmp_path / "frames.blf"
    assert cli.main(["export", str(run.out_dir), "--can-log", str(dest)]) == 0
    from can import player

    channel = f"replay-{os.getpid()}"
    received: list[can.Message] = []
    with can.Bus(interface="virtual", channel=channel, fd=True) as listener:
        monkeypatch.setattr(sys, "argv", ["can.player", "-i", "virtual", "-c", channel, "--fd",
                                          "--ignore-timestamps", str(dest)])
        player.main()
        while (msg := listener.recv(timeout=0.5)) is not None:
            received.append(msg)
    sent = list(can.LogReader(dest))
    assert len(received) == len(sent)
    assert [m.arbitration_id for m in received] == [m.arbitration_id for m in sent]
    db = _dbc()
    decoded = [db.decode_message(m.arbitration_id, bytes(m.data)) for m in received]
    cmds = [d for m, d in zip(received, decoded, strict=True)
            if db.get_message_by_frame_id(m.arbitration_id).name == "DRIVE_CMD"]
    assert cmds and all(str(c["ctrl_mode"]) == "SPEED" for c in cmds)  # the value table
    assert max(float(c["speed_ref"]) for c in cmds) == pytest.approx(300.0)


def test_a_bus_run_exports_what_the_rig_heard_too(tmp_path: Path) -> None:
    out = tmp_path / "bus"
    assert cli.main(["run", "smoke", "--bus", "unixcan", "--channel", f"exp-{os.getpid()}",
                     "--keep-all", "--quiet", "--out", str(out)]) == 0
    dest = tmp_path / "bus.log"
    assert cli.main(["export", str(out), "--can-log", str(dest)]) == 0
    db = _dbc()
    frames = list(can.LogReader(dest))
    names = collections.Counter(db.get_message_by_frame_id(f.arbitration_id).name
                                for f in frames)
    assert WHOLE_BUS <= set(names)
    assert {"DRIVE_STATUS", "HEARTBEAT", "TLM_POS", "BENCH_PROGRESS"} <= set(names)
    t0 = dt.datetime.fromisoformat(RunResult.load(out).started).timestamp()
    for f in frames:  # telemetry's 16-bit period, put back on the run's time line
        msg = db.get_message_by_frame_id(f.arbitration_id)
        if msg.name == "TLM_POS":
            period = round((f.timestamp - t0) / capture.TS)
            assert period & 0xFFFF == db.decode_message(f.arbitration_id, bytes(f.data))[
                "period"]
            assert 0 <= period < 5000


# -- what export refuses, and leaves nothing behind ---------------------------------------


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


def test_mf4_destinations(run: RunResult, tmp_path: Path,
                          capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "dest"
    d.mkdir()
    # a name that is not an MDF4 file's: a usage error, no file, no orphan temporary file
    assert cli.main(["export", str(run.out_dir), "--mf4", str(d / "smoke.dat")]) == 2
    assert "smoke.dat: an MDF4 file is named *.mf4" in capsys.readouterr().err
    assert list(d.iterdir()) == []
    # a folder: the file goes into it, named after the scenario
    assert cli.main(["export", str(run.out_dir), "--mf4", str(d)]) == 0
    assert [p.name for p in d.iterdir()] == ["smoke.mf4"]
    MDF(d / "smoke.mf4").close()
    # a device (or a FIFO): never replaced by a rename, nothing written next to it
    before = os.stat("/dev/full")
    assert cli.main(["export", str(run.out_dir), "--mf4", "/dev/full"]) == 2
    assert "/dev/full: an MDF4 file is named *.mf4" in capsys.readouterr().err
    os.mkfifo(d / "pipe.mf4")
    assert cli.main(["export", str(run.out_dir), "--mf4", str(d / "pipe.mf4")]) == 2
    assert "is not a regular file" in capsys.readouterr().err
    assert cli.main(["export", str(run.out_dir), "--can-log", "/dev/full"]) == 2
    assert "a CAN log" in capsys.readouterr().err
    after = os.stat("/dev/full")
    assert (before.st_ino, before.st_rdev) == (after.st_ino, after.st_rdev)
    assert [n for n in os.listdir("/dev") if ".tmp-" in n] == []
    # a folder that cannot be made (nor written, as root too): exit 3
    assert cli.main(["export", str(run.out_dir), "--mf4", "/proc/no-such/x.mf4"]) == 3
    assert "cannot write" in capsys.readouterr().err
    assert _leftovers(d) == [] and _leftovers(run.out_dir) == []


def test_mf4_without_a_name_stays_in_the_run_folder(run: RunResult, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    """Issue 36.7: a result.json whose scenario is ../../x wrote the file two folders up; a
    result.json that is a list was a traceback; an upper-case .MF4 left a 1 MB temporary
    file behind."""
    top = tmp_path / "top"
    d = top / "a" / "b" / "run"
    shutil.copytree(run.out_dir, d)
    result = d / "result.json"
    data = json.loads(result.read_text())
    result.write_text(json.dumps({**data, "scenario": "../../x"}))
    assert cli.main(["export", str(d), "--mf4"]) == 0
    assert sorted(p.relative_to(top).as_posix() for p in top.rglob("*.mf4")) == [
        "a/b/run/x.mf4"]
    result.write_text(json.dumps({**data, "scenario": "../.."}))
    assert cli.main(["export", str(d), "--mf4"]) == 0
    assert (d / "run.mf4").is_file() and not list(top.glob("*.mf4"))
    result.write_text("[1, 2]")
    assert cli.main(["export", str(d), "--mf4"]) == 2
    assert "is not a run's result" in capsys.readouterr().err
    result.write_text(json.dumps(data))
    upper = tmp_path / "up"
    upper.mkdir()
    assert cli.main(["export", str(d), "--mf4", str(upper / "X.MF4")]) == 0
    assert [p.name for p in upper.iterdir()] == ["X.MF4"]
    MDF(upper / "X.MF4").close()


def _copy(run: RunResult, tmp_path: Path) -> Path:
    d = tmp_path / "copy"
    shutil.copytree(run.out_dir, d)
    return d


@pytest.mark.parametrize("damage", ["cut_at_record", "cut_mid_record", "magic", "record_size",
                                    "rig_trace_cut"])
def test_a_damaged_trace_is_an_error_not_a_shorter_log(run: RunResult, tmp_path: Path,
                                                        damage: str,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    d = _copy(run, tmp_path)
    trace = d / ("rig.trace" if damage == "rig_trace_cut" else "plant.trace")
    raw = bytearray(trace.read_bytes())
    n = (len(raw) - HEADER_SIZE) // RECORD_SIZE
    if damage == "cut_at_record":  # (the issue: 11 944 of 15 000 frames, exit 0)
        raw = raw[: HEADER_SIZE + (n * 4 // 5) * RECORD_SIZE]
    elif damage in ("cut_mid_record", "rig_trace_cut"):
        raw = raw[: HEADER_SIZE + (n // 2) * RECORD_SIZE + 13]
    elif damage == "magic":
        raw[:8] = b"NOTATRCE"
    else:
        raw[12:16] = (64).to_bytes(4, "little")
    trace.write_bytes(bytes(raw))
    dest = tmp_path / "out.blf"
    assert cli.main(["export", str(d), "--can-log", str(dest)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and str(trace) in err
    assert {"cut_at_record": "was cut short", "cut_mid_record": "ends in a partial record",
            "magic": "not a HIL trace", "record_size": "record size 64",
            "rig_trace_cut": "ends in a partial record"}[damage] in err
    assert not dest.exists() and _leftovers(tmp_path) == []
    assert cli.main(["export", str(d), "--mf4", str(tmp_path / "x.mf4")]) == 2
    assert not (tmp_path / "x.mf4").exists() and _leftovers(tmp_path) == []


@pytest.mark.parametrize("meta", [b"{not json", b'{"n": 3}', b"[]"])
def test_a_damaged_capture_is_an_error(run: RunResult, tmp_path: Path, meta: bytes,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    d = _copy(run, tmp_path)
    (d / "capture" / "meta.json").write_bytes(meta)
    assert cli.main(["export", str(d), "--mf4", str(tmp_path / "x.mf4")]) == 2
    err = capsys.readouterr().err
    assert "capture is damaged" in err and "Traceback" not in err
    assert not (tmp_path / "x.mf4").exists()


def test_export_needs_the_full_rate_data(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "passing"
    assert cli.main(["run", "smoke", "--bus", "inproc", "--quiet", "--out", str(out)]) == 0
    assert cli.main(["export", str(out), "--mf4"]) == 2
    err = capsys.readouterr().err
    assert "no capture columns" in err and "--keep-all" in err
    assert cli.main(["export", str(out), "--can-log", str(tmp_path / "x.blf")]) == 2
    assert "no trace plant.trace" in capsys.readouterr().err
    assert not (tmp_path / "x.blf").exists()
    assert cli.main(["export", str(out), "--can-log", str(tmp_path / "x.txt")]) == 2
    assert cli.main(["export", str(out)]) == 2
    assert cli.main(["export", str(tmp_path / "nothing"), "--mf4"]) == 2
