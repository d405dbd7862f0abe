"""protocols/parameters.csv is the single source of truth: the table compiled into the core
matches it, the generator rejects broken files, and the core API range-checks every set."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import fwlib
import pytest

ROOT = Path(__file__).resolve().parents[3]
CSV = ROOT / "protocols" / "parameters.csv"
GEN = ROOT / "firmware_c2000" / "tools" / "gen_params.py"


def rows() -> list[dict[str, str]]:
    with CSV.open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_compiled_table_matches_the_csv() -> None:
    assert fwlib.lib().fwt_real_size() == 4  # ParamInfo declares float fields
    table = fwlib.param_table()
    src = rows()
    assert [int(r["id"]) for r in src] == [p["id"] for p in table]
    for r, p in zip(src, table, strict=True):
        assert p["name"] == r["name"]
        assert p["unit"] == r["unit"]
        for key in ("min", "max", "default"):
            assert p[key] == pytest.approx(float(r[key]), rel=1e-6)
        assert p["read_only"] == (r["access"] == "ro")


def test_every_tunable_the_drive_needs_is_listed() -> None:
    names = {r["name"] for r in rows()}
    needed = {
        "rs_ohm",
        "ld_h",
        "lq_h",
        "lambda_m_wb",
        "pole_pairs",
        "inertia_kgm2",
        "vdc_nom_v",
        "adc_bits",
        "adc_range_a",
        "adc_vdc_bits",
        "adc_vdc_range_v",
        "tmin_us",
        "soc_on_us",
        "soc_off_us",
        "soc_per_state",
        "pll_bw_hz",
        "cur_kp_d",
        "cur_ki_d",
        "cur_kp_q",
        "cur_ki_q",
        "spd_kp",
        "spd_ki",
        "i_max_a",
        "speed_max_rpm",
        "accel_rpm_s",
        "cmd_timeout_ms",
        "adc_loss_max",
        "oc_trip_a",
        "ov_trip_v",
        "uv_trip_v",
        "pol_method",
        "stretch_enable",
    }
    assert needed <= names


def test_core_defaults_and_range_checks_follow_the_table() -> None:
    core = fwlib.Core()
    for p in fwlib.param_table():
        pid = int(p["id"])  # type: ignore[call-overload]
        st, value = core.param_get(pid)
        assert st == 0
        if not p["read_only"]:
            assert value == pytest.approx(p["default"], rel=1e-6)
            hi = float(p["max"])  # type: ignore[arg-type]
            lo = float(p["min"])  # type: ignore[arg-type]
            assert core.param_set(pid, hi + abs(hi) * 0.01 + 1.0) == 2
            assert core.param_set(pid, lo - abs(lo) * 0.01 - 1.0) == 2
            assert core.param_set(pid, float("nan")) == 2
            assert core.param_get(pid) == (0, value)
        else:
            assert core.param_set(pid, value) == 3
    assert core.param_get(60000)[0] == 1
    assert core.param_set(60000, 1.0) == 1


def run_gen(tmp_path: Path, text: str) -> int:
    src = tmp_path / "p.csv"
    src.write_text(text, encoding="utf-8")
    proc = subprocess.run(
        [sys.executable, str(GEN), str(src), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        check=False,
    )
    return proc.returncode


HEADER = "id,name,unit,min,max,default,access,description\n"


@pytest.mark.parametrize(
    "body",
    [
        "1,a,-,0,1,2,rw,default above max\n",
        "1,a,-,0,1,0.5,rw,x\n1,b,-,0,1,0.5,rw,duplicate id\n",
        "1,a,-,0,1,0.5,rw,x\n2,a,-,0,1,0.5,rw,duplicate name\n",
        "2,a,-,0,1,0.5,rw,x\n1,b,-,0,1,0.5,rw,unsorted\n",
        "1,Bad-Name,-,0,1,0.5,rw,not an identifier\n",
        "1,a,-,0,1,0.5,wo,bad access\n",
        "1,a,-,0,nan,0.5,rw,non-finite\n",
    ],
)
def test_generator_rejects_broken_tables(tmp_path: Path, body: str) -> None:
    assert run_gen(tmp_path, HEADER + body) == 1


def test_generator_accepts_the_real_table(tmp_path: Path) -> None:
    assert run_gen(tmp_path, CSV.read_text(encoding="utf-8")) == 0
    header = (tmp_path / "out" / "fw_params_gen.h").read_text(encoding="utf-8")
    assert f"#define FW_PARAM_COUNT {len(rows())}" in header
    assert run_gen(tmp_path, "id;name\n1;a\n") == 1
