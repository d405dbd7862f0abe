"""Bad frames are rejected with a counted, logged reason, never used and never raised."""

from __future__ import annotations

import logging

import can
import pytest

from rig import protocols
from rig.bus.frames import FrameDecoder


@pytest.fixture
def decoder() -> FrameDecoder:
    return FrameDecoder()


def good_cmd(decoder: FrameDecoder, speed: float = 1500.0) -> can.Message:
    return decoder.encode("DRIVE_CMD", {"enable": 1, "fault_reset": 0, "ctrl_mode": 0,
                                        "fw_mode": 0, "alive": 7, "speed_ref": speed,
                                        "iq_ref": 0.0})


def test_good_frame_round_trips(decoder: FrameDecoder) -> None:
    d = decoder.decode(good_cmd(decoder))
    assert d is not None and d.name == "DRIVE_CMD"
    assert d.signals["speed_ref"] == pytest.approx(1500.0, abs=0.001)
    assert sum(decoder.rejected.values()) == 0


def test_unknown_id(decoder: FrameDecoder, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="rig.bus.frames"):
        assert decoder.decode(can.Message(arbitration_id=0x5A5, data=b"\0" * 8,
                                          is_extended_id=False)) is None
    assert decoder.rejected["unknown_id"] == 1
    assert "0x5A5" in caplog.text and "unknown_id" in caplog.text


def test_wrong_length(decoder: FrameDecoder) -> None:
    msg = good_cmd(decoder)
    short = can.Message(arbitration_id=msg.arbitration_id, data=bytes(msg.data)[:6],
                        is_extended_id=False)
    assert decoder.decode(short) is None
    assert decoder.rejected["bad_length"] == 1


def test_classic_frame_where_fd_is_defined(decoder: FrameDecoder) -> None:
    pwm = protocols.database("vio").get_message_by_name("VIO_PWM")
    msg = can.Message(arbitration_id=pwm.frame_id, data=b"\0" * 8, is_extended_id=False)
    assert decoder.decode(msg) is None
    assert decoder.rejected["wrong_frame_type"] == 1


def test_out_of_range_signal(decoder: FrameDecoder) -> None:
    # speed_ref is int32 at 0.001 r/min: the raw field can hold 2e6 r/min, the DBC allows 4000
    db_msg = protocols.database("drive").get_message_by_name("DRIVE_CMD")
    data = db_msg.encode({"enable": 1, "fault_reset": 0, "ctrl_mode": 0, "fw_mode": 0,
                          "alive": 1, "speed_ref": 9000.0, "iq_ref": 0.0}, strict=False)
    assert decoder.decode(can.Message(arbitration_id=db_msg.frame_id, data=data,
                                      is_extended_id=False)) is None
    assert decoder.rejected["out_of_range"] == 1


def test_encoder_refuses_out_of_range(decoder: FrameDecoder) -> None:
    with pytest.raises(Exception, match="speed_ref"):
        good_cmd(decoder, speed=5000.0)


def test_rejections_are_logged_sparingly(decoder: FrameDecoder,
                                         caplog: pytest.LogCaptureFixture) -> None:
    bad = can.Message(arbitration_id=0x5A5, data=b"", is_extended_id=False)
    with caplog.at_level(logging.WARNING, logger="rig.bus.frames"):
        for _ in range(2500):
            decoder.decode(bad)
    assert decoder.rejected["unknown_id"] == 2500
    assert len(caplog.records) == 3  # first, 1000th, 2000th

