"""ctypes access to libfwcore.so (firmware_c2000/core) for the firmware tests.

Only the thin ``fwt_*`` entry points (firmware_c2000/core/test_api/fw_test_api.c) and the public
API are used; they take doubles and int32 so no struct layout is duplicated here except the
parameter metadata of ``fw_param_info_t``. The core's status (``fw_status_t``) is mirrored by
names: ``FwStatus`` is built from the library's own field table (``fwt_status_field``: name,
offset, C type of every field) and checked against its offsets and size.
"""

from __future__ import annotations

import ctypes as C
import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from rig import _paths, protocols

TBPRD = protocols.timebase().tbprd
PERIOD_TICKS = protocols.timebase().period_ticks
TBCLK_HZ = float(protocols.timebase().tbclk_hz)
TICK = 1.0 / TBCLK_HZ
TS = PERIOD_TICKS * TICK
MAX_SOC = 16

# the core's FW_STATE_* and FW_FAULT_*: DRIVE_STATUS's value tables (protocols/drive.dbc)
_STATE = protocols.spelled("drive", "DRIVE_STATUS", "state")
_FAULT = protocols.spelled("drive", "DRIVE_STATUS", "fault_code")
STATE_IDLE, STATE_POLARITY, STATE_RUN, STATE_FAULT = (
    _STATE["IDLE"], _STATE["POLARITY"], _STATE["RUN"], _STATE["FAULT"])
FAULT_ADC_LOSS, FAULT_CMD_TIMEOUT = _FAULT["ADC_LOSS"], _FAULT["CMD_TIMEOUT"]

_D = C.c_double
_I = C.c_int32
_PD = C.POINTER(C.c_double)
_PI = C.POINTER(C.c_int32)


class ParamInfo(C.Structure):
    """fw_param_info_t (real_t is float in this build; checked by real_size())."""

    _fields_ = [
        ("id", C.c_uint16),
        ("name", C.c_char_p),
        ("unit", C.c_char_p),
        ("min", C.c_float),
        ("max", C.c_float),
        ("default", C.c_float),
        ("read_only", C.c_int16),
    ]


@cache
def lib() -> C.CDLL:
    so = C.CDLL(str(_paths.library("libfwcore.so")))
    sig: dict[str, tuple[object, list[object]]] = {
        "fwt_core_size": (_I, []),
        "fwt_real_size": (_I, []),
        "fwt_svpwm": (_I, [_D, _D, _D, _D, _D, _D, _I, _I, C.c_uint32, _PD, _PI, _PD]),
        "fwt_svpwm_vmax": (_D, [_D, _D]),
        "fwt_slope_window": (_I, [_I, _PI, _PI, _PI, _I, _D, _PD]),
        "fwt_slope_diff": (None, [_D, _D, _D, _D, _D, _D, _D, _PD]),
        "fwt_slope_solve": (_I, [_I, _PI, _PD, _PD, _D, _D, _D, _PD]),
        "fwt_tracker_size": (_I, []),
        "fwt_tracker_init": (None, [C.c_void_p, _D, _D, _D, _D]),
        "fwt_tracker_step": (None, [C.c_void_p, _D, _I, _PD]),
        "fwt_refs_mtpa_id": (_D, [_D, _D, _D, _D]),
        "fwt_refs_fluxweak_id": (_D, [_D, _D, _D, _D, _D, _D]),
        "fwt_refs_torque": (_D, [_D, _D, _D, _D, _D, _D]),
        "fwt_refs_select": (_I, [_I, _D, _D, _D, _D, _D, _D, _D, _D, _PD]),
        "fwt_flux_size": (_I, []),
        "fwt_flux_reset": (None, [C.c_void_p, _D]),
        "fwt_flux_update": (_I, [C.c_void_p, _D, _D, _D, _D, _D, _D, _D, _D, _D, _D, _D, _PD]),
        "fwt_paramest_size": (_I, []),
        "fwt_paramest_reset": (None, [C.c_void_p, _D, _D, _D]),
        "fwt_paramest_update": (None, [C.c_void_p, _D, _D, _D, _D, _D, _D, _PD]),
        "fwt_paramest_apparent": (None, [C.c_void_p, _D, _PD]),
        "fwt_status": (None, [C.c_void_p, C.c_void_p]),
        "fwt_status_size": (_I, []),
        "fwt_status_field": (C.c_char_p, [_I, _PI, C.POINTER(C.c_char_p)]),
        "fwt_command": (_I, [C.c_void_p, _I, _I, _I, _I, _D, _D]),
        "fwt_param_set": (_I, [C.c_void_p, _I, _D]),
        "fwt_param_get": (_I, [C.c_void_p, _I, _PD]),
        "fwt_isr": (None, [C.c_void_p, _I, C.c_uint32, _I, _PI, _PI, _I, _PI]),
        "fw_core_init": (None, [C.c_void_p]),
        "fw_param_count": (C.c_uint16, []),
        "fw_param_info_at": (C.POINTER(ParamInfo), [C.c_uint16]),
    }
    for name, (res, args) in sig.items():
        fn = getattr(so, name)
        fn.restype = res
        fn.argtypes = args
    return so


_CTYPES: dict[str, type[C._SimpleCData[Any]]] = {
    "int16_t": C.c_int16, "uint16_t": C.c_uint16, "int32_t": C.c_int32, "uint32_t": C.c_uint32,
}


@cache
def status_type() -> type[C.Structure]:
    """The ctypes mirror of ``fw_status_t``, made from the library's field table (names, offsets,
    C types) and checked against it: a field the core adds is mirrored without an edit here."""
    so = lib()
    real = C.c_float if so.fwt_real_size() == 4 else C.c_double
    fields: list[tuple[str, type[C._SimpleCData[Any]]]] = []
    offsets: list[int] = []
    i = 0
    while True:
        off, ctype = C.c_int32(), C.c_char_p()
        name = so.fwt_status_field(i, C.byref(off), C.byref(ctype))
        if name is None:
            break
        assert ctype.value is not None
        t = real if ctype.value == b"real_t" else _CTYPES[ctype.value.decode()]
        fields.append((name.decode(), t))
        offsets.append(off.value)
        i += 1
    mirror = type("FwStatus", (C.Structure,), {"_fields_": fields})
    got = [getattr(mirror, n).offset for n, _ in fields]
    assert got == offsets, f"fw_status_t offsets {offsets}, ctypes {got}"
    assert C.sizeof(mirror) == so.fwt_status_size(), "fw_status_t size"
    return mirror


def status_fields() -> list[str]:
    """The names of the fields of ``fw_status_t``, in their order."""
    return [n for n, _ in status_type()._fields_]


def dbuf(n: int) -> C.Array[C.c_double]:
    return (C.c_double * n)()


def ibuf(values: list[int] | int) -> C.Array[C.c_int32]:
    if isinstance(values, int):
        return (C.c_int32 * values)()
    return (C.c_int32 * len(values))(*values)


@dataclass(frozen=True)
class Window:
    measured: bool
    vec: int
    start: int
    end: int
    soc_first: int
    soc_count: int


@dataclass(frozen=True)
class Plan:
    cmp_up: tuple[int, int, int]
    cmp_dn: tuple[int, int, int]
    soc: tuple[int, ...]
    layout: int
    sector: int
    clipped: bool
    windows: tuple[Window, Window, Window]  # zero, odd, even
    t_odd: int
    t_even: int
    vec_odd: int
    vec_even: int
    v_applied: tuple[float, float]


def svpwm(
    vdc: float,
    v_alpha: float,
    v_beta: float,
    *,
    tmin_us: float = 20.0,
    on_us: float = 10.0,
    off_us: float = 5.0,
    n_per_state: int = 2,
    stretch: bool = True,
    parity: int = 0,
    carry: list[float] | None = None,
) -> Plan:
    out = ibuf(48)
    va = dbuf(2)
    cbuf = None
    if carry is not None:
        cbuf = (C.c_double * 2)(*carry)
    lib().fwt_svpwm(
        vdc,
        v_alpha,
        v_beta,
        tmin_us,
        on_us,
        off_us,
        n_per_state,
        int(stretch),
        parity,
        cbuf,
        out,
        va,
    )
    if carry is not None and cbuf is not None:
        carry[0], carry[1] = cbuf[0], cbuf[1]
    wins = tuple(
        Window(bool(out[26 + 6 * w]), *(int(out[26 + 6 * w + k]) for k in range(1, 6)))
        for w in range(3)
    )
    return Plan(
        cmp_up=(out[0], out[1], out[2]),
        cmp_dn=(out[3], out[4], out[5]),
        soc=tuple(out[7 + k] for k in range(out[6])),
        layout=out[23],
        sector=out[24],
        clipped=bool(out[25]),
        windows=wins,  # type: ignore[arg-type]
        t_odd=out[44],
        t_even=out[45],
        vec_odd=out[46],
        vec_even=out[47],
        v_applied=(va[0], va[1]),
    )


def svpwm_vmax(vdc: float, tmin_us: float) -> float:
    return float(lib().fwt_svpwm_vmax(vdc, tmin_us))


def slope_window(
    ticks: list[int], ia: list[int], ib: list[int], bits: int, range_a: float
) -> tuple[complex, float, complex] | None:
    out = dbuf(5)
    ok = lib().fwt_slope_window(len(ticks), ibuf(ticks), ibuf(ia), ibuf(ib), bits, range_a, out)
    if not ok:
        return None
    return complex(out[0], out[1]), out[2], complex(out[3], out[4])


def slope_diff(
    s_act: complex, t_act: float, s_zero: complex, t_zero: float, omega: float
) -> complex:
    out = dbuf(2)
    lib().fwt_slope_diff(
        s_act.real, s_act.imag, t_act, s_zero.real, s_zero.imag, t_zero, omega, out
    )
    return complex(out[0], out[1])


@dataclass(frozen=True)
class Estimate:
    ok: bool
    theta_raw: float
    gamma0: float
    gamma1: float
    g: complex
    residual: float
    t_ref: float
    n_active: int

    @property
    def ld(self) -> float:
        return 1.0 / (self.gamma0 + self.gamma1)

    @property
    def lq(self) -> float:
        return 1.0 / (self.gamma0 - self.gamma1)


def est_solve(
    vecs: list[int],
    di: list[complex],
    t: list[float],
    kv: float,
    omega: float = 0.0,
    gamma0_prior: float = 0.0,
) -> Estimate:
    n = len(vecs)
    dbl = dbuf(4)
    for k, d in enumerate(di):
        dbl[2 * k] = d.real
        dbl[2 * k + 1] = d.imag
    tb = dbuf(2)
    for k, tk in enumerate(t):
        tb[k] = tk
    out = dbuf(8)
    ok = lib().fwt_slope_solve(n, ibuf([*vecs, 1, 1][:2]), dbl, tb, kv, omega, gamma0_prior, out)
    return Estimate(
        bool(ok), out[0], out[1], out[2], complex(out[3], out[4]), out[5], out[6], int(out[7])
    )


def wrap_pi(x: float | np.ndarray) -> float | np.ndarray:
    """to (-pi, pi]"""
    return -((math.pi - x) % (2 * math.pi)) + math.pi


def diff_mod_pi(a: float | np.ndarray, b: float | np.ndarray) -> float | np.ndarray:
    """a - b modulo pi, in (-pi/2, pi/2]"""
    return 0.5 * wrap_pi(2.0 * (np.asarray(a) - np.asarray(b)))


class Core:
    """One control core instance in a ctypes buffer."""

    def __init__(self) -> None:
        self.buf = C.create_string_buffer(int(lib().fwt_core_size()))
        self.ptr = C.cast(self.buf, C.c_void_p)
        lib().fw_core_init(self.ptr)

    def command(
        self,
        enable: int,
        fault_reset: int = 0,
        ctrl_mode: int = 0,
        fw_mode: int = 0,
        speed_ref_rpm: float = 0.0,
        iq_ref: float = 0.0,
    ) -> int:
        return int(
            lib().fwt_command(
                self.ptr, enable, fault_reset, ctrl_mode, fw_mode, speed_ref_rpm, iq_ref
            )
        )

    def param_set(self, pid: int, value: float) -> int:
        return int(lib().fwt_param_set(self.ptr, pid, value))

    def param_get(self, pid: int) -> tuple[int, float]:
        v = C.c_double()
        st = lib().fwt_param_get(self.ptr, pid, C.byref(v))
        return int(st), float(v.value)

    def status(self) -> dict[str, float]:
        """``fw_core_status()``: every field of ``fw_status_t`` by its name."""
        st = status_type()()
        lib().fwt_status(self.ptr, C.byref(st))
        return {n: getattr(st, n) for n in status_fields()}

    def isr(
        self, period: int | None, ia: list[int], ib: list[int], vdc_code: int
    ) -> dict[str, object]:
        out = ibuf(25)
        n = len(ia)
        lib().fwt_isr(
            self.ptr,
            int(period is None),
            period or 0,
            n,
            ibuf(ia or [0]),
            ibuf(ib or [0]),
            vdc_code,
            out,
        )
        return {
            "period": out[0] & 0xFFFFFFFF,
            "cmp_up": [out[1], out[2], out[3]],
            "cmp_dn": [out[4], out[5], out[6]],
            "soc": [out[8 + k] for k in range(out[7])],
            "gate": out[24],
        }


def param_table() -> list[dict[str, object]]:
    rows: list[dict[str, object]] = []
    for k in range(lib().fw_param_count()):
        p = lib().fw_param_info_at(k).contents
        rows.append(
            {
                "id": int(p.id),
                "name": p.name.decode(),
                "unit": p.unit.decode(),
                "min": float(p.min),
                "max": float(p.max),
                "default": float(p.default),
                "read_only": bool(p.read_only),
            }
        )
    return rows
