"""One new telemetry signal = one edit (protocols/README.md): every FW_TRACE signal of
protocols/vio.dbc is packed from the fw_status_t field of its name by the code fw_host and the
in-process bench run (generated from the DBC at build time), reaches the capture as column
fw.<signal> and appears in the recording; and a signal added to FW_TRACE in the DBC, and nowhere
else, does all of that too."""

from __future__ import annotations

import ctypes as C
import shutil
import subprocess
import sys
from pathlib import Path

import fwlib
import numpy as np
import pytest
from cantools.database.can import Database, Message, Signal

from rig import protocols
from rig.bench import sil
from rig.data import capture
from rig.data.trace import TraceWriter
from rig.results import recording

REPO = Path(__file__).resolve().parents[3]
PERIODS = 40


def int_range(sig: Signal) -> tuple[int, int]:
    lo = sig.minimum if sig.minimum is not None else (
        -(2 ** (sig.length - 1)) if sig.is_signed else 0)
    hi = sig.maximum if sig.maximum is not None else (
        2 ** (sig.length - 1) - 1 if sig.is_signed else 2**sig.length - 1)
    return int(lo), int(hi)


def distinct_values(msg: Message) -> dict[str, float | int]:
    """A value for every signal, no two alike where their ranges allow (a signal packed from
    another field would show): floats exactly representable in float32, integers the largest
    of their range not taken yet."""
    out: dict[str, float | int] = {}
    taken: set[int] = set()
    for k, sig in enumerate(msg.signals):
        if sig.is_float:
            out[sig.name] = 0.5 + 0.25 * k
            continue
        lo, hi = int_range(sig)
        v = hi
        while v in taken and v > lo:
            v -= 1
        taken.add(v)
        out[sig.name] = v
    return out


def status_with(values: dict[str, float | int]) -> C.Structure:
    st = fwlib.status_type()()
    for name, v in values.items():
        setattr(st, name, v)
    return st


def pack(st: C.Structure) -> bytes:
    lib = sil.library()
    lib.sil_bench_fw_trace_record.restype = C.c_int
    lib.sil_bench_fw_trace_record.argtypes = [C.c_void_p, C.c_char_p]
    lib.sil_bench_sizeof_fw_status.restype = C.c_size_t
    assert lib.sil_bench_sizeof_fw_status() == C.sizeof(st), "fw_status_t in libsilbench.so"
    buf = C.create_string_buffer(64)
    n = lib.sil_bench_fw_trace_record(C.byref(st), buf)
    return buf.raw[:n]


def fw_trace() -> Message:
    return protocols.database("vio").get_message_by_name("FW_TRACE")


def write_traces(folder: Path, fw_records: list[bytes], fw_id: int) -> list[capture.TraceSpec]:
    """A plant trace of zeros and the firmware records, one per period."""
    truth = protocols.database("bench").get_message_by_name("BENCH_TRUTH")
    mag = protocols.database("bench").get_message_by_name("BENCH_TRUTH_MAG")
    plant_path, fw_path = folder / "plant.trace", folder / "fw.trace"
    with TraceWriter(plant_path) as pw, TraceWriter(fw_path) as fw:
        for i, rec in enumerate(fw_records):
            for m in (truth, mag):
                pw.write(m.frame_id, m.encode({s.name: 0 for s in m.signals} | {"period": i}))
            fw.write(fw_id, rec)
    return capture.default_specs(plant_path, fw_path)


def check_everywhere(msg: Message, records: list[bytes], want: dict[str, float | int],
                     tmp_path: Path) -> None:
    """The capture has a column fw.<signal> with the packed values (the period is the merge
    key, the column period); the recording shows every signal."""
    cap, loss = capture.build(tmp_path / "capture", write_traces(tmp_path, records, msg.frame_id))
    assert loss.ok, loss.summary()
    assert np.array_equal(np.asarray(cap["period"]), np.arange(len(records)))  # the merge key
    for sig in msg.signals:
        if sig.name != "period":
            col = np.asarray(cap[f"fw.{sig.name}"])
            assert np.array_equal(col, np.full(len(records), want[sig.name])), sig.name
    shown = ({k for s in recording.SERIES for k in s.keys} | recording.SHOWN_DERIVED
             | {k for s in recording.trace_series(cap.columns) for k in s.keys})
    assert {f"fw.{s.name}" for s in msg.signals} <= shown
    rows = recording.entity_rows(recording.write(tmp_path / "r.rrd", cap)["path"])
    for s in recording.trace_series(cap.columns):
        assert rows[s.entity] == len(records) // recording.DISPLAY_DECIMATE, s.entity


def test_every_fw_trace_signal_is_carried_from_its_status_field(tmp_path: Path) -> None:
    msg = fw_trace()
    fields = fwlib.status_fields()
    assert [s.name for s in msg.signals if s.name not in fields] == []
    want = distinct_values(msg)
    records = []
    for i in range(PERIODS):
        data = pack(status_with(want | {"period": i}))
        got = msg.decode(data, decode_choices=False)
        assert got == want | {"period": i}
        records.append(data)
    check_everywhere(msg, records, want, tmp_path)


def test_integers_beyond_their_dbc_range_are_saturated() -> None:
    msg = fw_trace()
    st = status_with({"state": -1, "sector": 9, "slopes_ok": 7, "fw_active": 2})
    got = msg.decode(pack(st), decode_choices=False)
    assert (got["state"], got["sector"], got["slopes_ok"], got["fw_active"]) == (0, 6, 3, 1)


# ---- the one edit: a status field the trace does not carry yet, added to the DBC only ----

NEW_SIGNAL = ' SG_ polarity_ok : 54|1@1+ (1,0) [0|1] "" RIG\n'  # bits 54..55 are free
PROBE = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fw_trace_gen.h"
/* every field of fw_status_t set to a value made from its position (fwlib.status_fields) */
#define SET(type, name) s.name = (type)(k % 2 ? (double)(k + 1) : 0.25 * (double)(k + 1)); k++;
int main(int argc, char **argv)
{
    fw_status_t s;
    struct hil_vio_fw_trace_t m;
    unsigned char data[64];
    int k = 0, i, p;
    const int periods = argc > 1 ? atoi(argv[1]) : 1;
    memset(&s, 0, sizeof(s));
    FW_STATUS_FIELDS(SET)
    for (p = 0; p < periods; p++) { /* one FW_TRACE record per period, as fw_host writes */
        s.period = (uint32_t)p;
        memset(&m, 0, sizeof(m));
        fwh_trace_from_status(&s, &m);
        hil_vio_fw_trace_pack(data, &m, sizeof(data));
        for (i = 0; i < 64; i++) printf("%02x", data[i]);
        printf("\n");
    }
    return 0;
}
"""


def probe_value(k: int, sig: Signal) -> float | int:
    """What PROBE puts into the k-th field, as the DBC signal carries it."""
    v = float(k + 1) if k % 2 else 0.25 * (k + 1)
    if sig.is_float:
        return v
    lo, hi = int_range(sig)
    return min(max(int(v), lo), hi)  # C's conversion truncates; then the packer saturates


def test_a_signal_added_to_the_dbc_alone_is_carried_everywhere(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler")
    protocols_dir = tmp_path / "protocols"
    shutil.copytree(REPO / "protocols", protocols_dir)
    vio = protocols_dir / "vio.dbc"
    text = vio.read_text()
    anchor = ' SG_ fw_active : 60|1@1+ (1,0) [0|1] "" RIG\n'
    assert anchor in text
    vio.write_text(text.replace(anchor, anchor + NEW_SIGNAL))  # the one edit

    gen = tmp_path / "gen"
    tools = REPO / "firmware_c2000" / "tools"
    for cmd in ([sys.executable, "-m", "cantools", "generate_c_source", "--use-round",
                 "--database-name", "hil_vio", "-o", str(gen), str(vio)],
                [sys.executable, str(tools / "gen_wire.py"), "core", str(gen), str(protocols_dir)],
                [sys.executable, str(tools / "gen_wire.py"), "trace", str(gen),
                 str(protocols_dir)]):
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
    (tmp_path / "probe.c").write_text(PROBE)
    exe = tmp_path / "probe"
    r = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror",
                        "-I", str(REPO / "firmware_c2000" / "core" / "include"), "-I", str(gen),
                        str(tmp_path / "probe.c"), str(gen / "fw_trace_gen.c"),
                        str(gen / "hil_vio.c"), "-lm", "-o", str(exe)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = subprocess.run([str(exe), str(PERIODS)], capture_output=True, text=True, check=True,
                         timeout=30).stdout.split()
    records = [bytes.fromhex(line) for line in out]
    assert len(records) == PERIODS

    edited = Database()
    edited.add_dbc_file(str(vio))
    msg = edited.get_message_by_name("FW_TRACE")
    assert "polarity_ok" in [s.name for s in msg.signals]
    fields = fwlib.status_fields()
    want = {s.name: probe_value(fields.index(s.name), s) for s in msg.signals}
    for i, rec in enumerate(records):
        assert msg.decode(rec, decode_choices=False) == want | {"period": i}

    # the rig reads the edited DBC: the capture's column and the recording follow
    original = protocols.database
    monkeypatch.setattr(protocols, "database",
                        lambda name: edited if name == "vio" else original(name))
    check_everywhere(msg, records, want, tmp_path)
    assert "firmware/polarity_ok" in {s.entity for s in recording.trace_series(
        [f"fw.{s.name}" for s in msg.signals])}
