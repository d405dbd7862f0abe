"""Bench description files: the shipped ones, the schema's checks, overrides; and the
commissioning test levels."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rig.bench import description as bd
from rig.commissioning.config import CommissioningConfig
from rig.commissioning.steps import ALL, STEPS


def test_shipped_virtual_bench() -> None:
    d = bd.load("virtual")
    assert d.lockstep and d.virtual is not None
    assert d.virtual.profile == "paper"
    assert set(d.virtual.programs) == {"plant_rt", "fw_host", "loadbench"}
    # a free port and a channel of the session's own unless one is named (issue 36.4)
    assert (d.modbus.kind, d.modbus.host, d.modbus.port) == ("tcp", "127.0.0.1", 0)
    assert d.can.channel == ""
    assert d.console.port == ""  # fw_host's pty
    CommissioningConfig.from_mapping(d.commissioning)


def test_shipped_lab_example_is_a_real_bench() -> None:
    d = bd.load("lab-example")
    assert not d.lockstep and d.virtual is None
    assert (d.can.transport, d.can.channel) == ("socketcan", "can0")
    assert d.console.port == "/dev/ttyUSB0" and d.console.baudrate == 115200
    assert d.modbus.kind == "tcp" and d.modbus.host.startswith("192.168.")
    cfg = CommissioningConfig.from_mapping(d.commissioning)
    assert max(cfg.rs_currents_a) <= cfg.i_max_a


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bench.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(("text", "message"), [
    ('[can]\nchanel = "can0"\n', "unknown key(s) chanel"),
    ('[console]\nport = "/dev/ttyS0"\n[modbus]\nkind = "ascii"\n', "modbus.kind"),
    ('[console]\nport = "/dev/ttyS0"\n[modbus]\nkind = "rtu"\n', "needs modbus.device"),
    ('[console]\nport = "/dev/ttyS0"\n[clock]\nmode = "lockstep"\n', "needs a [virtual]"),
    ('[modbus]\nhost = "10.0.0.1"\n', "console.port is required"),
    ('[console]\nport = "/dev/ttyS0"\n[modbus]\nport = "502"\n', "expected a whole number"),
    ('[virtual]\n[modbus]\nhost = "0.0.0.0"\n', "127.0.0.1 only"),
    ('[virtual]\nprograms = ["plant_rt", "doom"]\n', "unknown doom"),
    ('[console]\nport = "/dev/ttyS0"\n[modbus]\nunit = 300\n', "modbus.unit"),
    ("speed = 3\n", "unknown key(s) speed"),
])
def test_bad_descriptions_name_the_field(tmp_path: Path, text: str, message: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(bd.BenchDescriptionError) as e:
        bd.load(p)
    assert message in str(e.value) and str(p) in str(e.value)


def test_overrides(tmp_path: Path) -> None:
    d = bd.load("virtual", ["can.channel=x1", "modbus.port=0", "virtual.plant.initial."
                            "theta_e_deg=30", "virtual.firmware.pll_bw_hz=80",
                            'virtual.programs=["plant_rt"]', "console.port=/dev/pts/9",
                            "commissioning.flux_speeds_rpm=[400.0]"])
    assert d.can.channel == "x1" and d.modbus.port == 0
    assert d.virtual is not None and d.virtual.plant == {"initial.theta_e_deg": 30}
    assert d.virtual.firmware == {"pll_bw_hz": 80} and d.virtual.programs == ("plant_rt",)
    assert d.console.port == "/dev/pts/9"
    assert CommissioningConfig.from_mapping(d.commissioning).flux_speeds_rpm == (400.0,)
    with pytest.raises(bd.BenchDescriptionError, match=r"not section\.key=value"):
        bd.load("virtual", ["can.channel"])
    with pytest.raises(bd.BenchDescriptionError, match="no such bench file"):
        bd.load(tmp_path / "missing")


@pytest.mark.parametrize(("table", "message"), [
    ({"i_max_a": "4"}, "a number"), ({"rs_currents_a": [1.0]}, "at least two"),
    ({"rs_currents_a": [1.0, 9.0]}, "above i_max_a"), ({"sweep_fw_mode": "mtpa"}, "realtime"),
    ({"typo": 1}, "unknown key(s) typo"), ({"rs_align_speed_rpm": 0.0}, "above 0"),
    ({"rs_align_tolerance_deg": 30.0}, "at most 15°"), ({"rs_align_timeout_s": -1}, "above 0"),
])
def test_commissioning_levels_are_checked(table: dict[str, object], message: str) -> None:
    with pytest.raises(bd.BenchDescriptionError) as e:
        CommissioningConfig.from_mapping(table)
    assert message in str(e.value)


def test_cli_lists_the_steps_and_refuses_bad_input(tmp_path: Path) -> None:
    def rig(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "rig", *args], capture_output=True,
                              text=True, timeout=60, check=False)

    done = rig("commission", "--help")
    assert done.returncode == 0
    for step in STEPS:
        assert step in done.stdout
    assert set(ALL) <= set(STEPS)
    done = rig("commission", "all", "--bench", str(write(tmp_path, "[can]\nx = 1\n")))
    assert done.returncode == 2 and "unknown key(s) x" in done.stderr
    done = rig("commission", "dance", "--bench", "virtual")
    assert done.returncode == 2


def test_phase_axis_geometry_against_the_phase_currents() -> None:
    """The offset of the q axis from the nearest phase axis and the smallest phase share,
    checked against the phase currents of a unit q current computed directly."""
    from rig.commissioning.steps.standstill import phase_axis_offset_deg, smallest_phase_share

    for theta in np.arange(-720.0, 720.0, 0.7):
        phi = np.radians(theta + 90.0)  # direction of the q current
        phases = [np.cos(phi - k * 2.0 * np.pi / 3.0) for k in range(3)]
        off = phase_axis_offset_deg(float(theta))
        assert -30.0 <= off < 30.0
        # on a phase axis one phase carries the whole current, so |i| max = 1 there
        assert max(abs(x) for x in phases) == pytest.approx(np.cos(np.radians(off)), abs=1e-9)
        assert smallest_phase_share(off) == pytest.approx(min(abs(x) for x in phases),
                                                          abs=1e-9)
    assert smallest_phase_share(0.0) == pytest.approx(0.5)
    assert smallest_phase_share(30.0) == pytest.approx(0.0, abs=1e-12)
