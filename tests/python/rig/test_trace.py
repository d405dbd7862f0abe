"""Trace files: header checks, chunked reading, vectorised decode == cantools per frame."""

from __future__ import annotations

import struct
from pathlib import Path

import cantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig import protocols
from rig.data.trace import (
    HEADER,
    RECORD_DTYPE,
    MessageDecoder,
    TraceDecoder,
    TraceError,
    TraceFile,
    TraceWriter,
    concat,
    decode_file,
    make_records,
)

ALL_MESSAGES = [m for db in protocols.DATABASES for m in protocols.database(db).messages]


def _cantools_columns(msg, payloads: list[bytes]) -> dict[str, list[float]]:  # type: ignore[no-untyped-def]
    out: dict[str, list[float]] = {s.name: [] for s in msg.signals}
    for p in payloads:
        d = msg.decode(p, decode_choices=False, scaling=True)
        for k, v in d.items():
            out[k].append(float(v))
    return out


@pytest.mark.parametrize("msg", ALL_MESSAGES, ids=lambda m: m.name)
def test_vectorised_decode_equals_cantools_on_random_frames(msg) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(msg.frame_id)
    payloads = [rng.integers(0, 256, msg.length, dtype=np.uint8).tobytes() for _ in range(300)]
    dec = MessageDecoder(msg)
    assert not dec.fallback, f"{msg.name}: every signal of our DBCs is vectorised"
    got = dec.decode(make_records(msg.frame_id, payloads)["data"])
    want = _cantools_columns(msg, payloads)
    assert set(got) == set(want)
    for name in want:
        np.testing.assert_array_equal(np.asarray(got[name], dtype=np.float64),
                                      np.asarray(want[name]), err_msg=f"{msg.name}.{name}")


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_vectorised_decode_equals_cantools_on_encoded_values(data: st.DataObject) -> None:
    msg = data.draw(st.sampled_from(ALL_MESSAGES))
    values = {}
    for s in msg.signals:
        lo = s.minimum if s.minimum is not None else 0
        hi = s.maximum if s.maximum is not None else 1
        if s.is_float:
            values[s.name] = data.draw(st.floats(min_value=-1e6, max_value=1e6, width=32))
        else:
            raw = data.draw(st.integers(min_value=int(s.scaled_to_raw(lo)),
                                        max_value=int(s.scaled_to_raw(hi))))
            values[s.name] = s.raw_to_scaled(raw)
    payload = msg.encode(values, strict=False)
    got = MessageDecoder(msg).decode(make_records(msg.frame_id, [payload])["data"])
    want = msg.decode(payload, decode_choices=False)
    for name, v in want.items():
        assert float(got[name][0]) == float(v), name


BIG_ENDIAN_DBC = """VERSION ""
NS_ :
BS_:
BU_: A
BO_ 100 MIXED: 8 A
 SG_ be16 : 7|16@0- (0.5,-3) [-100000|100000] "" A
 SG_ le12 : 20|12@1+ (1,0) [0|4095] "" A
 SG_ be5 : 39|5@0+ (2,1) [0|100] "" A
"""


def test_big_endian_signals_fall_back_to_cantools(tmp_path: Path) -> None:
    db = cantools.database.load_string(BIG_ENDIAN_DBC, database_format="dbc")
    msg = db.get_message_by_name("MIXED")
    dec = MessageDecoder(msg)
    assert sorted(dec.fallback) == ["be16", "be5"]
    rng = np.random.default_rng(1)
    payloads = [rng.integers(0, 256, 8, dtype=np.uint8).tobytes() for _ in range(50)]
    got = dec.decode(make_records(msg.frame_id, payloads)["data"])
    want = _cantools_columns(msg, payloads)
    for name in want:
        np.testing.assert_array_equal(np.asarray(got[name], np.float64), want[name])


def _write_trace(path: Path, n: int) -> list[bytes]:
    msg = protocols.database("bench").get_message_by_name("BENCH_TRUTH")
    payloads = []
    with TraceWriter(path) as w:
        for i in range(n):
            p = msg.encode({s.name: 0 for s in msg.signals} | {"period": i, "theta_e": i * 0.5},
                           strict=False)
            payloads.append(p)
            w.write(msg.frame_id, p)
    return payloads


def test_chunked_reading_matches_whole_file(tmp_path: Path) -> None:
    path = tmp_path / "t.trace"
    _write_trace(path, 1000)
    msg = protocols.database("bench").get_message_by_name("BENCH_TRUTH")
    assert path.stat().st_size == 16 + 1000 * 72
    tf = TraceFile.open(path)
    assert tf.n_records == 1000 and tf.trailing_bytes == 0
    whole = concat([s.by_name["BENCH_TRUTH"] for s in decode_file(path, [msg], chunk=10**6)])
    chunked = concat([s.by_name["BENCH_TRUTH"] for s in decode_file(path, [msg], chunk=7)])
    for k in whole:
        np.testing.assert_array_equal(whole[k], chunked[k])
    np.testing.assert_array_equal(whole["period"], np.arange(1000))
    np.testing.assert_array_equal(whole["theta_e"], np.arange(1000) * 0.5)


def test_records_are_struct_canfd_frame(tmp_path: Path) -> None:
    path = tmp_path / "t.trace"
    payloads = _write_trace(path, 3)
    raw = path.read_bytes()
    assert raw[:16] == HEADER.pack(b"HILTRACE", 1, 72)
    can_id, length, flags, _, _ = struct.unpack_from("<IBBBB", raw, 16 + 72)
    assert (can_id, length) == (768, 64) and flags & 0x04
    assert raw[16 + 72 + 8 : 16 + 2 * 72] == payloads[1]
    assert RECORD_DTYPE.itemsize == 72


def test_split_counts_unknown_ids_and_short_frames() -> None:
    truth = protocols.database("bench").get_message_by_name("BENCH_TRUTH")
    good = truth.encode({s.name: 0 for s in truth.signals}, strict=False)
    recs = np.concatenate([
        make_records(truth.frame_id, [good, good]),
        make_records(0x7AB, [b"\x01\x02"]),
        make_records(truth.frame_id, [good[:8]]),
    ])
    split = TraceDecoder([truth]).split(recs)
    assert split.unknown == 1 and split.bad_length == 1
    assert len(split.by_name["BENCH_TRUTH"]["period"]) == 2


@pytest.mark.parametrize(
    "content, message",
    [
        (b"HILTRAC", "shorter than"),
        (b"NOTATRCE" + struct.pack("<II", 1, 72), "not a HIL trace"),
        (b"HILTRACE" + struct.pack("<II", 2, 72), "version 2"),
        (b"HILTRACE" + struct.pack("<II", 1, 16), "record size 16"),
    ],
)
def test_bad_headers_are_rejected(tmp_path: Path, content: bytes, message: str) -> None:
    p = tmp_path / "bad.trace"
    p.write_bytes(content)
    with pytest.raises(TraceError, match=message):
        TraceFile.open(p)


def test_partial_last_record_is_reported(tmp_path: Path) -> None:
    p = tmp_path / "t.trace"
    _write_trace(p, 5)
    with p.open("ab") as fh:
        fh.write(b"\x00" * 30)
    tf = TraceFile.open(p)
    assert tf.n_records == 5 and tf.trailing_bytes == 30
