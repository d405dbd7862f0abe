"""ctypes access to libplant_core.so (plant_rt/include/plant_core.h) for the plant tests."""

from __future__ import annotations

import ctypes as C
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig import _paths, protocols

MAX_SOC = 16
TBPRD = protocols.timebase().tbprd
PERIOD_TICKS = protocols.timebase().period_ticks
TBCLK_HZ = float(protocols.timebase().tbclk_hz)
TS = protocols.timebase().ts
PROFILES = Path(__file__).resolve().parents[3] / "plant_rt" / "profiles"


class PwmCmd(C.Structure):
    _fields_ = [
        ("period", C.c_uint32),
        ("cmp_up", C.c_uint16 * 3),
        ("cmp_dn", C.c_uint16 * 3),
        ("soc", C.c_uint16 * MAX_SOC),
        ("n_soc", C.c_uint8),
        ("gate_enable", C.c_uint8),
    ]


class Samples(C.Structure):
    _fields_ = [
        ("period", C.c_uint32),
        ("n_soc", C.c_uint32),
        ("ia_code", C.c_int32 * MAX_SOC),
        ("ib_code", C.c_int32 * MAX_SOC),
        ("vdc_code", C.c_int32 * MAX_SOC),
        ("ia_true", C.c_double * MAX_SOC),
        ("ib_true", C.c_double * MAX_SOC),
        ("ia_sensor", C.c_double * MAX_SOC),
        ("ib_sensor", C.c_double * MAX_SOC),
        ("ia_adc_in", C.c_double * MAX_SOC),
        ("ib_adc_in", C.c_double * MAX_SOC),
        ("clipped", C.c_uint32),
    ]


TRUTH_FIELDS = (
    "t_s theta_e omega_m id iq te tl t_shaft ia ib ic vdc psi_d psi_q ua ub uc "
    "ld_inc lq_inc ldq_inc ld_app lq_app lambda_m rs"
).split()


class Truth(C.Structure):
    _fields_ = [("period", C.c_uint32)] + [(n, C.c_double) for n in TRUTH_FIELDS]


class Stats(C.Structure):
    _fields_ = [
        (n, C.c_uint64)
        for n in (
            "periods adc_clipped rk_steps rhs_evals conduction_events newton_iterations "
            "newton_failures mode_loops_cut"
        ).split()
    ]


def _load() -> C.CDLL:
    lib = C.CDLL(str(_paths.library("libplant_core.so")))
    vp, dp, sz = C.c_void_p, C.POINTER(C.c_double), C.c_size_t
    lib.plant_open.restype = vp
    lib.plant_open.argtypes = [C.c_char_p, C.POINTER(C.c_char_p), C.c_int, C.c_char_p, sz]
    lib.plant_free.argtypes = [vp]
    lib.plant_step.argtypes = [vp, C.POINTER(PwmCmd), C.POINTER(Samples), C.POINTER(Truth)]
    lib.plant_truth_now.argtypes = [vp, C.POINTER(Truth)]
    lib.plant_next_period.restype = C.c_uint32
    lib.plant_next_period.argtypes = [vp]
    lib.plant_get_stats.argtypes = [vp, C.POINTER(Stats)]
    lib.plant_set_state.argtypes = [vp, C.c_double, C.c_double, C.c_double, C.c_double]
    lib.plant_set_load.argtypes = [vp, C.c_int, C.c_double, C.c_double, C.c_double]
    lib.plant_flux_map.argtypes = [vp, C.c_double, C.c_double, dp, dp]
    lib.plant_current_from_flux.restype = C.c_int
    lib.plant_current_from_flux.argtypes = [vp, C.c_double, C.c_double, dp]
    lib.plant_set_fault.restype = C.c_int
    lib.plant_set_fault.argtypes = [vp, C.c_int, C.c_int, C.c_int, C.c_int, C.c_int,
                                    C.c_double, C.c_uint32, C.c_char_p, sz]
    lib.plant_adc_current_code.restype = C.c_int32
    lib.plant_adc_current_code.argtypes = [C.c_double, C.c_int, C.c_double, C.POINTER(C.c_int)]
    for name, struct in (
        ("plant_sizeof_pwm_cmd", PwmCmd),
        ("plant_sizeof_samples", Samples),
        ("plant_sizeof_truth", Truth),
        ("plant_sizeof_stats", Stats),
    ):
        fn = getattr(lib, name)
        fn.restype = sz
        if fn() != C.sizeof(struct):
            raise RuntimeError(f"{name}: C {fn()} bytes, ctypes mirror {C.sizeof(struct)}")
    return lib


_LIB: C.CDLL | None = None


def lib() -> C.CDLL:
    global _LIB
    if _LIB is None:
        _LIB = _load()
    return _LIB


def profile_path(name: str) -> Path:
    return PROFILES / f"{name}.toml"


def profile(name: str, overrides: dict[str, float] | None = None) -> dict[str, dict[str, Any]]:
    """The profile as Python reads it (tomllib), with --set style overrides applied."""
    with open(profile_path(name), "rb") as fh:
        data = tomllib.load(fh)
    for key, value in (overrides or {}).items():
        section, name_ = key.split(".")
        data[section][name_] = value
    return data


@dataclass
class Pwm:
    """One period's command."""

    cmp_up: tuple[int, int, int]
    cmp_dn: tuple[int, int, int]
    soc: list[int] = field(default_factory=list)
    gate_enable: int = 1


@dataclass
class StepResult:
    truth: dict[str, float]
    ia_true: np.ndarray
    ib_true: np.ndarray
    ia_sensor: np.ndarray
    ib_sensor: np.ndarray
    ia_adc_in: np.ndarray
    ib_adc_in: np.ndarray
    ia_code: np.ndarray
    ib_code: np.ndarray
    vdc_code: np.ndarray
    clipped: int


def truth_dict(t: Truth) -> dict[str, float]:
    out = {n: float(getattr(t, n)) for n in TRUTH_FIELDS}
    out["period"] = float(t.period)
    return out


class Plant:
    def __init__(self, profile_name: str | None, overrides: dict[str, float] | None = None):
        sets = [f"{k}={v!r}" for k, v in (overrides or {}).items()]
        arr = (C.c_char_p * max(1, len(sets)))(*[s.encode() for s in sets])
        err = C.create_string_buffer(512)
        path = str(profile_path(profile_name)).encode() if profile_name else None
        self._lib = lib()
        self._h = self._lib.plant_open(path, arr, len(sets), err, len(err))
        if not self._h:
            raise ValueError(err.value.decode())

    def close(self) -> None:
        if self._h:
            self._lib.plant_free(self._h)
            self._h = None

    def __del__(self) -> None:
        self.close()

    def step(self, pwm: Pwm) -> StepResult:
        cmd = PwmCmd()
        cmd.period = self._lib.plant_next_period(self._h)
        for k in range(3):
            cmd.cmp_up[k] = pwm.cmp_up[k]
            cmd.cmp_dn[k] = pwm.cmp_dn[k]
        for k, s in enumerate(pwm.soc):
            cmd.soc[k] = s
        cmd.n_soc = len(pwm.soc)
        cmd.gate_enable = pwm.gate_enable
        smp, tr = Samples(), Truth()
        self._lib.plant_step(self._h, C.byref(cmd), C.byref(smp), C.byref(tr))
        n = len(pwm.soc)
        return StepResult(
            truth=truth_dict(tr),
            ia_true=np.array(smp.ia_true[:n]),
            ib_true=np.array(smp.ib_true[:n]),
            ia_sensor=np.array(smp.ia_sensor[:n]),
            ib_sensor=np.array(smp.ib_sensor[:n]),
            ia_adc_in=np.array(smp.ia_adc_in[:n]),
            ib_adc_in=np.array(smp.ib_adc_in[:n]),
            ia_code=np.array(smp.ia_code[:n]),
            ib_code=np.array(smp.ib_code[:n]),
            vdc_code=np.array(smp.vdc_code[:n]),
            clipped=int(smp.clipped),
        )

    def truth_now(self) -> dict[str, float]:
        tr = Truth()
        self._lib.plant_truth_now(self._h, C.byref(tr))
        return truth_dict(tr)

    def stats(self) -> dict[str, int]:
        st = Stats()
        self._lib.plant_get_stats(self._h, C.byref(st))
        return {f[0]: int(getattr(st, f[0])) for f in Stats._fields_}

    def set_state(self, theta_e: float, omega_m: float, id_: float, iq: float) -> None:
        self._lib.plant_set_state(self._h, theta_e, omega_m, id_, iq)

    def set_fault(self, slot: int, kind: str, *, channel: int = 0, phase: int = 0,
                  gate: int = 0, value: float = 0.0, periods: int = 0) -> None:
        """A physical fault from the next period on; kind by its name in bench.dbc's
        FAULT_CMD.kind (OPEN_PHASE, GATE_OFF, ...)."""
        choices = protocols.database("bench").get_message_by_name("FAULT_CMD") \
            .get_signal_by_name("kind").choices
        code = next(int(v) for v, n in choices.items() if str(n) == kind)
        err = C.create_string_buffer(256)
        if self._lib.plant_set_fault(self._h, slot, code, channel, phase, gate, value, periods,
                                     err, len(err)) != 0:
            raise ValueError(err.value.decode())

    def set_load(self, mode: int, torque: float = 0.0, speed_rpm: float = 0.0, k: float = 0.0):
        self._lib.plant_set_load(self._h, mode, torque, speed_rpm, k)

    def flux(self, id_: float, iq: float) -> tuple[np.ndarray, np.ndarray]:
        psi = (C.c_double * 2)()
        linc = (C.c_double * 3)()
        self._lib.plant_flux_map(self._h, id_, iq, psi, linc)
        return np.array(psi[:]), np.array(linc[:])

    def current_from_flux(self, psi_d: float, psi_q: float) -> tuple[np.ndarray, int]:
        i = (C.c_double * 2)()
        it = self._lib.plant_current_from_flux(self._h, psi_d, psi_q, i)
        return np.array(i[:]), int(it)
