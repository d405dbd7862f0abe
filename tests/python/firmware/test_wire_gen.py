"""The wire facts C gets generated from protocols/*.dbc (firmware_c2000/tools/gen_wire.py):
the same numbers Python reads, and a build that stops on a DBC whose facts disagree."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from rig import protocols

REPO = Path(__file__).resolve().parents[3]
GEN = REPO / "firmware_c2000" / "tools" / "gen_wire.py"


def generate(mode: str, out: Path, protocols_dir: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(GEN), mode, str(out), str(protocols_dir)],
                          capture_output=True, text=True, timeout=60)


def defines(path: Path) -> dict[str, str]:
    return dict(re.findall(r"^#define (\w+) (\S+)", path.read_text(), re.M))


def test_core_header_holds_the_dbc_facts(tmp_path: Path) -> None:
    assert generate("core", tmp_path, REPO / "protocols").returncode == 0
    d = defines(tmp_path / "fw_wire_gen.h")
    tb = protocols.timebase()
    assert d["FW_TBPRD"] == f"{tb.tbprd}u" and d["FW_PERIOD_TICKS"] == f"{tb.period_ticks}u"
    assert float(d["FW_TBCLK_HZ"].rstrip("f")) == tb.tbclk_hz
    assert float(d["FW_TS"].rstrip("f")) == tb.ts == 100e-6
    assert int(d["FW_SPEED_DIVIDER"]) == tb.speed_loop_divider == 10
    for prefix, message, signal in (("FW_FAULT_", "DRIVE_STATUS", "fault_code"),
                                    ("FW_STATE_", "DRIVE_STATUS", "state"),
                                    ("FW_CTRL_", "DRIVE_CMD", "ctrl_mode"),
                                    ("FW_FWMODE_", "DRIVE_CMD", "fw_mode"),
                                    ("FW_STATUS_", "PARAM_RESP", "status")):
        table = protocols.spelled("drive", message, signal)
        got = {k[len(prefix):]: int(v) for k, v in d.items()
               if k.startswith(prefix) and not k.endswith("WIRE_MAX")}
        assert got == table, prefix


def test_host_header_time_base(tmp_path: Path) -> None:
    assert generate("host", tmp_path, REPO / "protocols").returncode == 0
    d = defines(tmp_path / "hil_wire.h")
    tb = protocols.timebase()
    assert int(d["HIL_TBPRD"]) == tb.tbprd and int(d["HIL_PERIOD_TICKS"]) == tb.period_ticks
    assert d["HIL_PERIOD_NS"] == f"{tb.period_ns}LL" and tb.period_ns == 100_000
    assert int(d["HIL_SPEED_LOOP_DIVIDER"]) == tb.speed_loop_divider


def test_host_header_id_ranges(tmp_path: Path) -> None:
    """Each database's range as declared, every message inside it, and filter blocks that
    match exactly the range (checked over all 2048 ids against the range itself)."""
    assert generate("host", tmp_path, REPO / "protocols").returncode == 0
    d = defines(tmp_path / "hil_wire.h")
    source = (tmp_path / "hil_wire.c").read_text()
    for db in ("drive", "vio", "bench"):
        first, last = protocols.id_range(db)
        up = db.upper()
        assert int(d[f"HIL_{up}_ID_FIRST"].rstrip("u"), 16) == first
        assert int(d[f"HIL_{up}_ID_LAST"].rstrip("u"), 16) == last
        assert all(first <= m.frame_id <= last for m in protocols.database(db).messages)
        body = re.search(rf"hil_{db}_id_blocks\[HIL_{up}_ID_BLOCKS\] = \{{(.*?)\}};",
                         source, re.S)
        assert body is not None
        blocks = [(int(i, 16), int(m, 16))
                  for i, m in re.findall(r"\{0x([0-9A-F]+)u, 0x([0-9A-F]+)u\}", body[1])]
        assert len(blocks) == int(d[f"HIL_{up}_ID_BLOCKS"])
        matched = {x for x in range(0x800) if any(x & m == i for i, m in blocks)}
        assert matched == set(range(first, last + 1)), db
    assert protocols.id_range("vio") == (0x10, 0x2F)  # the fw_host filters' old 0x00-0x3F


@pytest.mark.parametrize("edit, needle", [
    (("vio.dbc", 'BA_ "HilTbprd" 5000;', 'BA_ "HilTbprd" 4000;'),
     "VIO_PWM.cmp_a_up range [0|5000], the time base (HilTbprd 4000) says [0|4000]"),
    (("drive.dbc", 'BA_ "HilSpeedLoopDivider" 10;', 'BA_ "HilSpeedLoopDivider" 20;'),
     "TLM_POS GenMsgCycleTime 1 ms is not HilSpeedLoopDivider (20) PWM periods"),
    (("vio.dbc", 'BA_ "HilTbclkHz" 100000000;\n', ""), "HilTbclkHz missing"),
    (("drive.dbc", ' 9 "OVERSPEED" ', ' 9 "OVER SPEED" '), "is not an upper-case C identifier"),
])
def test_disagreeing_facts_stop_the_build(tmp_path: Path, edit: tuple[str, str, str],
                                          needle: str) -> None:
    protocols_dir = tmp_path / "protocols"
    shutil.copytree(REPO / "protocols", protocols_dir)
    name, old, new = edit
    dbc = protocols_dir / name
    text = dbc.read_text()
    assert old in text
    dbc.write_text(text.replace(old, new))
    r = generate("core", tmp_path / "out", protocols_dir)
    assert r.returncode == 1 and needle in r.stderr, r.stderr


@pytest.mark.parametrize("edit, needle", [
    (("vio.dbc", 'BA_ "HilIdLast" 47;', 'BA_ "HilIdLast" 31;'),
     "vio.dbc: FW_TRACE (0x20) outside the database's ID range 0x10..0x1F"),
    (("bench.dbc", 'BA_ "HilIdFirst" 768;', 'BA_ "HilIdFirst" 769;'),
     "bench.dbc: BENCH_TRUTH (0x300) outside"),
    (("drive.dbc", 'BA_ "HilIdLast" 511;', 'BA_ "HilIdLast" 768;'),
     "bench.dbc: ID range 0x300..0x33F overlaps drive.dbc's 0x100..0x300"),
    (("drive.dbc", 'BA_ "HilIdFirst" 256;\n', ""),
     "drive.dbc: database attribute HilIdFirst missing"),
])
def test_id_range_disagreeing_with_messages_stops_the_build(
        tmp_path: Path, edit: tuple[str, str, str], needle: str) -> None:
    protocols_dir = tmp_path / "protocols"
    shutil.copytree(REPO / "protocols", protocols_dir)
    name, old, new = edit
    dbc = protocols_dir / name
    text = dbc.read_text()
    assert old in text
    dbc.write_text(text.replace(old, new))
    r = generate("host", tmp_path / "out", protocols_dir)
    assert r.returncode == 1 and needle in r.stderr, r.stderr


def test_array_signals_cover_every_soc_once(tmp_path: Path) -> None:
    """hil_arrays.h: ia_<k>/ib_<k> of VIO_ADC_0..2 and soc_<k> of VIO_PWM as arrays whose
    FIRST/COUNT put every SOC 0..n_soc max in exactly one frame, and each accessor reads the
    member of its signal (element j of VIO_ADC_1.ia is ia_<7 + j>)."""
    assert generate("arrays", tmp_path, REPO / "protocols").returncode == 0
    d = defines(tmp_path / "hil_arrays.h")
    vio = protocols.database("vio")
    n_soc = int(vio.get_message_by_name("VIO_PWM").get_signal_by_name("n_soc").maximum)
    assert (d["HIL_VIO_VIO_PWM_SOC_FIRST"], d["HIL_VIO_VIO_PWM_SOC_COUNT"]) == ("0", str(n_soc))
    for base in ("IA", "IB"):
        socs: list[int] = []
        for x in range(3):
            first, count = (int(d[f"HIL_VIO_VIO_ADC_{x}_{base}_{f}"]) for f in ("FIRST", "COUNT"))
            names = {s.name for s in vio.get_message_by_name(f"VIO_ADC_{x}").signals}
            assert {f"{base.lower()}_{k}" for k in range(first, first + count)} <= names
            socs += range(first, first + count)
        assert socs == list(range(n_soc))
    source = (tmp_path / "hil_arrays.c").read_text()
    body = source[source.index("hil_vio_vio_adc_1_ia_get"):]
    assert "case 0: return m->ia_7;" in body and "case 6: return m->ia_13;" in body
