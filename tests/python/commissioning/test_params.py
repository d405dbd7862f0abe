"""CAN parameter access (rig.drive.params over PARAM_REQ / PARAM_RESP) against fw_host on a running
virtual bench, and ``rig param``. Expected values come from protocols/parameters.csv."""

from __future__ import annotations

import csv
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator

import numpy as np
import pytest
from waits import EVENT_S, RUN_S

from rig import _paths
from rig.bus import unixcan
from rig.commissioning.session import BenchSession
from rig.drive.params import ParamClient, ParamError, ParamTimeout, table
from rig.link.bus import BusLink


def csv_rows() -> dict[str, dict[str, str]]:
    with (_paths.data_dir("protocols") / "parameters.csv").open(newline="") as fh:
        return {r["name"]: r for r in csv.DictReader(fh)}


@pytest.fixture
def bench(module_bench: BenchSession) -> Iterator[BenchSession]:
    s = module_bench
    yield s
    for name in ("rs_ohm", "ld_h", "pll_bw_hz"):
        s.params.set(name, float(csv_rows()[name]["default"]))


def reqs(s: BenchSession) -> int:
    assert s.console is not None
    return int(s.console.counters()["param_reqs"])


def test_get_by_name_and_id_matches_the_csv(bench: BenchSession) -> None:
    rows = csv_rows()
    p = bench.params
    for name in ("rs_ohm", "ld_h", "lq_h", "lambda_m_wb", "pole_pairs", "fw_version"):
        want = float(np.float32(float(rows[name]["default"])))
        assert p.get(name) == want
        assert p.get(int(rows[name]["id"])) == want
        assert p.get(rows[name]["id"]) == want


def test_list_reads_every_parameter(bench: BenchSession) -> None:
    got = bench.params.list()
    assert [info.name for info, _ in got] == sorted(csv_rows(), key=lambda n: int(
        csv_rows()[n]["id"]))


def test_set_is_range_checked_here_and_read_back(bench: BenchSession) -> None:
    p = bench.params
    assert p.set("rs_ohm", 2.2) == float(np.float32(2.2))
    assert bench.console is not None and bench.console.get("rs_ohm") == pytest.approx(2.2)
    n = reqs(bench)
    for name, value in (("rs_ohm", 1000.0), ("rs_ohm", -1.0), ("fw_version", 2.0),
                        ("rs_ohm", float("nan"))):
        with pytest.raises(ParamError) as e:
            p.set(name, value)
        assert e.value.status == "LOCAL_RANGE"
    assert reqs(bench) == n  # nothing was sent
    with pytest.raises(ParamError, match="no parameter named"):
        p.get("rs")


def test_the_drive_checks_as_well(bench: BenchSession) -> None:
    p = bench.params
    with pytest.raises(ParamError) as e:
        p.set("rs_ohm", 1000.0, check_local=False)
    assert e.value.status == "OUT_OF_RANGE"
    with pytest.raises(ParamError) as e:
        p.set("ld_h", 0.05)  # inside its own range, but above lq_h: refused by the core
    assert e.value.status == "OUT_OF_RANGE"
    with pytest.raises(ParamError) as e:
        p.set("fw_version", 3.0, check_local=False)
    assert e.value.status == "READ_ONLY"
    assert p.get("ld_h") == float(np.float32(0.015))


def test_busy_while_enabled(bench: BenchSession) -> None:
    s = bench
    assert s.load is not None
    s.load.speed_hold(0.0)
    s.drive.set_limits(4.0, 3300.0, 3000.0)
    s.drive.enable(ctrl_mode="current", fw_mode="id_zero", iq_ref=0.0)
    try:
        with pytest.raises(ParamError) as e:
            s.params.set("rs_ohm", 2.0)
        assert e.value.status == "BUSY"
        assert s.params.set("pll_bw_hz", 70.0) == 70.0  # not a configuration parameter
    finally:
        s.drive.disable()
        s.load.off()


def test_save_and_load(bench: BenchSession) -> None:
    p = bench.params
    p.set("rs_ohm", 2.75)
    p.save()
    assert "rs_ohm = 2.75" in (bench.dir / "params.txt").read_text()
    p.set("rs_ohm", 1.5)
    p.load()
    assert p.get("rs_ohm") == 2.75


def test_no_answer_times_out(unix_channel: str) -> None:
    link = BusLink.open("unixcan", unix_channel)  # nobody else on this channel
    try:
        client = ParamClient(link, timeout_s=0.2, retries=1)
        t0 = time.monotonic()
        with pytest.raises(ParamTimeout, match=r"no PARAM_RESP with seq 2 within 0.2 s"):
            client.get("rs_ohm")
        # two attempts of 0.2 s each (new sequence number each: seq 2 is the second's)
        assert 0.4 <= time.monotonic() - t0 < EVENT_S
    finally:
        link.close()


def test_table_is_the_csv() -> None:
    rows = csv_rows()
    t = table()
    assert len(t) == len(rows)
    for name, r in rows.items():
        info = t.lookup(name)
        assert (info.id, info.unit, info.access) == (int(r["id"]), r["unit"], r["access"])


def test_cli(bench: BenchSession) -> None:
    def rig(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "rig", "param", "--bus", "unixcan",
                               "--channel", bench.link.channel, "--timeout", f"{EVENT_S:g}",
                               *args], capture_output=True, text=True, timeout=RUN_S,
                              check=False)

    done = rig("get", "rs_ohm")
    assert done.returncode == 0 and done.stdout.strip() == "rs_ohm = 1.92999995 ohm"
    done = rig("set", "pll_bw_hz", "75")
    assert done.returncode == 0 and "pll_bw_hz = 75 Hz (read back)" in done.stdout
    done = rig("set", "pll_bw_hz", "5000")
    assert done.returncode == 1 and "outside [1, 2000]" in done.stderr
    done = rig("list")
    assert done.returncode == 0 and len(done.stdout.splitlines()) == len(csv_rows())
    nobody = bench.link.channel + "-nobody"
    try:
        done = subprocess.run([sys.executable, "-m", "rig", "param", "--bus", "unixcan",
                               "--channel", nobody, "--timeout", "0.2", "get", "1"],
                              capture_output=True, text=True, timeout=60, check=False)
    finally:
        shutil.rmtree(unixcan.base_dir() / nobody, ignore_errors=True)
    assert done.returncode == 3 and "no PARAM_RESP" in done.stderr
