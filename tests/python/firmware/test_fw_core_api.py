"""Core API on bad input and on lost inputs, through the shared library."""

from __future__ import annotations

import math

import fwlib


def test_out_of_range_commands_are_rejected_without_effect() -> None:
    core = fwlib.Core()
    before = core.status()
    assert core.command(enable=2) == 2
    assert core.command(enable=1, ctrl_mode=3) == 2
    assert core.command(enable=1, fw_mode=5) == 2
    assert core.command(enable=1, speed_ref_rpm=1e6) == 2
    assert core.command(enable=1, speed_ref_rpm=math.nan) == 2
    assert core.command(enable=1, iq_ref=-50.0) == 2
    after = core.status()
    assert after["cmd_status"] == 2
    assert {k: v for k, v in after.items() if k != "cmd_status"} == {
        k: v for k, v in before.items() if k != "cmd_status"
    }
    assert core.command(enable=0, speed_ref_rpm=100.0) == 0


def test_lost_adc_data_turns_the_outputs_off() -> None:
    core = fwlib.Core()
    vdc = round(200.0 / 400.0 * 2**16)
    half = 2**15
    pwm = core.isr(0, [half, half], [half, half], vdc)  # first frame: synchronise
    assert pwm["period"] == 1 and pwm["gate"] == 0
    assert core.status()["state"] == fwlib.STATE_IDLE
    for _ in range(3):
        pwm = core.isr(None, [], [], 0)
    st = core.status()
    assert st["state"] == fwlib.STATE_FAULT and st["fault_code"] == fwlib.FAULT_ADC_LOSS
    assert pwm["gate"] == 0
