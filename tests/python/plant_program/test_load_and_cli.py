"""plant_rt as a program: LOAD_CMD modes change the truth as the shaft equation says,
configuration errors stop it with exit 2 and a message naming file, line and field, and
SIGTERM/SIGINT end it cleanly with its counters on stderr."""

from __future__ import annotations

import math
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from plant_peer import Peer, PlantProcess, Pwm, read_trace, run_plant

from rig import _paths, protocols

# paper profile
J, B = 0.0005, 0.003
POLE_PAIRS = 2
TS = protocols.timebase().ts


def test_load_modes_change_the_truth(transport: str, channel: str, tmp_path: Path) -> None:
    """Torque mode decelerates a free rotor as (J) dw/dt = -T0 - (B + k) w predicts; speed
    hold then holds 3000 r/min exactly while the machine, gates off, brakes through the
    diode bridge (line EMF 235 V > Vdc)."""
    t0, k_speed, n1, n2 = 0.4, 0.002, 300, 500
    trace = tmp_path / "plant.trace"
    peer = Peer(transport, channel)
    plant = PlantProcess(transport, channel, tmp_path, "--profile", "paper", "--speed0", "1000",
                         "--trace", str(trace))
    off = (0,)
    try:
        peer.load(0, torque=t0, k_speed=k_speed, seq=1)
        peer.step(n1, seq=1)
        for k in range(n1):
            peer.adc(k)
            peer.pwm(Pwm(k + 1, socs=off, gate_enable=0))
        peer.wait_for(lambda f: f.name == "BENCH_PROGRESS" and f.signals["seq"] == 1
                      and f.signals["period"] == n1)
        peer.load(1, speed=3000.0, seq=2)
        peer.step(n2, seq=2)
        for k in range(n1, n2):
            peer.adc(k)
            peer.pwm(Pwm(k + 1, socs=off, gate_enable=0))
        peer.wait_for(lambda f: f.name == "BENCH_PROGRESS" and f.signals["seq"] == 2
                      and f.signals["period"] == n2)
    finally:
        result = plant.stop()
        peer.close()
    assert result.returncode == 0, result.stderr
    assert result.counters["load_cmds"] == 2 and result.counters["periods"] == n2

    truth = [r.signals for r in read_trace(trace) if r.name == "BENCH_TRUTH"]
    assert [int(t["period"]) for t in truth] == list(range(n2))
    w = np.array([t["omega_m"] for t in truth])
    te = np.array([t["te"] for t in truth])
    tl = np.array([t["tl"] for t in truth])
    shaft = np.array([t["t_shaft"] for t in truth])
    theta = np.array([t["theta_e"] for t in truth])

    # torque mode: a linear ODE with the closed-form solution
    w0 = 1000 / 60 * 2 * math.pi
    a = (B + k_speed) / J
    w_inf = -t0 / (B + k_speed)
    t = np.arange(n1) * TS
    expected = w_inf + (w0 - w_inf) * np.exp(-a * t)
    assert np.max(np.abs(w[:n1] - expected)) < 1e-5 * w0
    assert w[n1 - 1] < 0.7 * w0  # it did decelerate
    assert np.all(te[:n1] == 0.0)  # 78 V line EMF < Vdc: no current with the gates off
    assert np.allclose(tl[:n1], t0 + k_speed * w[:n1], rtol=0, atol=1e-6)
    assert np.allclose(shaft[:n1], tl[:n1], rtol=0, atol=1e-6)  # = TL when J_load = B_load = 0

    # speed hold: exactly the setpoint from the first period after the command
    w_hold = 3000 / 60 * 2 * math.pi
    assert np.all(np.abs(w[n1:] - w_hold) < 1e-7 * w_hold)
    assert te[n1:].min() < -0.05  # the rectifying machine brakes ...
    assert np.allclose(tl[n1:], te[n1:] - B * w[n1:], rtol=0, atol=1e-5)  # ... the dyno holds
    dtheta = np.mod(np.diff(theta[n1:]), 2 * math.pi)
    assert np.allclose(dtheta, POLE_PAIRS * w_hold * TS, rtol=0, atol=2e-6)


def profile_line(path: Path, key: str) -> int:
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.split("=")[0].strip() == key:
            return number
    raise KeyError(key)


@pytest.mark.parametrize(("key", "bad", "field", "why"), [
    ("rs_ohm", "-1.0", "machine.rs_ohm", "outside"),
    ("vdc_v", "two hundred", "inverter.vdc_v", "not a number"),
    ("noise_rms_a", "0.001\nnoise_rms_a = 0.002", "sensors.noise_rms_a", "defined twice"),
])
def test_bad_profile_file_exits_2_naming_file_line_and_field(
        tmp_path: Path, key: str, bad: str, field: str, why: str) -> None:
    src = _paths.data_dir("profiles") / "paper.toml"
    path = tmp_path / "broken.toml"
    shutil.copy(src, path)
    line = profile_line(path, key)
    lines = path.read_text().splitlines()
    lines[line - 1] = f"{key} = {bad}"
    path.write_text("\n".join(lines) + "\n")
    # "defined twice" is reported on the second definition, one line further down
    at = line + 1 if why == "defined twice" else line
    done = run_plant("--profile", str(path), "--bus", "unixcan", "--channel", "never")
    assert done.returncode == 2
    assert f"{path}:{at}:" in done.stderr and field in done.stderr and why in done.stderr


@pytest.mark.parametrize(("setting", "field", "why"), [
    ("machine.rs_ohm=abc", "machine.rs_ohm", "not a number"),
    ("machine.bogus=1", "machine.bogus", "unknown field"),
    ("inverter.dead_time_s=1", "inverter.dead_time_s", "outside"),
])
def test_bad_set_exits_2_naming_the_field(setting: str, field: str, why: str) -> None:
    done = run_plant("--set", setting, "--bus", "unixcan", "--channel", "never")
    assert done.returncode == 2
    assert field in done.stderr and why in done.stderr


@pytest.mark.parametrize(("flag", "value"), [("--max-periods", "-3"), ("--truth-every", "x"),
                                           ("--rt-spin-us", "100")])
def test_bad_flag_value_exits_2(flag: str, value: str) -> None:
    done = run_plant(flag, value)
    assert done.returncode == 2 and f"{flag} {value}" in done.stderr


@pytest.mark.parametrize(("pacing", "sig"), [("--lockstep", signal.SIGTERM),
                                             ("--realtime", signal.SIGINT)])
def test_signal_stops_cleanly_with_counters(transport: str, channel: str, tmp_path: Path,
                                            pacing: str, sig: int) -> None:
    plant = PlantProcess(transport, channel, tmp_path, pacing, "--rt-priority", "0")
    time.sleep(0.05)  # (a real-time plant runs some periods; none is needed in lockstep)
    result = plant.stop(sig)
    assert result.returncode == 0, result.stderr
    c = result.counters
    assert c["program"] == "plant_rt" and c["transport"] == transport
    if pacing == "--lockstep":
        assert c["mode"] == "lockstep" and c["periods"] == 0  # no grant, nothing simulated
    else:
        assert c["mode"] == "realtime" and c["periods"] > 0
        assert c["wake_late_us"]["n"] == c["periods"]
        assert c["late_cmds"] == c["periods"] - 1  # nobody answers: every update is late
