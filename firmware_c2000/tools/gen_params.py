#!/usr/bin/env python3
"""Generate the control core's parameter table from protocols/parameters.csv.

The CSV is the single source of truth (columns: id, name, unit, min, max, default, access,
description). This script writes two files into the build directory (never committed):

* ``fw_params_gen.h``: ``FW_PARAM_COUNT``, one index macro ``FW_IDX_<NAME>`` (position in the
  core's value array) and one id macro ``FW_PID_<NAME>`` (wire id) per parameter;
* ``fw_params_gen.c``: the constant metadata table the core range-checks every set against.

Usage: gen_params.py CSV OUT_DIR
"""

from __future__ import annotations

import csv
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from c_codegen import banner, c_string, generate

COLUMNS = ["id", "name", "unit", "min", "max", "default", "access", "description"]
NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
MAX_PARAMS = 128  # FW_PARAM_MAX in fw_core_state.h
CONFIG_ID_LIMIT = 100  # ids below this are configuration: writable only while not enabled


@dataclass(frozen=True)
class Param:
    pid: int
    name: str
    unit: str
    lo: float
    hi: float
    default: float
    read_only: bool
    description: str


class CsvError(ValueError):
    pass


def parse(path: Path) -> list[Param]:
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames != COLUMNS:
            raise CsvError(f"{path}: header must be {','.join(COLUMNS)}")
        params: list[Param] = []
        for line, row in enumerate(reader, start=2):
            try:
                p = Param(
                    pid=int(row["id"]),
                    name=row["name"].strip(),
                    unit=row["unit"].strip(),
                    lo=float(row["min"]),
                    hi=float(row["max"]),
                    default=float(row["default"]),
                    read_only=row["access"].strip() == "ro",
                    description=row["description"].strip(),
                )
            except (TypeError, ValueError) as exc:
                raise CsvError(f"{path}:{line}: {exc}") from exc
            if row["access"].strip() not in ("rw", "ro"):
                raise CsvError(f"{path}:{line}: access must be rw or ro")
            if not NAME_RE.match(p.name):
                raise CsvError(f"{path}:{line}: name {p.name!r} is not a lower-case C identifier")
            if not 0 < p.pid < 65536:
                raise CsvError(f"{path}:{line}: id out of 1..65535")
            if not all(math.isfinite(v) for v in (p.lo, p.hi, p.default)):
                raise CsvError(f"{path}:{line}: non-finite number")
            if not p.lo <= p.default <= p.hi:
                raise CsvError(f"{path}:{line}: default outside [min, max]")
            params.append(p)
    ids = [p.pid for p in params]
    names = [p.name for p in params]
    if len(set(ids)) != len(ids):
        raise CsvError(f"{path}: duplicate id")
    if len(set(names)) != len(names):
        raise CsvError(f"{path}: duplicate name")
    if ids != sorted(ids):
        raise CsvError(f"{path}: ids must be in ascending order (the core bisects them)")
    if len(params) > MAX_PARAMS:
        raise CsvError(f"{path}: more than {MAX_PARAMS} parameters")
    return params


def c_float(v: float) -> str:
    text = repr(float(v))
    if "e" not in text and "." not in text:
        text += ".0"
    return f"(real_t){text}"


def header(params: list[Param]) -> str:
    out = [
        *banner("gen_params.py", "protocols/parameters.csv"),
        "#ifndef FW_PARAMS_GEN_H",
        "#define FW_PARAMS_GEN_H",
        "",
        f"#define FW_PARAM_COUNT {len(params)}",
        f"#define FW_PARAM_CONFIG_ID_LIMIT {CONFIG_ID_LIMIT}",
        "",
    ]
    for i, p in enumerate(params):
        up = p.name.upper()
        out.append(f"#define FW_IDX_{up} {i}")
        out.append(f"#define FW_PID_{up} {p.pid}u")
    out += ["", "#endif", ""]
    return "\n".join(out)


def source(params: list[Param]) -> str:
    out = [
        *banner("gen_params.py", "protocols/parameters.csv"),
        '#include "fw_core.h"',
        '#include "fw_params_gen.h"',
        "",
        "const fw_param_info_t fw_param_table[FW_PARAM_COUNT] = {",
    ]
    for p in params:
        out.append(
            f"    {{{p.pid}u, {c_string(p.name)}, {c_string(p.unit)}, {c_float(p.lo)}, "
            f"{c_float(p.hi)}, {c_float(p.default)}, {1 if p.read_only else 0}}},"
        )
    out += ["};", ""]
    return "\n".join(out)


def main(argv: list[str]) -> int:
    return generate(argv, __doc__ or "", parse,
                    {"fw_params_gen.h": header, "fw_params_gen.c": source})


if __name__ == "__main__":
    sys.exit(main(sys.argv))
