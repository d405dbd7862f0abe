"""The plant's profile schema, asked of the plant itself: a scenario's ``[overrides]`` are
checked by plant_rt's own loader (``libplant_core.so``: ``plant_config_load``, ``_set``,
``_check``), so the field names, ranges and cross-field rules have one source, in C, and the
rig finds a bad override at load time instead of as a crash of the started program.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Mapping
from pathlib import Path

from rig import _paths

_ERR_LEN = 512


@functools.cache
def _lib() -> ctypes.CDLL:
    lib = ctypes.CDLL(str(_paths.library("libplant_core.so")))
    lib.plant_config_size.restype = ctypes.c_size_t
    for name in ("plant_config_load", "plant_config_set"):
        fn = getattr(lib, name)
        fn.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_size_t]
        fn.restype = ctypes.c_int
    lib.plant_config_check.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t]
    lib.plant_config_check.restype = ctypes.c_int
    lib.plant_config_defaults.argtypes = [ctypes.c_void_p]
    return lib


def available() -> bool:
    """True when the plant library is built (``./hil install``)."""
    try:
        _lib()
    except (FileNotFoundError, OSError):
        return False
    return True


def _format(value: object) -> str:
    return repr(value) if isinstance(value, float) else str(value)


def check(profile: Path, overrides: Mapping[str, object]) -> dict[str, str]:
    """Problems of ``overrides`` on ``profile``: {override key (or "" for the profile
    itself): message}. Per-field problems first; the cross-field check (names the field it
    is about) only when every override is acceptable on its own."""
    lib = _lib()
    cfg = ctypes.create_string_buffer(lib.plant_config_size())
    err = ctypes.create_string_buffer(_ERR_LEN)
    if lib.plant_config_load(cfg, str(profile).encode(), err, _ERR_LEN) != 0:
        return {"": err.value.decode(errors="replace")}
    problems: dict[str, str] = {}
    for key, value in overrides.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            problems[key] = f"must be a number, not {value!r}"
            continue
        assignment = f"{key}={_format(value)}".encode()
        if lib.plant_config_set(cfg, assignment, err, _ERR_LEN) != 0:
            msg = err.value.decode(errors="replace")
            # "--set k=v: section.key: why" -> "why"
            problems[key] = msg.split(f"{key}: ", 1)[-1] if f"{key}: " in msg else msg
    if problems:
        return problems
    if lib.plant_config_check(cfg, err, _ERR_LEN) != 0:
        msg = err.value.decode(errors="replace")
        field, _, why = msg.partition(": ")
        if field in overrides:
            return {field: why}
        named = [k for k in overrides if k in msg]
        return {(named[0] if named else ""): msg}
    return {}
