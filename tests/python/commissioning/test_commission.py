"""``rig commission`` on the virtual bench: identification against the plant's true machine
(read from the profile file here, not from the rig), polarity from 12 start angles, safety
on interrupts and dead links."""

from __future__ import annotations

import csv
import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import can
import numpy as np
import pytest
from commission_support import (
    MakeDesc,
    cross_saturation_per_ampere,
    paper_truth,
    profile_truth,
)
from waits import RUN_S

from rig import _paths, protocols
from rig.bench.configuration import firmware_settings
from rig.commissioning import commission
from rig.drive import commissioned


def within(value: float, truth: float, rel: float) -> bool:
    return abs(value / truth - 1.0) <= rel


def test_commission_all_identifies_the_paper_machine(make_desc: MakeDesc,
                                                     tmp_path: Path) -> None:
    run = commission.commission(make_desc(), ["all"], tmp_path / "run")
    assert run.passed, run.report_path.read_text()
    truth = paper_truth()
    got = {k: run.value(k) for k in ("rs_ohm", "ld_h", "lq_h", "lambda_m_wb")}
    # rs: the q current on a phase axis keeps the dead-time error constant over the steps
    # (measured ≤ 0.6 % at any start angle; at arbitrary lock angles -2 % … +5 %)
    assert within(got["rs_ohm"], truth["rs_ohm"], 0.02), got
    assert within(got["ld_h"], truth["ld_h"], 0.05), got
    assert within(got["lq_h"], truth["lq_h"], 0.05), got
    assert within(got["lambda_m_wb"], truth["lambda_m_wb"], 0.03), got
    standstill = run.step("standstill")
    assert all(c.passed for c in standstill.checks)
    assert standstill.facts["polarity_first"] == standstill.facts["polarity_final"] == "correct"
    assert any(c.name.endswith("polarity by shaft torque") for c in standstill.checks)
    # the report names the numbers, the nominal values and the recording
    md = run.report_path.read_text()
    assert "## Identified parameters" in md and "bus.log" in md
    assert re.search(r"\| rs \| [0-9.]+ Ω \| 1\.93 Ω \| [-+][0-9.]+ % \| 1\.93 Ω \|", md), md
    log = tmp_path / "run" / "bus.log"
    assert log.stat().st_size > 0
    assert "drive state afterwards: DRIVE_STATUS IDLE" in run.data["safety"][-1]


def test_identification_follows_the_plant_not_the_nominal(make_desc: MakeDesc,
                                                          tmp_path: Path) -> None:
    """The emulated machine differs from the drive's nominal parameters (parameters.csv):
    the identified values must follow the machine."""
    machine = {"machine.rs_ohm": 2.4, "magnetics.ld_h": 0.0165, "magnetics.lq_h": 0.035,
               "machine.lambda_m_wb": 0.2}
    desc = make_desc(*(f"virtual.plant.{k}={v}" for k, v in machine.items()))
    run = commission.commission(desc, ["standstill", "flux"], tmp_path / "run")
    assert run.passed, run.report_path.read_text()
    assert within(run.value("rs_ohm"), machine["machine.rs_ohm"], 0.02)
    assert within(run.value("ld_h"), machine["magnetics.ld_h"], 0.05)
    assert within(run.value("lq_h"), machine["magnetics.lq_h"], 0.05)
    assert within(run.value("lambda_m_wb"), machine["machine.lambda_m_wb"], 0.03)
    q = {x.key: x for s in run.steps for x in s.quantities}
    assert q["rs_ohm"].truth == 2.4 and q["rs_ohm"].nominal == 1.93


def test_xsat_identifies_the_harsh_machines_cross_saturation(make_desc: MakeDesc,
                                                            tmp_path: Path) -> None:
    """Ldq per ampere from the turn of the saliency axes against the flux angle at speed
    (1000 r/min, rs from the standstill step, 2 s per current): within 15 % of the plant's
    Ldq at 3 A per ampere. Measured over 18 runs (start angles, channel timing): -3.9 ... +8.3 %,
    mean +2.3 %, standard deviation 3.6 % (the plant's Ldq per ampere is 4.6 % higher near 0 A
    than at 3 A, and the fit spans 1 to 3 A of both signs); 15 % of Ldq moves the harsh
    2 N*m cells by ~1.4 deg. Before the turn was averaged as a complex number and rs
    identified first: -51 %. The drive the harsh scenarios run (rig/commissioned/harsh.toml)
    carries what this identifies."""
    run = commission.commission(make_desc("virtual.profile=harsh"), ["standstill", "xsat"],
                            tmp_path / "run")
    assert run.passed, run.report_path.read_text()
    # rs of the hot machine (+30 % against nominal) within 5 %: measured -4.8 … +0.7 % over
    # 7 start angles and 2 noise seeds; a current step on the held rotor had turned the
    # drive's frame by π during the rs steps ("polarity kept through the rs steps" failed)
    rs_truth = profile_truth("harsh")["rs_ohm"]
    assert within(run.value("rs_ohm"), rs_truth, 0.05), (run.value("rs_ohm"), rs_truth)
    k = run.value("xsat_ldq_per_a")
    truth = cross_saturation_per_ampere("harsh")
    assert within(k, truth, 0.15), (k, truth)
    assert run.data["written"] == {"xsat_ldq_per_a": k}
    shipped = commissioned.parameters("harsh")["xsat_ldq_per_a"]
    assert within(shipped, k, 0.15), (shipped, k)


def test_xsat_finds_no_cross_saturation_on_the_paper_machine(make_desc: MakeDesc,
                                                             tmp_path: Path) -> None:
    run = commission.commission(make_desc(), ["standstill", "xsat"], tmp_path / "run")
    assert run.passed, run.report_path.read_text()
    assert cross_saturation_per_ampere("paper") == 0.0
    # a tenth of the harsh machine's at most
    assert abs(run.value("xsat_ldq_per_a")) < 0.1 * abs(cross_saturation_per_ampere("harsh"))


@pytest.mark.parametrize(("profile", "theta0", "rel"), [
    ("paper", 45.0, 0.02), ("paper", 75.0, 0.02),
    # harsh: -4.8 ... +0.7 % over 7 start angles and 2 noise seeds; 200 deg was the worst. At
    # every angle the steps had turned the drive's frame by pi (the flux check took the held
    # rotor's runaway estimate for a turned frame), which the polarity check now fails
    ("harsh", 200.0, 0.05), ("harsh", 300.0, 0.05)])
def test_rs_does_not_depend_on_where_the_rotor_stops(make_desc: MakeDesc, tmp_path: Path,
                                                     profile: str, theta0: float,
                                                     rel: float) -> None:
    """The rotor is turned until the q current lies on a phase axis before the rs steps:
    the identified rs must not depend on the angle the drive started at."""
    desc = make_desc(f"virtual.plant.initial.theta_e_deg={theta0}",
                     f"virtual.profile={profile}")
    run = commission.commission(desc, ["standstill"], tmp_path / "run")
    assert run.passed, run.report_path.read_text()
    assert within(run.value("rs_ohm"), profile_truth(profile)["rs_ohm"], rel), run.value("rs_ohm")
    aligned = [c for c in run.step("standstill").checks if c.name.startswith("q axis on")]
    assert len(aligned) == 1 and aligned[0].passed


def angle_errors_per_start(log: Path) -> list[np.ndarray]:
    """θ̂ (TLM_POS) minus θ (BENCH_TRUTH) of the same periods for each enable of the drive
    (DRIVE_CMD enable 0 → 1 … 1 → 0), decoded here from the run's recording with the DBC."""
    drive, bench = protocols.database("drive"), protocols.database("bench")
    ids = {name: db.get_message_by_name(name).frame_id
           for db, name in ((drive, "TLM_POS"), (drive, "DRIVE_CMD"), (bench, "BENCH_TRUTH"))}
    theta: dict[int, float] = {}
    starts: list[list[tuple[int, float]]] = []
    enabled = False
    for msg in can.LogReader(str(log)):
        if msg.arbitration_id == ids["DRIVE_CMD"]:
            en = bool(drive.decode_message(ids["DRIVE_CMD"], msg.data)["enable"])
            if en and not enabled:
                starts.append([])
            enabled = en
        elif msg.arbitration_id == ids["BENCH_TRUTH"]:
            v = bench.decode_message(ids["BENCH_TRUTH"], msg.data)
            theta[int(v["period"]) & 0xFFFF] = math.degrees(float(v["theta_e"])) % 360.0
        elif msg.arbitration_id == ids["TLM_POS"] and enabled and starts:
            v = drive.decode_message(ids["TLM_POS"], msg.data)
            starts[-1].append((int(v["period"]), float(v["theta_hat"])))
    return [np.asarray([(th - theta[p] + 180.0) % 360.0 - 180.0 for p, th in s
                        if p in theta]) for s in starts]


def pol_method_writes(log: Path) -> list[float]:
    """Values of the PARAM_REQ writes to pol_method in the recording."""
    drive = protocols.database("drive")
    req = drive.get_message_by_name("PARAM_REQ")
    pid = int(next(r["id"] for r in csv.DictReader(
        (_paths.data_dir("protocols") / "parameters.csv").open()) if r["name"] == "pol_method"))
    out = []
    for msg in can.LogReader(str(log)):
        if msg.arbitration_id == req.frame_id:
            v = req.decode(msg.data, decode_choices=False)
            if int(v["op"]) == 1 and int(v["param_id"]) == pid:
                out.append(float(v["value"]))
    return out


# Start angles at which the firmware's saturation detection (pol_method 0) picks the south
# pole on the paper profile; the commissioning would detect it and recover with the motion
# check. None since the ±id incremental-Ld test replaced the pulse/chord comparison (that
# one failed at 60°, 180°, 300°: dead-time volt-second error of the even SVPWM vectors).
FIRMWARE_WRONG: set[int] = set()


@pytest.mark.parametrize("theta0", range(0, 360, 30))
def test_standstill_from_12_start_angles(make_desc: MakeDesc, tmp_path: Path,
                                         theta0: int) -> None:
    """Polarity, Ld, Lq and rs wherever the rotor happens to stop."""
    desc = make_desc(f"virtual.plant.initial.theta_e_deg={theta0}")
    run = commission.commission(desc, ["standstill"], tmp_path / "run")
    facts = run.step("standstill").facts
    starts = angle_errors_per_start(tmp_path / "run" / "bus.log")
    assert len(starts) == (1 if facts["polarity_first"] == "correct" else 2), facts
    # the commissioning's verdict on each start agrees with the plant's true angle
    # (a retry that raised leaves no final verdict: compared as such, with its facts)
    final = facts.get("polarity_final", f"none: the retry did not finish, {facts}")
    verdicts = [facts["polarity_first"], final][:len(starts)]
    for errs, verdict in zip(starts, verdicts, strict=True):
        assert errs.size >= 20
        truly = "correct" if np.max(np.abs(errs[-20:])) < 10.0 else (
            "wrong" if np.min(np.abs(errs[-20:])) > 170.0 else "unclear")
        assert verdict == truly, (verdict, errs[-20:])
    # the drive ends up running on the north pole, pol_method as it was
    assert facts["polarity_final"] == "correct"
    assert np.max(np.abs(starts[-1][-20:])) < 10.0
    assert pol_method_writes(tmp_path / "run" / "bus.log")[-1:] in ([], [0.0])
    truth = paper_truth()
    for key in ("rs_ohm", "ld_h", "lq_h"):
        assert within(run.value(key), truth[key], 0.05), (key, run.value(key))
    first = starts[0][-20:]
    if theta0 in FIRMWARE_WRONG:
        assert facts["polarity_first"] != "correct", "the firmware is right here now: " \
            "remove the angle from FIRMWARE_WRONG"
        pytest.xfail(f"firmware start-up polarity detection (pol_method 0) picks the south "
                     f"pole at {theta0}°: θ̂ - θ = {float(np.median(first)):+.1f}° measured; "
                     "the commissioning detects it and recovers with pol_method 2")
    assert run.passed, run.report_path.read_text()


def test_firmware_settings_follow_the_profile() -> None:
    """The firmware is told the hardware the plant emulates: ADC scaling, dead time, drop."""
    values = {"adc.bits": 16, "adc.range_a": 10.0, "inverter.dead_time_s": 2e-6,
              "inverter.device_drop_v": 1.2, "machine.rs_ohm": 1.93}
    assert firmware_settings(values) == {"adc_bits": 16, "adc_range_a": 10.0,
                                         "deadtime_us": 2.0, "vdrop_v": 1.2}


# -- safety ----------------------------------------------------------------------------


def run_cli(args: list[str], until: Callable[[str], bool] | None = None,
            sig: int = signal.SIGINT, timeout: float = RUN_S) -> tuple[int, str]:
    proc = subprocess.Popen([sys.executable, "-m", "rig", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    err = ""
    assert proc.stderr is not None
    if until is not None:
        deadline = time.monotonic() + timeout
        for line in proc.stderr:
            err += line
            if until(line):
                time.sleep(0.3)
                proc.send_signal(sig)
                break
            assert time.monotonic() < deadline
    out, rest = proc.communicate(timeout=timeout)
    return proc.returncode, err + rest + out


def test_ctrl_c_disables_the_drive_and_zeroes_the_load(unix_channel: str, programs_built: None,
                                                      tmp_path: Path) -> None:
    out = tmp_path / "run"
    code, text = run_cli(["commission", "all", "--bench", "virtual", "--set",
                          "can.transport=unixcan", "--set", f"can.channel={unix_channel}",
                          "--set", "modbus.port=0", "--out", str(out)],
                         until=lambda line: "step start:" in line)
    assert code == 130, text
    md = (out / "commissioning.md").read_text()
    assert "INTERRUPTED" in md
    assert "CAN: DRIVE_CMD enable 0 sent" in md and "console: disable → OK" in md
    assert "load bench: mode off, torque 0 (read back)" in md
    assert "drive state afterwards: DRIVE_STATUS IDLE, console enable=0 state=IDLE" in md
    assert not list(out.glob("console.pty"))  # fw_host stopped and removed its link


def test_silent_console_stops_within_its_time_out(make_desc: MakeDesc,
                                                  tmp_path: Path) -> None:
    master, slave = os.openpty()
    try:
        desc = make_desc(f"console.port={os.ttyname(slave)}", "console.timeout_s=0.5")
        t0 = time.monotonic()
        run = commission.commission(desc, ["all"], tmp_path / "run")
        wall = time.monotonic() - t0
    finally:
        os.close(master)
        os.close(slave)
    assert not run.passed
    err = run.step("connectivity").error or ""
    assert "ConsoleTimeout" in err and "no reply to 'ping' within 0.5 s" in err
    assert [s.step for s in run.steps] == ["connectivity"]  # nothing after the failure
    assert "drive state afterwards: DRIVE_STATUS IDLE" in run.data["safety"][-1]
    assert wall < RUN_S  # it ends (the 0.5 s is in the message; the rest is the start-up)


def test_unreachable_load_bench_stops_with_a_clear_error(make_desc: MakeDesc,
                                                         tmp_path: Path) -> None:
    import socket

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    desc = make_desc('virtual.programs=["plant_rt", "fw_host"]', f"modbus.port={port}",
                     "modbus.timeout_s=0.5")
    run = commission.commission(desc, ["connectivity"], tmp_path / "run")
    assert not run.passed
    err = run.step("connectivity").error or ""
    assert f"modbus tcp 127.0.0.1:{port} unit 1: cannot connect" in err
    assert "drive state afterwards: DRIVE_STATUS IDLE" in run.data["safety"][-1]


@pytest.mark.vcan
def test_commission_over_socketcan(programs_built: None, tmp_path: Path) -> None:
    from rig import bus as rigbus
    from rig.bench import description as bd

    if not rigbus.kernel_has_can():
        pytest.skip("this kernel has no CAN (run inside the VM: rig vm -- pytest -m vcan)")
    if not rigbus.interface_exists("vcan0"):
        if os.geteuid() != 0:
            pytest.skip("vcan0 does not exist and creating it needs root")
        rigbus.vcan_up("vcan0")
    # in the TCG VM Python starts slowly (the load bench server imports over 9p)
    desc = bd.load("virtual", ["can.transport=socketcan", "can.channel=vcan0",
                               "modbus.port=0", "virtual.ready_timeout_s=180.0",
                               "modbus.timeout_s=5.0", "console.timeout_s=10.0"])
    run = commission.commission(desc, ["connectivity", "polarity"], tmp_path / "run")
    assert run.passed, run.report_path.read_text()
    assert run.data["can"] == "socketcan vcan0"
