"""plant_rt on the real bus, lockstep pacing (docs/interfaces.md): start-up, grants, the ADC
re-send, bad input, the trace file and the truth decimation. A Python peer stands in for the
firmware (answers ADC(k) with PWM(k+1)) and for the rig (grants, load commands).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from plant_peer import Frame, Peer, PlantProcess, Pwm, adc_codes, read_trace
from waits import EVENT_S

pytestmark = pytest.mark.vcan

ADC_MID = 1 << 15  # paper profile: 16-bit offset binary, zero current


@pytest.fixture
def peer(transport: str, channel: str) -> Iterator[Peer]:
    p = Peer(transport, channel)
    yield p
    p.close()


def is_progress(seq: int | None = None, period: int | None = None) -> Callable[[Frame], bool]:
    def pred(f: Frame) -> bool:
        return (f.name == "BENCH_PROGRESS" and (seq is None or f.signals["seq"] == seq)
                and (period is None or f.signals["period"] == period))
    return pred


def test_startup_grants_and_soc_counts(transport: str, channel: str, tmp_path: Path,
                                       peer: Peer) -> None:
    plant = PlantProcess(transport, channel, tmp_path)
    try:
        # No grant yet: the plant waits in period 0 and says so every 100 ms.
        first = peer.wait_for(is_progress(), EVENT_S, "BENCH_PROGRESS before any grant")
        assert (first.signals["period"], first.signals["state"]) == (0, 0)
        assert not [f for f in peer.heard if f.name.startswith("VIO_ADC")]

        peer.step(4, seq=7)
        adc0 = peer.adc(0)
        # start-up command: gates off, one SOC at tick 0; standstill, zero current
        assert adc0.name == "VIO_ADC_0" and adc0.signals["n_soc"] == 1
        assert adc0.signals["vdc_code"] == 32768  # floor(200 V / 400 V * 2^16 + 0.5)
        (ia, ib), = adc_codes([adc0], 1)
        assert abs(ia - ADC_MID) < 20 and abs(ib - ADC_MID) < 20  # 1 mA rms noise, 0.3 mA LSB

        socs = {1: (100, 2000, 4000, 6000, 9999), 2: tuple(range(0, 9000, 1000)),
                3: tuple(range(5, 10000, 625))}
        expected_frames = {1: ["VIO_ADC_0"], 2: ["VIO_ADC_0", "VIO_ADC_1"],
                           3: ["VIO_ADC_0", "VIO_ADC_1", "VIO_ADC_2"]}
        for k in (1, 2, 3):
            start = len(peer.heard)
            peer.pwm(Pwm(k, socs=socs[k]))
            last = peer.adc(k)
            got = [f for f in peer.heard[start:] if f.name.startswith("VIO_ADC")]
            assert [f.name for f in got] == expected_frames[k]
            assert all(f.signals["n_soc"] == len(socs[k]) for f in got)
            assert len(adc_codes(got, len(socs[k]))) == len(socs[k])
            assert last.signals["period"] == k

        # PWM(4) is there, but the grant ends before period 4
        peer.pwm(Pwm(4))
        done = peer.wait_for(is_progress(7, 4), EVENT_S, "BENCH_PROGRESS for grant 7")
        assert (done.signals["period"], done.signals["state"]) == (4, 0)
        mark = len(peer.heard)
        # a housekeeping BENCH_PROGRESS (every 100 ms) comes after any ADC frame the plant
        # would have sent at once had it simulated past the grant
        peer.wait_for(is_progress(), EVENT_S, "BENCH_PROGRESS of the housekeeping")
        later = peer.heard[mark:]
        assert not [f for f in later if f.name.startswith("VIO_ADC")], "simulated past grant"
        assert [f.signals["period"] for f in later if f.name == "BENCH_PROGRESS"] != []
        assert all(f.signals["period"] == 4 and f.signals["state"] == 0
                   for f in later if f.name == "BENCH_PROGRESS")

        peer.step(6, seq=8)
        peer.adc(4)
        peer.pwm(Pwm(5))
        peer.adc(5)
        done = peer.wait_for(is_progress(8, 6), EVENT_S, "BENCH_PROGRESS for grant 8")
        assert (done.signals["period"], done.signals["state"]) == (6, 0)
        # a grant that is already reached is answered, with its own seq
        peer.step(6, seq=9)
        again = peer.wait_for(is_progress(9), EVENT_S, "BENCH_PROGRESS for grant 9")
        assert again.signals["period"] == 6
    finally:
        result = plant.stop()
    assert result.returncode == 0, result.stderr
    c = result.counters
    assert c["program"] == "plant_rt" and c["mode"] == "lockstep"
    assert (c["periods"], c["next_period"], c["steps"], c["rejected"]) == (6, 6, 3, 0)


def test_adc_resent_after_100ms_without_pwm(transport: str, channel: str, tmp_path: Path,
                                            peer: Peer) -> None:
    # Re-sent every 100 ms of the plant's clock: bounds that hold on any machine, since a
    # frame is received (timestamped) only after it was sent, and the plant was started after
    # started_at. The third copy cannot come before 0.2 s; and the copies of ADC(0) sent
    # before the plant took PWM(1) are at most one per 100 ms up to ADC(1)'s arrival.
    started_at = time.time()
    plant = PlantProcess(transport, channel, tmp_path, "--run-until", "3")
    try:
        copies = [peer.adc(0) for _ in range(3)]  # nobody answers ADC(0)
        payloads = {bytes(f.msg.data) for f in copies}
        assert len(payloads) == 1, "a re-sent ADC(k) must repeat the same codes"
        assert copies[2].msg.timestamp - started_at >= 0.2 * 0.99
        adc1_at = 0.0
        for k in (1, 2, 3):
            peer.pwm(Pwm(k, cmp_up=(2400, 2600, 2600), cmp_dn=(2400, 2600, 2600)))
            if k < 3:
                got = peer.adc(k)
                adc1_at = adc1_at or got.msg.timestamp
        peer.wait_for(lambda f: f.name == "BENCH_PROGRESS" and f.signals["period"] == 3)
    finally:
        result = plant.stop()
    peer.drain(0.2)
    assert result.returncode == 0, result.stderr
    adc = [f.signals["period"] for f in peer.frames("VIO_ADC_0")]
    assert sorted(set(adc)) == [0, 1, 2]
    assert 3 <= adc.count(0) <= 2 + (adc1_at - started_at) / 0.1, (adc.count(0), adc1_at)
    # every ADC frame beyond the first of its period is a counted re-send
    assert result.counters["resends"] == len(adc) - 3
    assert result.counters["periods"] == 3


def test_bad_input_rejected_counted_and_previous_command_kept(
        transport: str, channel: str, tmp_path: Path, peer: Peer) -> None:
    plant = PlantProcess(transport, channel, tmp_path, "--run-until", "1")
    pwm_id = peer.message("VIO_PWM").frame_id
    try:
        peer.adc(0)
        sent: dict[str, int] = {}

        def bad(kind: str, send: Callable[[], object]) -> None:
            # one at a time: the plant's datagram queue on unixcan holds 10 frames
            # (net.unix.max_dgram_qlen) and on a loaded machine a burst can outlast the
            # sender's 2 ms grace, which drops the rest (that is the bus's rule, not the test's)
            send()
            sent[kind] = sent.get(kind, 0) + 1
            peer.wait_for(lambda f: f.name == "BENCH_REJECTS" and f.signals[kind] >= sent[kind],
                          3.0, f"BENCH_REJECTS counting {kind}")

        # the plant expects PWM(1)
        bad("out_of_range", lambda: peer.pwm(Pwm(1, cmp_up=(5001, 2500, 2500)), strict=False))
        bad("soc_outside", lambda: peer.pwm(Pwm(1, socs=(10, 20, 10000)), strict=False))
        bad("too_many_soc",
            lambda: peer.pwm(Pwm(1, socs=tuple(range(16)), n_soc=17), strict=False))
        bad("stale_period", lambda: peer.pwm(Pwm(0)))
        bad("future_period", lambda: peer.pwm(Pwm(2)))
        good = peer.message("VIO_PWM").encode(Pwm(1).signals())
        bad("bad_length", lambda: peer.send_raw(pwm_id, good[:48], is_fd=True))
        bad("malformed", lambda: peer.send_raw(pwm_id, good[:8], is_fd=False))
        bad("unknown_id", lambda: peer.send_raw(0x1F, bytes(64), is_fd=True))
        bad("out_of_range", lambda: peer.load(0, torque=20.0, strict=False))
        step = peer.message("BENCH_STEP").encode({"run_until": 2, "seq": 1})
        bad("malformed",
            lambda: peer.send_raw(peer.message("BENCH_STEP").frame_id, step, is_fd=False))
        # a valid PWM(1), then a broken one for the same period: the valid one stays
        peer.pwm(Pwm(1, socs=(0, 5000, 9000)))
        bad("out_of_range", lambda: peer.pwm(Pwm(1, cmp_dn=(2500, 6000, 2500),
                                                  socs=(1, 2, 3, 4, 5)), strict=False))
        expected = {"unknown_id": 1, "bad_length": 1, "out_of_range": 3, "stale_period": 1,
                    "future_period": 1, "too_many_soc": 1, "soc_outside": 1, "malformed": 2}
        rejects = peer.wait_for(
            lambda f: f.name == "BENCH_REJECTS"
            and {k: f.signals[k] for k in expected} == expected, EVENT_S, "BENCH_REJECTS")
        assert rejects.signals["period"] == 1
        counters = peer.wait_for(lambda f: f.name == "BENCH_COUNTERS")
        assert counters.signals["rejected"] == sum(expected.values())
        # none of that simulated anything: the grant still ends at period 1 (ADC(0) may be
        # heard again: the plant re-sends the last ADC every 100 ms while it waits)
        assert {f.signals["period"] for f in peer.heard if f.name.startswith("VIO_ADC")} == {0}

        peer.step(2, seq=2)
        adc1 = peer.adc(1)
        assert adc1.signals["n_soc"] == 3  # the valid command's three SOCs
        peer.pwm(Pwm(2))
        peer.step(3, seq=3)
        assert peer.adc(2).signals["n_soc"] == 1  # and the plant keeps running
    finally:
        result = plant.stop()
    assert result.returncode == 0, result.stderr
    assert result.counters["rejects"] == expected
    assert result.counters["rejected"] == sum(expected.values())
    assert result.counters["periods"] == 3
    assert "rejected: out_of_range" in result.stderr  # logged, not silent


def test_trace_has_every_period_and_bus_truth_is_decimated(
        transport: str, channel: str, tmp_path: Path, peer: Peer) -> None:
    n = 20
    trace = tmp_path / "plant.trace"
    plant = PlantProcess(transport, channel, tmp_path, "--run-until", str(n),
                         "--max-periods", str(n), "--truth-every", "3", "--trace", str(trace),
                         "--speed0", "300")
    for k in range(n - 1):
        peer.adc(k)
        peer.pwm(Pwm(k + 1, cmp_up=(2300, 2600, 2600), cmp_dn=(2300, 2600, 2600)))
    result = plant.wait()  # --max-periods: it stops by itself
    peer.drain(0.2)
    assert result.returncode == 0, result.stderr
    assert result.counters["periods"] == n

    on_bus = {int(f.signals["period"]): f for f in peer.frames("BENCH_TRUTH")}
    assert sorted(on_bus) == list(range(0, n, 3))
    assert sorted(int(f.signals["period"]) for f in peer.frames("BENCH_TRUTH_MAG")) == list(
        range(0, n, 3))

    records = read_trace(trace)
    assert [r.name for r in records] == ["BENCH_TRUTH", "BENCH_TRUTH_MAG"] * n
    assert [r.signals["period"] for r in records] == [k for k in range(n) for _ in (0, 1)]
    truth = {int(r.signals["period"]): r.signals for r in records if r.name == "BENCH_TRUTH"}
    for k, f in on_bus.items():
        assert f.signals == truth[k]  # the same float32 values on the bus and in the trace
    # the rotor turns at about 300 r/min: theta_e advances by pp * omega_m * Ts per period
    assert truth[0]["omega_m"] == pytest.approx(300 / 60 * 2 * math.pi, rel=1e-6)
    step = truth[10]["theta_e"] - truth[9]["theta_e"]
    mean_speed = 0.5 * (truth[9]["omega_m"] + truth[10]["omega_m"])
    assert step == pytest.approx(2 * mean_speed * 100e-6, rel=1e-4)
