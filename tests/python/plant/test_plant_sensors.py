"""Sensors and ADC measured from the returned codes against the profile numbers."""

from __future__ import annotations

import numpy as np
import pytest
from plant_lib import Plant, Pwm, profile
from scipy.optimize import curve_fit

LOCKED = {"load.mode": 1, "load.speed_rpm": 0.0}


def decode(code: np.ndarray, bits: int, rng_a: float) -> np.ndarray:
    """docs/interfaces.md: i = (code - 2^(N-1)) * 2R / 2^N."""
    return (code.astype(float) - 2 ** (bits - 1)) * 2 * rng_a / 2**bits


@pytest.mark.parametrize("name", ["paper", "harsh"])
def test_quantization_step(name: str) -> None:
    over = LOCKED | {"sensors.noise_rms_a": 0.0, "sensors.ring_amp_a": 0.0}
    adc = profile(name)["adc"]
    lsb = 2 * adc["range_a"] / 2 ** adc["bits"]
    p = Plant(name, over)
    p.set_state(0.0, 0.0, -4.0, 0.0)  # decays through the ADC range: many code levels
    res = []
    socs = list(range(0, 10000, 700))
    for _ in range(60):
        r = p.step(Pwm((5000, 5000, 5000), (5000, 5000, 5000), socs))
        res.extend(decode(r.ia_code, adc["bits"], adc["range_a"]) - r.ia_adc_in)
    res_arr = np.array(res)
    assert np.max(np.abs(res_arr)) <= lsb / 2 * (1 + 1e-9)
    assert np.std(res_arr) == pytest.approx(lsb / np.sqrt(12), rel=0.1)


@pytest.mark.parametrize("name", ["paper", "harsh"])
def test_noise_standard_deviation(name: str) -> None:
    prof = profile(name)
    adc, sigma = prof["adc"], prof["sensors"]["noise_rms_a"]
    lsb = 2 * adc["range_a"] / 2 ** adc["bits"]
    p = Plant(name, LOCKED)  # gates off, rotor still: the true current is exactly zero
    socs = list(range(100, 10000, 625))
    codes: list[float] = []
    for _ in range(400):
        r = p.step(Pwm((5000, 5000, 5000), (5000, 5000, 5000), socs, gate_enable=0))
        assert np.all(r.ia_true == 0.0)
        codes.extend(decode(r.ia_code, adc["bits"], adc["range_a"]))
        codes.extend(decode(r.ib_code, adc["bits"], adc["range_a"]))
    x = np.array(codes)
    expect = np.sqrt(sigma**2 + lsb**2 / 12)  # noise plus the quantisation it dithers
    assert abs(np.mean(x)) < 4 * expect / np.sqrt(len(x))
    assert np.std(x) == pytest.approx(expect, rel=0.03)


def ring_model(t: np.ndarray, amp: float, tau: float, freq: float) -> np.ndarray:
    return amp * np.exp(-t / tau) * np.sin(2 * np.pi * freq * t)


@pytest.mark.parametrize("leg", [0, 2])
def test_ringing_after_edge(leg: int) -> None:
    """One leg switches on at tick 2000 + dead time; the ringing is the difference of the
    codes with ringing on and off (the currents are the same in both runs)."""
    prof = profile("paper")
    adc, sen = prof["adc"], prof["sensors"]
    dead = round(prof["inverter"]["dead_time_s"] / 1e-8)
    edge = 2000 + dead
    offsets = [5, 10, 15, 25, 35, 50, 65, 75, 90, 110, 125, 150, 175, 225, 275, 325]
    socs = [edge + o for o in offsets]
    up = [5000, 5000, 5000]
    dn = [5000, 5000, 5000]
    up[leg], dn[leg] = 2000, 2000
    runs = []
    for amp in (sen["ring_amp_a"], 0.0):
        p = Plant("paper", LOCKED | {"sensors.noise_rms_a": 0.0, "sensors.ring_amp_a": amp})
        runs.append(p.step(Pwm((up[0], up[1], up[2]), (dn[0], dn[1], dn[2]), socs)))
    t = np.array(offsets) * 1e-8
    da = decode(runs[0].ia_code, adc["bits"], adc["range_a"]) - decode(
        runs[1].ia_code, adc["bits"], adc["range_a"])
    db = decode(runs[0].ib_code, adc["bits"], adc["range_a"]) - decode(
        runs[1].ib_code, adc["bits"], adc["range_a"])
    # phase a: its own ringing (leg a) or the share of c's ringing returning through it
    start = (0.08 if leg == 0 else -0.04, 8e-7, 9e5)
    (amp, tau, freq), _ = curve_fit(ring_model, t, da, p0=start)
    expect_amp = sen["ring_amp_a"] * (1.0 if leg == 0 else -0.5 * sen["ring_return_fraction"])
    print(f"leg {leg}: amplitude {amp * 1e3:.2f} mA, tau {tau * 1e6:.3f} us, "
          f"f {freq / 1e6:.3f} MHz")
    assert amp == pytest.approx(expect_amp, rel=0.03)
    assert tau == pytest.approx(sen["ring_tau_s"], rel=0.03)
    assert freq == pytest.approx(sen["ring_freq_hz"], rel=0.01)
    # the other sensed phase: an edge of a returns -1/2 through b, an edge of c shows equally
    ratio = -0.5 * sen["ring_return_fraction"] if leg == 0 else 1.0
    assert np.max(np.abs(db - ratio * da)) < 2 * 2 * adc["range_a"] / 2 ** adc["bits"]
