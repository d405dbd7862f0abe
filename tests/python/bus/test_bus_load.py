"""The drive protocol's bus load from its DBC (``rig bus load``): frame lengths against the
closed form of the CAN schedulability literature, and the default telemetry's share of the
lab's 1 Mbit/s classic-CAN bus."""

from __future__ import annotations

import subprocess
import sys

import pytest

from rig.bus import load


@pytest.mark.parametrize("data_bytes", range(9))
def test_worst_case_frame_bits_match_the_closed_form(data_bytes: int) -> None:
    # Davis, Burns, Bril, Lukkien (2007), "Controller Area Network (CAN) schedulability
    # analysis: refuted, revisited and revised", eq. (2)-(3): 55 + 10 s bits with an 11-bit
    # id, 80 + 10 s with a 29-bit id, s data bytes, worst-case stuffing
    assert load.frame_bits(data_bytes) == 55 + 10 * data_bytes
    assert load.frame_bits(data_bytes, extended=True) == 80 + 10 * data_bytes


def test_more_than_eight_bytes_is_not_classic_can() -> None:
    with pytest.raises(ValueError):
        load.frame_bits(9)


def test_the_table_counts_every_cyclic_message_at_its_rate() -> None:
    loads = {x.name: x for x in load.message_loads("drive")}
    rate = load.bitrate("drive")
    assert rate == 1_000_000  # the F2808's eCAN in the lab (README: ip link ... bitrate)
    # DRIVE_CMD every 10 ms: 100 frames of 135 bits a second
    assert loads["DRIVE_CMD"].pct(rate) == pytest.approx(100 * 135 / 1e6 * 100)
    assert loads["PARAM_REQ"].cycle_ms is None and loads["PARAM_REQ"].pct(rate) == 0.0
    expected = sum(100.0 * load.frame_bits(x.length) * 1000.0 / x.cycle_ms / rate
                   for x in loads.values() if x.cycle_ms)
    assert load.total_pct(list(loads.values()), rate) == pytest.approx(expected)


@pytest.mark.xfail(strict=True, reason=(
    "measured 69.1 %: the five TLM_* messages (8 bytes at 1 kHz, the speed-loop rate) take "
    "67.5 % of 1 Mbit/s with worst-case stuffing; holding 60 % needs fewer, shorter or "
    "slower telemetry frames in protocols/drive.dbc, a protocol decision"))
def test_the_default_telemetry_stays_under_60_percent() -> None:
    loads = load.message_loads("drive")
    assert load.total_pct(loads, load.bitrate("drive")) < load.TELEMETRY_LIMIT_PCT


def test_rig_bus_load_prints_the_table_and_says_what_it_decided() -> None:
    r = subprocess.run([sys.executable, "-m", "rig", "bus", "load"], capture_output=True,
                       text=True, check=False, timeout=120)
    total = load.total_pct(load.message_loads("drive"), load.bitrate("drive"))
    assert f"{total:.2f}" in r.stdout.splitlines()[-1]
    assert "TLM_POS" in r.stdout and "(on demand)" in r.stdout
    assert r.returncode == (1 if total > load.TELEMETRY_LIMIT_PCT else 0), r
    if r.returncode:
        assert "above 60 %" in r.stderr
