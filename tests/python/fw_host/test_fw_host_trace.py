"""Data log: one FW_TRACE record per ISR in the trace file (and on the bus with --send-trace)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from fwhost_support import Peer, StartFw

HEADER = struct.Struct("<8sII")
RECORD = 72


def read_trace(path: Path) -> list[tuple[int, int, bytes]]:
    raw = path.read_bytes()
    magic, version, size = HEADER.unpack_from(raw)
    assert (magic, version, size) == (b"HILTRACE", 1, RECORD)
    body = raw[HEADER.size:]
    assert len(body) % RECORD == 0
    out = []
    for off in range(0, len(body), RECORD):
        can_id, length = struct.unpack_from("<IB", body, off)
        out.append((can_id, length, body[off + 8: off + 8 + length]))
    return out


def test_trace_has_one_record_per_isr(start_fw: StartFw, peer: Peer, tmp_path: Path) -> None:
    trace = tmp_path / "fw.trace"
    fw = start_fw("--trace", str(trace), "--send-trace")
    pwms = peer.run(20, 5)
    peer.step_after_loss(27, pwms[-1]["n_soc"])  # 25 and 26 lost: ISRs without data
    peer.drain()
    assert fw.stop() == 0
    c = fw.counters()
    recs = read_trace(trace)
    assert len(recs) == c["isr"] == c["trace_records"] == 8
    m = peer.msg("FW_TRACE")
    rows = []
    for can_id, length, data in recs:
        assert can_id == m.frame_id and length == 64
        rows.append(peer.decode_data("FW_TRACE", data))
    assert [r["period"] for r in rows] == list(range(20, 28))
    for r in rows:
        assert -32768 <= r["stamp"] <= 32767 and r["state"] in (1, 4)
        assert 0.0 <= r["theta_hat"] < 6.2832
    assert rows[0]["ld_hat"] == pytest.approx(0.015, rel=1e-6)  # nominal Ld at start
    on_bus = [peer.decode(f)["period"] for f in peer.log if f.arbitration_id == m.frame_id]
    assert on_bus == list(range(20, 28)) and c["trace_sent"] == 8


def test_trace_is_complete_after_sigint(start_fw: StartFw, peer: Peer, tmp_path: Path) -> None:
    import signal

    trace = tmp_path / "fw.trace"
    fw = start_fw("--trace", str(trace))
    peer.run(0, 300)
    assert fw.stop(signal.SIGINT) == 0
    assert len(read_trace(trace)) == 300
