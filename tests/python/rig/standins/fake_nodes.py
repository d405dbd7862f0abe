"""Stand-ins for plant_rt and fw_host: tiny Python programs that speak the same protocol.

They exist only to test the rig's supervisor and runner before (and independently of) the
C programs: same command-line flags, ready files, lockstep pacing (BENCH_STEP /
BENCH_PROGRESS), VIO exchange per period, trace files and exit JSON. The physics is a toy:
the plant is a rigid shaft driven by a torque the fake firmware asks for (coded in a PWM
compare value), and the fake firmware's estimate is the true angle (read from a fake ADC
code) plus a fixed error, so tests know the expected position error exactly.

Fault injection by environment:
  FAKE_<ROLE>_CRASH_AT=<period>  exit with status 3 there
  FAKE_<ROLE>_HANG=1             ignore SIGTERM
  FAKE_PLANT_LOSE_STEP=<n>       ignore the n-th BENCH_STEP (a lost grant)
  FAKE_PLANT_FREEZE_AT=<period>  stop simulating there (still alive and talking)
  FAKE_PLANT_DROP=<p1,p2>        leave these periods out of the trace
  FAKE_FW_ERR_DEG=<deg>          the estimate's error (default 0.5)
  FAKE_RT_SCALE=<x>              real-time clock x times slower than the wall clock
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from pathlib import Path

import can

from rig import bus as rigbus
from rig import protocols
from rig.data.trace import TraceWriter

TS = protocols.timebase().ts
POLE_PAIRS = 2
J = 0.0005
B = 0.003
KT = 0.65  # N*m/A
STOP = False


def _msg(db: str, name: str):  # type: ignore[no-untyped-def]
    return protocols.database(db).get_message_by_name(name)


def _frame(m, values) -> can.Message:  # type: ignore[no-untyped-def]
    return can.Message(arbitration_id=m.frame_id, is_extended_id=False,
                       data=m.encode(values, strict=False), is_fd=bool(m.is_fd))


def _on_term(signum: int, frame: object) -> None:
    global STOP
    STOP = True


def _args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    p.add_argument("--bus", default="unixcan")
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--lockstep", action="store_true")
    p.add_argument("--realtime", action="store_true")
    p.add_argument("--trace")
    p.add_argument("--trace-vio", action="store_true")  # plant_rt's (the stand-in has no VIO)
    p.add_argument("--ready-file")
    p.add_argument("--config")
    p.add_argument("--set", action="append", default=[])
    p.add_argument("--max-periods", type=int, default=0)
    p.add_argument("--first-period", type=int)  # fw_host's pairing (the stand-in has none)
    return p.parse_args(argv)


def _ready(path: str | None) -> None:
    if path:
        tmp = Path(path + ".tmp")
        tmp.write_text(str(os.getpid()))
        tmp.replace(path)


def _env_int(name: str) -> int | None:
    v = os.environ.get(name)
    return int(v) if v else None


def plant(argv: list[str]) -> int:
    a = _args(argv)
    hang = os.environ.get("FAKE_PLANT_HANG") == "1"
    signal.signal(signal.SIGTERM, signal.SIG_IGN if hang else _on_term)
    signal.signal(signal.SIGINT, _on_term)
    crash_at = _env_int("FAKE_PLANT_CRASH_AT")
    rt_scale = float(os.environ.get("FAKE_RT_SCALE", "1"))  # Python cannot keep 10 kHz
    drop = {int(x) for x in os.environ.get("FAKE_PLANT_DROP", "").split(",") if x}
    sets = dict(s.split("=", 1) for s in a.set)
    m_truth, m_mag = _msg("bench", "BENCH_TRUTH"), _msg("bench", "BENCH_TRUTH_MAG")
    m_adc, m_pwm = _msg("vio", "VIO_ADC_0"), _msg("vio", "VIO_PWM")
    m_step, m_prog = _msg("bench", "BENCH_STEP"), _msg("bench", "BENCH_PROGRESS")
    m_load, m_cnt = _msg("bench", "LOAD_CMD"), _msg("bench", "BENCH_COUNTERS")
    bus = rigbus.open_bus(a.bus, a.channel)  # after the slow DBC loading: then ready at once
    trace = TraceWriter(a.trace) if a.trace else None
    theta = math.radians(float(sets.get("initial.theta_e_deg", 0.0)))
    omega = float(sets.get("initial.speed_rpm", 0.0)) * 2 * math.pi / 60
    run_until, seq = 0, 0
    iq = 0.0
    tl_cmd, k_speed, load_mode = 0.0, 0.0, 0
    pwm: dict[int, float] = {}
    k = 0
    counters = {"periods": 0, "adc_resends": 0, "late_cmds": 0, "loads": 0, "steps": 0}
    lose_step = _env_int("FAKE_PLANT_LOSE_STEP")
    freeze_at = _env_int("FAKE_PLANT_FREEZE_AT")
    _ready(a.ready_file)
    last_beat = time.monotonic()
    adc_sent_at = 0.0
    t0 = time.monotonic()

    def handle(msg: can.Message) -> None:
        nonlocal run_until, seq, tl_cmd, k_speed, load_mode
        if msg.arbitration_id == m_step.frame_id and not a.realtime:
            counters["steps"] += 1
            if counters["steps"] == lose_step:
                return  # injected loss of this grant
            v = m_step.decode(msg.data)
            run_until, seq = int(v["run_until"]), int(v["seq"])
        elif msg.arbitration_id == m_pwm.frame_id:
            v = m_pwm.decode(msg.data)
            pwm[int(v["period"])] = (int(v["cmp_a_up"]) - 2500) / 500.0
        elif msg.arbitration_id == m_load.frame_id:
            v = m_load.decode(msg.data, decode_choices=False)
            load_mode, tl_cmd, k_speed = int(v["mode"]), float(v["torque"]), float(v["k_speed"])
            counters["loads"] += 1

    def progress(state: int) -> None:
        bus.send(_frame(m_prog, {"period": k, "seq": seq, "state": state}))

    while not STOP:
        if a.max_periods and k >= a.max_periods:
            break
        now = time.monotonic()
        if now - last_beat > 0.1:
            last_beat = now
            progress(1 if k < run_until else 0)
            bus.send(_frame(m_cnt, {"period": k, "late_cmds": counters["late_cmds"],
                                    "overruns": 0, "rejected": 0, "adc_clipped": 0,
                                    "tx_drops": 0, "max_late_us": 0}))
        if a.realtime:
            may_run = (now - t0) / TS * rt_scale > k
        else:
            may_run = k < run_until
        need_pwm = k > 0 and not a.realtime
        if freeze_at is not None and k >= freeze_at:
            may_run = False  # alive, talking, but not simulating any more
        if may_run and (not need_pwm or k in pwm):
            if crash_at is not None and k >= crash_at:
                print(f"fake plant: injected crash at period {k} (t={time.time():.6f})",
                      file=sys.stderr, flush=True)
                os._exit(3)
            if k in pwm:
                iq = pwm.pop(k)
            elif a.realtime and k > 0:
                counters["late_cmds"] += 1
            tl = tl_cmd + k_speed * omega if load_mode == 0 else 0.0
            te = KT * iq
            if trace is not None and k not in drop:
                trace.write(m_truth.frame_id, m_truth.encode({
                    "period": k, "theta_e": math.remainder(theta, 2 * math.pi),
                    "omega_m": omega, "id": 0.0, "iq": iq, "te": te, "tl": tl, "t_shaft": te,
                    "ia": 0.0, "ib": 0.0, "vdc": 200.0, "psi_d": 0.216, "psi_q": 0.0,
                    "ua": 0.0, "ub": 0.0, "uc": 0.0}, strict=False))
                trace.write(m_mag.frame_id, m_mag.encode({
                    "period": k, "ld_inc": 0.015, "lq_inc": 0.032, "ldq_inc": 0.0,
                    "ld_app": 0.015, "lq_app": 0.032, "lambda_m": 0.216, "rs": 1.93},
                    strict=False))
            # the ADC frame carries the true angle (µrad) and speed (mrad/s): a fake sensor
            adc = {"period": k, "n_soc": 2, "vdc_code": 0,
                   "ia_0": round(math.remainder(theta, 2 * math.pi) * 1e6),
                   "ib_0": round(omega * 1e3)}
            adc.update({f"{c}_{i}": 0 for c in ("ia", "ib") for i in range(1, 7)})
            bus.send(_frame(m_adc, adc))
            adc_sent_at = time.monotonic()
            last_adc = adc
            omega += (te - tl - B * omega) / J * TS
            theta += omega * POLE_PAIRS * TS
            k += 1
            counters["periods"] = k
            if not a.realtime and k == run_until:
                progress(0)
            continue
        if need_pwm and may_run and time.monotonic() - adc_sent_at > 0.1:
            bus.send(_frame(m_adc, last_adc))
            adc_sent_at = time.monotonic()
            counters["adc_resends"] += 1
        msg = bus.recv(timeout=0.0005 if a.realtime else 0.02)
        while msg is not None:
            handle(msg)
            msg = bus.recv(timeout=0)
    if trace is not None:
        trace.close()
    bus.shutdown()
    print(json.dumps({"node": "fake_plant", **counters}), file=sys.stderr, flush=True)
    return 0


def firmware(argv: list[str]) -> int:
    a = _args(argv)
    hang = os.environ.get("FAKE_FW_HANG") == "1"
    signal.signal(signal.SIGTERM, signal.SIG_IGN if hang else _on_term)
    signal.signal(signal.SIGINT, _on_term)
    crash_at = _env_int("FAKE_FW_CRASH_AT")
    err = math.radians(float(os.environ.get("FAKE_FW_ERR_DEG", "0.5")))
    m_adc, m_pwm = _msg("vio", "VIO_ADC_0"), _msg("vio", "VIO_PWM")
    m_cmd, m_lim = _msg("drive", "DRIVE_CMD"), _msg("drive", "DRIVE_LIMITS")
    m_tr, m_pos = _msg("vio", "FW_TRACE"), _msg("drive", "TLM_POS")
    m_tr.encode({s.name: 0 for s in m_tr.signals}, strict=False)  # warm up the codecs
    m_pwm.encode({s.name: 0 for s in m_pwm.signals}, strict=False)
    bus = rigbus.open_bus(a.bus, a.channel)
    trace = TraceWriter(a.trace) if a.trace else None
    enable, target, accel, i_max = 0, 0.0, 1e5, 3.0
    ref = 0.0
    integ = 0.0
    last_pwm: tuple[int, can.Message] | None = None
    counters = {"isr": 0, "repeats": 0, "cmds": 0}
    _ready(a.ready_file)
    stamp = 5000
    while not STOP:
        msg = bus.recv(timeout=0.05)
        if msg is None:
            continue
        if msg.arbitration_id == m_cmd.frame_id:
            v = m_cmd.decode(msg.data, decode_choices=False)
            enable, target = int(v["enable"]), float(v["speed_ref"])
            counters["cmds"] += 1
        elif msg.arbitration_id == m_lim.frame_id:
            v = m_lim.decode(msg.data)
            accel, i_max = float(v["accel_max"]), float(v["i_max"])
        elif msg.arbitration_id == m_adc.frame_id:
            v = m_adc.decode(msg.data)
            k = int(v["period"])
            if last_pwm is not None and last_pwm[0] == k:
                bus.send(last_pwm[1])
                counters["repeats"] += 1
                continue
            if crash_at is not None and k >= crash_at:
                print(f"fake firmware: injected crash at period {k} (t={time.time():.6f})",
                      file=sys.stderr, flush=True)
                os._exit(3)
            theta = v["ia_0"] * 1e-6
            omega_m = v["ib_0"] * 1e-3
            omega_e = omega_m * POLE_PAIRS
            step = accel * TS
            ref = min(target, ref + step) if target > ref else max(target, ref - step)
            e = ref - omega_m * 60 / (2 * math.pi)
            integ += 0.5 * e * TS
            iq = max(-i_max, min(i_max, 0.02 * e + integ)) if enable else 0.0
            theta_hat = math.remainder(theta + omega_e * stamp * 1e-8 + err, 2 * math.pi)
            if trace is not None:
                trace.write(m_tr.frame_id, m_tr.encode({
                    "period": k, "stamp": stamp, "state": 3 if enable else 1, "slopes_ok": 2,
                    "sector": 1, "fw_active": 0, "theta_hat": theta_hat, "omega_hat": omega_e,
                    "id": 0.0, "iq": iq, "id_ref": 0.0, "iq_ref": iq, "vd": 1.0, "vq": 10.0,
                    "ld_hat": 0.015, "lq_hat": 0.032, "lambda_hat": 0.216, "te_hat": 0.65 * iq,
                    "theta_raw": theta_hat, "residual": 0.0}, strict=False))
            code = round(2500 + iq * 500)
            pwm = _frame(m_pwm, {"period": k + 1, "cmp_a_up": code, "cmp_a_dn": 0,
                                 "cmp_b_up": 0, "cmp_b_dn": 0, "cmp_c_up": 0, "cmp_c_dn": 0,
                                 "n_soc": 2, "gate_enable": enable,
                                 **{f"soc_{i}": 0 for i in range(16)}})
            bus.send(pwm)
            last_pwm = (k, pwm)
            counters["isr"] += 1
            if k % 10 == 0:
                bus.send(_frame(m_pos, {"period": k & 0xFFFF,
                                        "theta_hat": math.degrees(theta_hat) % 359.99,
                                        "speed_hat": omega_m * 60 / (2 * math.pi)}))
    if trace is not None:
        trace.close()
    bus.shutdown()
    print(json.dumps({"node": "fake_fw", **counters}), file=sys.stderr, flush=True)
    return 0


def main(role: str, argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    # the unixcan reader thread must get the GIL well within a sender's 2 ms patience
    sys.setswitchinterval(0.0002)
    return plant(args) if role == "plant" else firmware(args)
