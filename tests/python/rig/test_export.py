"""rig export: the MDF4 file and the CAN logs, read back with asammdf and python-can and
compared with the capture value for value (the DBC decoded by cantools itself)."""

from __future__ import annotations

import math
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from asammdf import MDF

from rig import capture, cli, protocols
from rig.run.result import RunResult

PREFIX = {"BENCH_TRUTH": "truth", "BENCH_TRUTH_MAG": "mag", "FW_TRACE": "fw"}


@pytest.fixture
def run(hil_run) -> RunResult:  # type: ignore[no-untyped-def]
    r = hil_run("smoke", bus="inproc", keep="all")
    assert r.passed and r.capture is not None
    return r


def _dbc() -> cantools.database.can.Database:
    db = cantools.database.can.Database()
    for name in protocols.DATABASES:
        db.add_dbc_file(str(protocols.path(name)))
    return db


def test_mf4_holds_the_capture_value_for_value(run: RunResult, tmp_path: Path) -> None:
    cap = run.capture
    assert cap is not None
    dest = tmp_path / "smoke.mf4"
    assert cli.main(["export", str(run.out_dir), "--mf4", str(dest)]) == 0
    db = _dbc()
    units = {f"{PREFIX[m.name]}.{s.name}": s.unit or ""
             for m in db.messages if m.name in PREFIX for s in m.signals}
    t = np.asarray(cap["period"], dtype=np.float64) * capture.TS
    with MDF(dest) as mdf:
        assert mdf.version == "4.10"
        names = {ch.name for group in mdf.groups for ch in group.channels} - {"time"}
        assert names == set(cap.keys()) - {"period"}
        for column in names:
            sig = mdf.get(column)
            want = np.asarray(cap[column])
            assert sig.samples.dtype == want.dtype, column
            np.testing.assert_array_equal(sig.samples, want, err_msg=column)
            np.testing.assert_array_equal(sig.timestamps, t, err_msg=column)
            expected_unit = units.get(column, capture.DERIVED_UNITS.get(column))
            assert sig.unit == expected_unit, column
        assert mdf.get("fw.theta_hat").unit == "rad" and mdf.get("pos_err_deg").unit == "deg"


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log"])
def test_can_log_holds_every_frame_value_for_value(run: RunResult, tmp_path: Path,
                                                   suffix: str) -> None:
    cap = run.capture
    assert cap is not None
    dest = tmp_path / f"frames{suffix}"
    assert cli.main(["export", str(run.out_dir), "--can-log", str(dest)]) == 0
    frames = list(can.LogReader(dest))
    n = cap.n
    assert len(frames) == 3 * n  # BENCH_TRUTH and BENCH_TRUTH_MAG per period, FW_TRACE per ISR
    db = _dbc()
    t_first = frames[0].timestamp
    seen = {name: np.zeros(n, dtype=bool) for name in PREFIX}
    for f in frames:
        assert f.is_fd and len(f.data) == 64
        msg = db.get_message_by_frame_id(f.arbitration_id)
        values = msg.decode(bytes(f.data), decode_choices=False)
        assert isinstance(values, dict)
        row = int(values["period"]) - cap.first_period
        assert round((f.timestamp - t_first) / capture.TS) == int(values["period"])
        channel = int(str(f.channel).removeprefix("can"))
        assert channel == (1 if msg.name == "FW_TRACE" else 0)
        for sig, v in values.items():
            if sig == "period":
                continue
            want = float(cap[f"{PREFIX[msg.name]}.{sig}"][row])
            assert v == want or (math.isnan(v) and math.isnan(want)), (msg.name, sig, row)
        seen[msg.name][row] = True
    assert all(s.all() for s in seen.values())  # every period of every message


def test_export_needs_the_full_rate_data(hil_run, tmp_path: Path,  # type: ignore[no-untyped-def]
                                         capsys: pytest.CaptureFixture[str]) -> None:
    r = hil_run("smoke", bus="inproc", keep="failing")
    assert r.passed
    assert cli.main(["export", str(r.out_dir), "--mf4"]) == 2
    err = capsys.readouterr().err
    assert "no capture columns" in err and "--keep-all" in err
    assert cli.main(["export", str(r.out_dir), "--can-log", str(tmp_path / "x.blf")]) == 2
    assert "no trace plant.trace" in capsys.readouterr().err
    assert not (tmp_path / "x.blf").exists()
    assert cli.main(["export", str(r.out_dir), "--can-log", str(tmp_path / "x.txt")]) == 2
    assert cli.main(["export", str(r.out_dir)]) == 2
    assert cli.main(["export", str(tmp_path / "nothing"), "--mf4"]) == 2
