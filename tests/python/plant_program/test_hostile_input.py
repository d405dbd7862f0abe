"""plant_rt against what an adversarial campaign sent it (issue 16): datagrams no CAN
controller sends, frames of other CAN frame kinds, and a grant at the far end of the period
counter. The plant stays up, counts each, and the lockstep goes on.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from plant_peer import Frame, Peer, PlantProcess, Pwm, read_trace
from waits import EVENT_S

from rig.bus import unixcan

VIO_PWM_ID = 0x10


@pytest.fixture
def peer(transport: str, channel: str) -> Iterator[Peer]:
    p = Peer(transport, channel)
    yield p
    p.close()


def progress(f: Frame) -> bool:
    return f.name == "BENCH_PROGRESS"


def plant_socket(channel: str, pid: int) -> str:
    socks = list((unixcan.base_dir() / channel).glob(f"{pid}-*.sock"))
    assert len(socks) == 1, socks
    return str(socks[0])


def test_a_datagram_with_length_255_is_counted_not_traced(transport: str, channel: str,
                                                          tmp_path: Path, peer: Peer) -> None:
    if transport != "unixcan":
        pytest.skip("the kernel's SocketCAN never delivers such a frame")
    trace = tmp_path / "plant.trace"
    plant = PlantProcess(transport, channel, tmp_path, "--trace", str(trace), "--trace-vio")
    try:
        target = plant_socket(channel, plant.proc.pid)
        s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        # struct canfd_frame: VIO_PWM with len 255 (the campaign's stack smash), then 13 (no
        # FD length), a 100-byte datagram and a classic frame with len 9
        bad = [struct.pack("<IBBBB", VIO_PWM_ID, 255, 4, 0, 0) + bytes(range(64)),
               struct.pack("<IBBBB", VIO_PWM_ID, 13, 4, 0, 0) + bytes(64),
               bytes(100),
               struct.pack("<IBBBB", VIO_PWM_ID, 9, 0, 0, 0) + bytes(8)]
        for d in bad:
            s.sendto(d, target)
        s.close()
        # and an extended, a remote and an error frame: other CAN frame kinds, counted
        for m in (can.Message(arbitration_id=VIO_PWM_ID, is_extended_id=True, data=b"\0" * 8),
                  can.Message(arbitration_id=VIO_PWM_ID, is_extended_id=False,
                              is_remote_frame=True, dlc=8),
                  can.Message(arbitration_id=VIO_PWM_ID, is_extended_id=False,
                              is_error_frame=True, data=b"\0" * 8)):
            peer.bus.send(m)
        # the lockstep still works
        peer.step(3, seq=1)
        peer.adc(0)
        peer.pwm(Pwm(1))
        peer.adc(1)
        peer.pwm(Pwm(2))
        peer.adc(2)
        peer.pwm(Pwm(3))
        peer.wait_for(lambda f: progress(f) and f.signals["period"] == 3, EVENT_S, "progress 3")
        out = plant.stop()
        assert out.returncode == 0, out.stderr
        assert out.counters["rx_malformed"] == len(bad)
        assert out.counters["non_data_frames"] == 3
        records = read_trace(trace)
        assert [r.signals["period"] for r in records if r.name == "VIO_PWM"] == [1, 2, 3]
    finally:
        plant.kill()


def test_a_grant_at_the_far_end_of_the_counter_is_rejected(transport: str, channel: str,
                                                           tmp_path: Path, peer: Peer) -> None:
    plant = PlantProcess(transport, channel, tmp_path)
    try:
        peer.step(2, seq=1)
        peer.adc(0)
        peer.pwm(Pwm(1))
        peer.adc(1)
        peer.pwm(Pwm(2))
        peer.wait_for(lambda f: progress(f) and f.signals["period"] == 2, EVENT_S, "progress 2")
        # 0xFFFFFFFF is 2^32 - 3 periods "ahead" unsigned, behind the plant with wrapping
        # periods: it must not take the plant's grant, nor make it say it is running
        peer.step(0xFFFFFFFF, seq=9)
        mark = len(peer.heard)
        peer.wait_for(progress, EVENT_S, "BENCH_PROGRESS of the housekeeping (every 100 ms)")
        said = [f for f in peer.heard[mark:] if progress(f)]
        assert said and all(f.signals["state"] == 0 and f.signals["seq"] == 1
                            and f.signals["period"] == 2 for f in said)
        # a real grant goes on from there
        peer.step(3, seq=2)
        peer.pwm(Pwm(2))  # (already there: the plant kept it)
        peer.adc(2)
        peer.pwm(Pwm(3))
        peer.wait_for(lambda f: progress(f) and f.signals["seq"] == 2
                      and f.signals["period"] == 3, EVENT_S, "progress 3")
        out = plant.stop()
        assert out.returncode == 0, out.stderr
        assert out.counters["rejects"]["stale_period"] >= 1
        assert out.counters["steps"] == 2
    finally:
        plant.kill()
