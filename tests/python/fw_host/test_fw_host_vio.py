"""Virtual I/O: ADC(k) in, PWM(k+1) out; repeats, multi-frame periods, bad and lost data."""

from __future__ import annotations

import pytest
from fwhost_support import FAULT_ADC_LOSS, STATE, Peer, StartFw

from rig import protocols

TBPRD = protocols.timebase().tbprd
PERIOD_TICKS = protocols.timebase().period_ticks


def check_pwm(pwm: dict[str, int], period: int) -> None:
    assert pwm["period"] == period
    for x in "abc":
        assert 0 <= pwm[f"cmp_{x}_up"] <= TBPRD
        assert 0 <= pwm[f"cmp_{x}_dn"] <= TBPRD
    assert 0 <= pwm["n_soc"] <= 16
    for i in range(pwm["n_soc"]):
        assert 0 <= pwm[f"soc_{i}"] < PERIOD_TICKS
    assert pwm["gate_enable"] in (0, 1)


@pytest.mark.vcan
def test_adc_k_gives_pwm_k_plus_1_and_repeats_are_idempotent(
        start_fw: StartFw, peer: Peer) -> None:
    fw = start_fw()
    pwms = peer.run(100, 5)
    for i, pwm in enumerate(pwms):
        check_pwm(pwm, 101 + i)
        assert pwm["gate_enable"] == 0  # never enabled
    # the plant re-sends ADC(104) (no PWM seen within 100 ms): the same PWM(105) again
    n_soc = pwms[-2]["n_soc"]
    again = peer.step(104, n_soc)
    assert again == pwms[-1]
    assert fw.stop() == 0
    c = fw.counters()
    assert c["isr"] == 5 and c["repeats"] == 1 and c["pwm_sent"] == 6
    assert c["rx_rejected"] == 0 and c["last_period"] == 104


def test_period_in_three_frames_runs_the_isr_once_complete(start_fw: StartFw,
                                                           peer: Peer) -> None:
    fw = start_fw()
    frames = peer.adc_frames(7, 16)
    assert len(frames) == 3
    # any order: 2, 0, then 1 completes the period
    for frame_id, data in (frames[2], frames[0]):
        peer.send_raw(frame_id, data, fd=True)
    assert peer.recv_until(lambda m: m.arbitration_id == 0x10, timeout=0.3) is None
    peer.send_raw(*frames[1], fd=True)
    check_pwm(peer.pwm(8), 8)
    assert fw.stop() == 0
    assert fw.counters()["isr"] == 1


def test_stale_future_incomplete_and_malformed_adc_data_are_rejected(
        start_fw: StartFw, peer: Peer) -> None:
    fw = start_fw()
    pwms = peer.run(50, 3)
    n_soc = pwms[-1]["n_soc"]
    peer.send_adc(40, n_soc)                       # stale
    peer.send_adc(53 + 5000, n_soc)                # far in the future
    frames = peer.adc_frames(53, 12)               # n_soc 12: needs VIO_ADC_0 and _1
    peer.send_raw(*frames[0], fd=True)             # ... only _0 comes: incomplete
    peer.sync(53)                                  # (a frame fault: the plant's barrier)
    bad = peer.adc_frames(54, 3)[0]
    peer.send_raw(0x12, bad[1], fd=True)           # VIO_ADC_1 although n_soc is 3: malformed
    peer.send_raw(*bad, fd=True)                   # 54 complete: ISRs for 53 (no data), 54
    pwm = peer.pwm(55)
    check_pwm(pwm, 55)
    assert fw.stop() == 0
    c = fw.counters()
    assert c["rejects"]["stale_period"] == 1
    assert c["rejects"]["future_period"] == 1
    assert c["rejects"]["incomplete"] == 1
    assert c["rejects"]["malformed"] == 1
    assert c["isr"] == 5 and c["isr_no_data"] == 1 and c["last_period"] == 54


def test_wrong_length_type_and_range_of_adc_frames(start_fw: StartFw, peer: Peer) -> None:
    fw = start_fw()
    peer.run(0, 2)
    frame_id, data = peer.adc_frames(2, 2)[0]
    peer.send_raw(frame_id, data[:48], fd=True)      # FD but 48 bytes
    peer.send_raw(frame_id, data[:8], fd=False)      # classic frame for an FD message
    m = peer.msg("VIO_ADC_0")
    peer.send_raw(frame_id, m.encode({"period": 2, "n_soc": 17, "vdc_code": 0,
                                      **{f"{c}_{i}": 0 for c in "ia ib".split()
                                         for i in range(7)}}, strict=False), fd=True)
    peer.send_raw(0x2E, bytes(64), fd=True)          # unknown id in the virtual-I/O range
    check_pwm(peer.step(2, 2), 3)                    # still working
    st = peer.status(lambda v: v["rx_rejected"] >= 4)
    assert st["rx_rejected"] == 4
    assert fw.stop() == 0
    rej = fw.counters()["rejects"]
    assert rej["bad_length"] == 1 and rej["wrong_frame_type"] == 1
    assert rej["out_of_range"] == 1 and rej["unknown_id"] == 1


def test_adc_loss_faults_and_turns_the_gates_off(start_fw: StartFw, peer: Peer) -> None:
    fw = start_fw()
    pwms = peer.run(0, 3)
    # periods 3..6 never come: ADC(7), confirmed by the plant's barrier (in lockstep the plant
    # skips a period only behind one), runs the ISR without data for them first
    pwm = peer.step_after_loss(7, pwms[-1]["n_soc"])
    assert pwm["gate_enable"] == 0
    st = peer.status(lambda v: v["state"] == STATE["FAULT"])
    assert st["fault_code"] == FAULT_ADC_LOSS
    assert fw.stop() == 0
    c = fw.counters()
    assert c["isr_no_data"] == 4 and c["fault_name"] == "ADC_LOSS"


def test_a_stray_frame_ahead_does_not_take_the_lockstep_over(start_fw: StartFw,
                                                              peer: Peer) -> None:
    """Issue 23.5: one VIO_ADC frame of another node a few periods ahead of the plant (within
    FWH_ADC_MAX_GAP) took the ADC sequence over: the ISR ran the skipped periods without data
    and the stray data, the plant's next frames were stale and the lockstep stalled. In
    lockstep the plant skips no period until a frame fault makes it send barriers: before
    that, data that skips periods is rejected (future)."""
    fw = start_fw()
    pwms = peer.run(0, 5)
    n_soc = int(pwms[-1]["n_soc"])
    peer.send_adc(5 + 60, 1)                        # the stray frame, 60 periods ahead
    check_pwm(peer.step(5, n_soc), 6)               # the plant's period 5 goes on
    pwms = peer.run(6, 3, n_soc=int(pwms[-1]["n_soc"]))
    check_pwm(pwms[-1], 9)
    assert fw.stop() == 0
    c = fw.counters()
    assert c["isr_no_data"] == 0 and c["last_period"] == 8 and c["fault_name"] == "NONE"
    assert c["rejects"]["future_period"] == 1


def test_in_real_time_skipped_periods_are_followed_at_once(start_fw: StartFw,
                                                          peer: Peer) -> None:
    """Real time: the plant does not wait, frames lost on the bus leave gaps; the firmware
    follows the newest period at once (no barrier there)."""
    fw = start_fw("--realtime")
    pwms = peer.run(0, 3)
    check_pwm(peer.step(6, int(pwms[-1]["n_soc"])), 7)  # 3..5 lost
    assert fw.stop() == 0
    assert fw.counters()["isr_no_data"] == 3


def test_restarted_plant_is_followed_after_a_few_periods(start_fw: StartFw,
                                                         peer: Peer) -> None:
    fw = start_fw()
    peer.run(1000, 3)
    # the plant restarts at 0: ten consecutive stale periods, then fw_host follows it
    n_soc = 1
    for k in range(10):
        peer.send_adc(k, n_soc)
    pwm = peer.pwm(10)
    check_pwm(pwm, 10)
    check_pwm(peer.step(10, pwm["n_soc"]), 11)
    assert fw.stop() == 0
    c = fw.counters()
    assert c["resyncs"] == 1 and c["rejects"]["stale_period"] == 9


def test_current_codes_outside_the_converter_are_rejected(start_fw: StartFw,
                                                          peer: Peer) -> None:
    """Issue 16.5: codes beyond 2^adc_bits - 1 (the default 16-bit converter) or below 0
    never reach the core (INT32_MIN overflowed its arithmetic): rejected and counted, no
    fault; the next good period runs as if the bad ones never came."""
    fw = start_fw()
    pwms = peer.run(0, 3)
    n_soc = pwms[-1]["n_soc"]
    for codes in ({"ia": -2**31}, {"ib": 2**31 - 1}, {"ia": 65536}, {"ib": -1}):
        peer.send_adc(3, n_soc, **codes)
    check_pwm(peer.step(3, n_soc), 4)
    st = peer.status()
    assert st["state"] != STATE["FAULT"]
    assert fw.stop() == 0
    c = fw.counters()
    assert c["rejects"]["out_of_range"] == 4
    assert c["isr_no_data"] == 0 and c["fault_name"] == "NONE"


def test_sync_is_answered_after_everything_before_it(start_fw: StartFw, peer: Peer) -> None:
    """The plant's lockstep barrier under frame faults (docs/interfaces.md, "Fault
    injection"): VIO_SYNC is answered with VIO_SYNC_ACK (period and seq echoed), after the PWM
    its preceding ADC frames caused; a refused frame before it causes no PWM."""
    fw = start_fw()
    pwm_id, ack_id = peer.msg("VIO_PWM").frame_id, peer.msg("VIO_SYNC_ACK").frame_id
    pwms = peer.run(20, 2)
    n_soc = int(pwms[-1]["n_soc"])
    peer.send_adc(22, n_soc)
    peer.send("VIO_SYNC", {"period": 22, "seq": 7})
    got = []
    while len(got) < 2:
        m = peer.recv_until(lambda f: f.arbitration_id in (pwm_id, ack_id))
        assert m is not None, got
        got.append(peer.decode(m) | {"id": m.arbitration_id})
    assert [g["id"] for g in got] == [pwm_id, ack_id]
    assert got[0]["period"] == 23 and (got[1]["period"], got[1]["seq"]) == (22, 7)
    # an ADC frame of period 23 with a code beyond the converter: refused, no PWM, the ACK
    frame_id, data = peer.adc_frames(23, n_soc, ia=1 << 20)[0]
    peer.send_raw(frame_id, data, fd=True)
    peer.send("VIO_SYNC", {"period": 23, "seq": 8})
    ack = peer.recv_until(lambda f: f.arbitration_id in (pwm_id, ack_id))
    assert ack is not None and ack.arbitration_id == ack_id
    assert peer.decode(ack)["seq"] == 8
    # a VIO_SYNC of the wrong length is refused (the next one shows it was handled)
    peer.send_raw(peer.msg("VIO_SYNC").frame_id, bytes(4), fd=True)
    peer.send("VIO_SYNC", {"period": 23, "seq": 9})
    ack = peer.recv_until(lambda f: f.arbitration_id == ack_id)
    assert ack is not None and peer.decode(ack)["seq"] == 9
    assert fw.stop() == 0
    c = fw.counters()
    assert c["syncs"] == 3 and c["rejects"]["out_of_range"] == 1
    assert c["rejects"]["bad_length"] == 1
