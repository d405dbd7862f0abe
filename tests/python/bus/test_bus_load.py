"""The drive protocol's bus load from its DBC (``rig bus load``): frame lengths against the
closed form of the CAN schedulability literature, the default telemetry's share of the lab's
1 Mbit/s classic-CAN bus, and each message's worst-case latency (``rig.bus.latency``) against
the literature's worked example and a simulation of the arbitration."""

from __future__ import annotations

import math
import random
import subprocess
import sys

import pytest

from rig.bus import latency, load
from rig.bus.load import MessageLoad


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
        assert "above 60 %" in r.stderr or "beyond its period" in r.stderr
    late = [x for x in latency.worst_case_latencies(load.message_loads("drive"),
                                                    load.bitrate("drive"))
            if not x.meets_period]
    for x in late:
        assert f"{x.name}'s worst-case latency" in r.stderr, r.stderr
    assert "worst latency" in r.stdout and "1080 µs" in r.stdout


def _set(*messages: tuple[int, int]) -> list[MessageLoad]:
    """Messages (period in ms, transmission time in bits), highest priority first."""
    return [MessageLoad(f"m{i}", 0x100 + i, "x", 8, t, c) for i, (t, c) in enumerate(messages)]


def test_the_literatures_example_needs_the_second_instance() -> None:
    # Davis et al. (2007), section 3.1: A (T 2.5, C 1), B (T 3.5, C 1), C (T 3.5, C 1), in
    # ms: the first instance of C is answered in 3, the second in 3.5, its worst (the analysis
    # of 1994 said 3). Here scaled by 2 to whole milliseconds, at 1 Mbit/s.
    got = latency.worst_case_latencies(_set((5, 2000), (7, 2000), (7, 2000)), 1_000_000)
    assert [x.worst_s for x in got] == pytest.approx([0.004, 0.006, 0.007])
    assert [x.meets_period for x in got] == [True, True, True]


def test_an_overloaded_bus_has_no_bound() -> None:
    got = latency.worst_case_latencies(_set((1, 600), (1, 500)), 1_000_000)
    assert got[0].worst_s == pytest.approx(0.0011) and got[1].worst_s is None
    assert not got[1].meets_period


def _simulated_worst(loads: list[MessageLoad], bitrate: int) -> dict[str, float]:
    """Every message queued at time 0 and then at its period; the bus takes the lowest id
    among the frames queued when it falls free, and sends it whole. The worst queued-to-sent
    time of each, over two hyperperiods."""
    period = {x.name: x.cycle_ms * bitrate // 1000 for x in loads}
    horizon = 2 * math.lcm(*period.values())
    queued: list[tuple[int, int, str]] = []  # (id, queued at, name)
    releases = sorted((k * period[x.name], x.frame_id, x.name, x.bits) for x in loads
                      for k in range(horizon // period[x.name]))
    bits = {x.name: x.bits for x in loads}
    worst = dict.fromkeys(period, 0)
    now, i = 0, 0
    while i < len(releases) or queued:
        while i < len(releases) and releases[i][0] <= now:
            at, frame_id, name, _ = releases[i]
            queued.append((frame_id, at, name))
            i += 1
        if not queued:
            now = releases[i][0]
            continue
        queued.sort()
        frame_id, at, name = queued.pop(0)
        now += bits[name]
        worst[name] = max(worst[name], now - at)
    return {name: w / bitrate for name, w in worst.items()}


def test_the_analysis_bounds_the_simulated_bus() -> None:
    """The analysis is a bound, reached where nothing lower can block: the drive's message
    set and random sets below full load (synchronous start, the critical instant)."""
    rng = random.Random(37)
    sets = [[x for x in load.message_loads("drive") if x.cycle_ms]]
    for _ in range(30):
        n = rng.randint(2, 6)
        sets.append(_set(*[(rng.choice([1, 2, 4, 5, 10]), rng.randint(50, 135))
                           for _ in range(n)]))
    checked = 0
    for loads in sets:
        got = latency.worst_case_latencies(loads, 1_000_000)
        if any(x.worst_s is None for x in got):
            continue
        sim = _simulated_worst(loads, 1_000_000)
        for x in got:
            assert sim[x.name] <= x.worst_s + 1e-12, (x, sim)
        # the lowest priority has no blocking: the synchronous start is its worst case
        assert sim[got[-1].name] == pytest.approx(got[-1].worst_s)
        checked += 1
    assert checked >= 20


@pytest.mark.xfail(strict=True, reason=(
    "computed 1080 µs for TLM_PARAM and TLM_VOLT against their 1000 µs period: in the worst "
    "case the five TLM_* frames of a speed-loop period, DRIVE_CMD, DRIVE_STATUS and HEARTBEAT "
    "(135 bits each) queue together, and the last telemetry frame leaves after the next "
    "period's is queued; fewer, shorter or slower telemetry frames in protocols/drive.dbc "
    "(a protocol decision) would fit"))
def test_every_cyclic_drive_message_is_sent_within_its_period() -> None:
    got = latency.worst_case_latencies(load.message_loads("drive"), load.bitrate("drive"))
    assert all(x.meets_period for x in got), [(x.name, x.worst_s) for x in got]
