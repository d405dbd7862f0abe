"""Test levels of the commissioning scripts: the ``[commissioning]`` table of a bench
description (every key optional; unknown keys are errors)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from rig.bench.description import BenchDescriptionError


@dataclass(frozen=True)
class CommissioningConfig:
    # limits the scripts run with (DRIVE_LIMITS)
    i_max_a: float = 4.0
    speed_max_rpm: float = 3300.0
    accel_rpm_s: float = 3000.0
    # start-up: polarity detection must end in RUN within this much bench time
    start_timeout_s: float = 1.0
    # polarity check: locked rotor, this q current must give a positive shaft torque of at
    # least this fraction of the nominal 1.5·p·λm·iq
    polarity_current_a: float = 1.0
    polarity_torque_fraction: float = 0.3
    # Ld, Lq: slope estimator at standstill, zero current
    ldlq_settle_s: float = 0.25
    ldlq_window_s: float = 0.1
    # rs: locked rotor, q-current steps; voltage vs current slope. First the load machine
    # turns the rotor at rs_align_speed_rpm until the q axis of θ̂ lies within
    # rs_align_tolerance_deg (electrical) of a phase axis: then every phase carries at least
    # half the step current, well above the ripple, so the inverter's voltage error is the
    # same at every step. The online inductances settle (param_tau_ms) before the window.
    rs_align_speed_rpm: float = 5.0
    rs_align_tolerance_deg: float = 3.0
    rs_align_timeout_s: float = 3.0
    rs_currents_a: tuple[float, ...] = (1.5, 2.25, 3.0)
    rs_settle_s: float = 0.2
    rs_window_s: float = 0.3
    # current steps of the polarity and flux tests
    step_settle_s: float = 0.08
    step_window_s: float = 0.1
    # sensorless start at low speed (free shaft)
    start_speed_rpm: float = 100.0
    start_accel_rpm_s: float = 500.0
    start_hold_s: float = 0.3
    start_tolerance_rpm: float = 10.0
    start_fw_mode: str = "conventional"
    # λm: the load machine holds each speed, ±flux_current_a in q, id = 0
    flux_speeds_rpm: tuple[float, ...] = (300.0, 600.0, 900.0)
    flux_current_a: float = 1.0
    flux_ramp_rpm_s: float = 2000.0
    # cross-saturation: the load machine holds the speed, these q currents in turn (both
    # signs), each for the dwell time; the drive's estimate is then written
    xsat_speed_rpm: float = 1000.0
    xsat_currents_a: tuple[float, ...] = (1.0, 2.0, 3.0, -1.0, -2.0, -3.0)
    xsat_dwell_s: float = 2.0
    # the fit's rms deviation of (Lq - Ld) tan(2 turn)/2 from the line: at most this, H*A, or
    # this fraction of the fitted Ldq at the largest current when that is more (the noise of
    # the online Lq - Ld scales with the turn: 0.03-0.05 mH*A at 0.5 mH on the harsh machine)
    xsat_fit_rms_ha: float = 5e-5
    xsat_fit_rms_rel: float = 0.15
    # speed sweep with load steps (speed control, load machine in torque mode)
    sweep_speeds_rpm: tuple[float, ...] = (300.0, 1000.0, 1800.0)
    sweep_load_nm: float = 1.0
    sweep_settle_s: float = 0.2
    sweep_step_s: float = 0.3
    sweep_fw_mode: str = "realtime"
    sweep_tolerance_rpm: float = 20.0
    sweep_recovery_s: float = 0.3

    @classmethod
    def from_mapping(cls, raw: Mapping[str, Any], where: str = "[commissioning]"
                     ) -> CommissioningConfig:
        known = {f.name: f for f in fields(cls)}
        unknown = set(raw) - set(known)
        if unknown:
            raise BenchDescriptionError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
        base = cls()
        values: dict[str, Any] = {}
        for key, value in raw.items():
            default = getattr(base, key)
            if isinstance(default, tuple):
                if not isinstance(value, list) or not value or not all(
                        isinstance(x, int | float) and not isinstance(x, bool) for x in value):
                    raise BenchDescriptionError(f"{where}.{key}: a non-empty list of numbers")
                values[key] = tuple(float(x) for x in value)
            elif isinstance(default, float):
                if isinstance(value, bool) or not isinstance(value, int | float):
                    raise BenchDescriptionError(f"{where}.{key}: a number")
                values[key] = float(value)
            else:
                if not isinstance(value, str):
                    raise BenchDescriptionError(f"{where}.{key}: a string")
                values[key] = value
        cfg = replace(base, **values)
        for key in ("start_fw_mode", "sweep_fw_mode"):
            if getattr(cfg, key) not in ("realtime", "conventional", "id_zero"):
                raise BenchDescriptionError(f"{where}.{key}: realtime, conventional or id_zero")
        if max(cfg.rs_currents_a) > cfg.i_max_a or cfg.flux_current_a > cfg.i_max_a:
            raise BenchDescriptionError(f"{where}: test currents above i_max_a")
        if not 0.0 < cfg.rs_align_speed_rpm <= 60.0:
            raise BenchDescriptionError(f"{where}.rs_align_speed_rpm: above 0, at most 60 r/min")
        if not 0.0 < cfg.rs_align_tolerance_deg <= 15.0:
            raise BenchDescriptionError(f"{where}.rs_align_tolerance_deg: above 0, at most 15°")
        if cfg.rs_align_timeout_s <= 0.0:
            raise BenchDescriptionError(f"{where}.rs_align_timeout_s: above 0")
        if len(cfg.rs_currents_a) < 2:
            raise BenchDescriptionError(f"{where}.rs_currents_a: at least two currents")
        return cfg
