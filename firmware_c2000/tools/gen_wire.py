#!/usr/bin/env python3
"""Generate the C programs' wire facts from the DBC files in protocols/.

The DBC files are the single source of the PWM time base, the speed-loop divider, the value
tables (drive states, fault codes, modes, parameter-access status) and the FW_TRACE signals.
This script writes them for C into the build directory (never committed), and refuses a DBC
whose facts disagree with each other (the build stops with the reason):

* ``core OUT_DIR PROTOCOLS_DIR``: ``fw_wire_gen.h`` for the control core (no frame code, no
  8-bit types): ``FW_TBPRD``, ``FW_PERIOD_TICKS``, ``FW_TBCLK_HZ``, ``FW_TS``,
  ``FW_SPEED_DIVIDER``, ``FW_MAX_SOC`` and ``FW_STATE_*``, ``FW_FAULT_*``, ``FW_CTRL_*``,
  ``FW_FWMODE_*``, ``FW_STATUS_*`` (CORE_TABLES below);
* ``host OUT_DIR PROTOCOLS_DIR``: ``hil_wire.h`` / ``hil_wire.c`` for the programs on the bus
  (plant_rt, fw_host, the in-process bench): ``HIL_TBCLK_HZ``, ``HIL_TBPRD``,
  ``HIL_PERIOD_TICKS``, ``HIL_PERIOD_NS``, ``HIL_SPEED_LOOP_DIVIDER``, ``HIL_MAX_SOC``; per
  database its CAN ID range (database attributes ``HilIdFirst``, ``HilIdLast``):
  ``HIL_<DB>_ID_FIRST``, ``HIL_<DB>_ID_LAST``, ``hil_<db>_id_in_range(id)`` and the receive
  filter blocks ``hil_<db>_id_blocks[HIL_<DB>_ID_BLOCKS]`` (``(id & mask) == id`` blocks
  that make up the range exactly); and, for every value table,
  ``const char *hil_<db>_<message>_<signal>_name(long value)`` (NULL for a value the table
  does not name);
* ``arrays OUT_DIR PROTOCOLS_DIR``: ``hil_arrays.h`` / ``hil_arrays.c``: the signals a DBC
  spells as one array, ``<name>_<k>`` for consecutive k (``VIO_ADC_0.ia_0`` .. ``ia_6``,
  ``VIO_PWM.soc_0`` .. ``soc_15``), read and written by index:
  ``hil_<db>_<message>_<name>_get(const struct *m, int j)`` and ``_set(struct *m, int j, v)``
  for element j = signal ``<name>_<FIRST + j>``, with ``HIL_<DB>_<MESSAGE>_<NAME>_FIRST`` and
  ``_COUNT``;
* ``trace OUT_DIR PROTOCOLS_DIR``: ``fw_trace_gen.h`` / ``fw_trace_gen.c``:
  ``fwh_trace_from_status()``, FW_TRACE (vio.dbc) filled from ``fw_status_t``, every signal
  from the status field of the same name (a signal without such a field does not compile).
  Float signals are assigned; integer signals (scale 1, offset 0) are saturated into their
  DBC range.

Usage: gen_wire.py core|host|arrays|trace OUT_DIR PROTOCOLS_DIR
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path

import cantools
from c_codegen import banner, write_if_changed
from cantools.database.can import Database, Message, Signal
from cantools.database.can.c_source import CodeGenSignal, camel_to_snake_case

DATABASES = ("drive", "vio", "bench")
IDENT = re.compile(r"^[A-Z][A-Z0-9_]*$")
ELEMENT = re.compile(r"^(?P<name>[A-Za-z][A-Za-z0-9_]*?)_(?P<k>[0-9]+)$")

# (database, message, signal, C prefix): the value tables the control core uses.
CORE_TABLES = (
    ("drive", "DRIVE_STATUS", "state", "FW_STATE_"),
    ("drive", "DRIVE_STATUS", "fault_code", "FW_FAULT_"),
    ("drive", "DRIVE_CMD", "ctrl_mode", "FW_CTRL_"),
    ("drive", "DRIVE_CMD", "fw_mode", "FW_FWMODE_"),
    ("drive", "PARAM_RESP", "status", "FW_STATUS_"),
)
# Signals that carry the values of another signal's table: their ranges must hold it.
SAME_VALUES = (
    (("vio", "FW_TRACE", "state"), ("drive", "DRIVE_STATUS", "state")),
    (("drive", "DRIVE_STATUS", "ctrl_mode"), ("drive", "DRIVE_CMD", "ctrl_mode")),
    (("drive", "DRIVE_STATUS", "fw_mode"), ("drive", "DRIVE_CMD", "fw_mode")),
)
TELEMETRY = ("TLM_POS", "TLM_CUR", "TLM_REF", "TLM_PARAM", "TLM_VOLT")


class WireError(ValueError):
    pass


@dataclass(frozen=True)
class TimeBase:
    tbclk_hz: int  # ticks per second
    tbprd: int  # half a PWM period (up-down count), ticks
    speed_loop_divider: int  # PWM periods per speed-loop period

    @property
    def period_ticks(self) -> int:
        return 2 * self.tbprd

    @property
    def period_ns(self) -> int:
        return self.period_ticks * 1_000_000_000 // self.tbclk_hz


def load(protocols: Path) -> dict[str, Database]:
    dbs: dict[str, Database] = {}
    for name in DATABASES:
        db = cantools.database.load_file(str(protocols / f"{name}.dbc"), strict=True)
        assert isinstance(db, Database)
        dbs[name] = db
    return dbs


def signal(dbs: dict[str, Database], db: str, message: str, name: str) -> Signal:
    try:
        return dbs[db].get_message_by_name(message).get_signal_by_name(name)
    except KeyError as exc:
        raise WireError(f"{db}.dbc: no signal {message}.{name}") from exc


def attribute(db: Database, file: str, name: str) -> int:
    attrs = db.dbc.attributes if db.dbc is not None else {}
    if name not in attrs:
        raise WireError(f"{file}: database attribute {name} missing (BA_ \"{name}\" ...)")
    value = attrs[name].value
    if not isinstance(value, int) or value < 1:
        raise WireError(f"{file}: {name} = {value!r}: a positive integer")
    return value


SFF_MASK = 0x7FF  # 11-bit identifiers


@dataclass(frozen=True)
class IdRange:
    """The CAN IDs a database owns, first..last (11-bit, both included)."""

    db: str
    first: int
    last: int

    def blocks(self) -> list[tuple[int, int]]:
        """(id, mask) pairs, each matching the ids with ``(x & mask) == id``, that together
        match exactly first..last (largest aligned power-of-two blocks, lowest first)."""
        out: list[tuple[int, int]] = []
        lo = self.first
        while lo <= self.last:
            size = lo & -lo if lo else SFF_MASK + 1
            while size > self.last - lo + 1:
                size //= 2
            out.append((lo, SFF_MASK & ~(size - 1)))
            lo += size
        return out


def id_ranges(dbs: dict[str, Database]) -> list[IdRange]:
    """Every database's declared ID range, checked: 11-bit, holding all its messages (standard
    frames), no two overlapping."""
    ranges: list[IdRange] = []
    for db in DATABASES:
        attrs = dbs[db].dbc.attributes if dbs[db].dbc is not None else {}
        ends = []
        for name in ("HilIdFirst", "HilIdLast"):
            if name not in attrs:
                raise WireError(f"{db}.dbc: database attribute {name} missing (BA_ \"{name}\" ...)")
            value = attrs[name].value
            if not isinstance(value, int) or not 0 <= value <= SFF_MASK:
                raise WireError(f"{db}.dbc: {name} = {value!r}: an 11-bit CAN ID")
            ends.append(value)
        r = IdRange(db, ends[0], ends[1])
        if r.first > r.last:
            raise WireError(f"{db}.dbc: HilIdFirst 0x{r.first:X} after HilIdLast 0x{r.last:X}")
        for message in dbs[db].messages:
            if message.is_extended_frame or not r.first <= message.frame_id <= r.last:
                raise WireError(f"{db}.dbc: {message.name} (0x{message.frame_id:X}) outside "
                                f"the database's ID range 0x{r.first:X}..0x{r.last:X}")
        for other in ranges:
            if r.first <= other.last and other.first <= r.last:
                raise WireError(f"{db}.dbc: ID range 0x{r.first:X}..0x{r.last:X} overlaps "
                                f"{other.db}.dbc's 0x{other.first:X}..0x{other.last:X}")
        ranges.append(r)
    return ranges


def timebase(dbs: dict[str, Database]) -> TimeBase:
    """The time base, checked against the ranges and cycle times that follow from it."""
    tb = TimeBase(attribute(dbs["vio"], "vio.dbc", "HilTbclkHz"),
                  attribute(dbs["vio"], "vio.dbc", "HilTbprd"),
                  attribute(dbs["drive"], "drive.dbc", "HilSpeedLoopDivider"))
    if tb.period_ticks * 1_000_000_000 % tb.tbclk_hz:
        raise WireError("vio.dbc: a PWM period of 2*HilTbprd ticks is no whole number of ns")
    pwm = dbs["vio"].get_message_by_name("VIO_PWM")
    for sig in pwm.signals:
        want = (tb.tbprd if sig.name.startswith("cmp_")
                else tb.period_ticks - 1 if sig.name.startswith("soc_") else None)
        if want is not None and (sig.minimum != 0 or sig.maximum != want):
            raise WireError(f"vio.dbc: VIO_PWM.{sig.name} range [{sig.minimum}|{sig.maximum}], "
                            f"the time base (HilTbprd {tb.tbprd}) says [0|{want}]")
    for name in TELEMETRY:
        cycle = dbs["drive"].get_message_by_name(name).cycle_time
        # cycle ms = divider * period ticks / tbclk  <=>  cycle * tbclk = 1000 * divider * ticks
        if cycle is None or cycle * tb.tbclk_hz != 1000 * tb.speed_loop_divider * tb.period_ticks:
            raise WireError(f"drive.dbc: {name} GenMsgCycleTime {cycle} ms is not "
                            f"HilSpeedLoopDivider ({tb.speed_loop_divider}) PWM periods")
    return tb


def max_soc(dbs: dict[str, Database]) -> int:
    """SOCs per period: VIO_PWM.n_soc's maximum, one soc_<k> signal each."""
    pwm = dbs["vio"].get_message_by_name("VIO_PWM")
    n = pwm.get_signal_by_name("n_soc").maximum
    socs = [s.name for s in pwm.signals if s.name.startswith("soc_")]
    if n is None or socs != [f"soc_{k}" for k in range(int(n))]:
        raise WireError(f"vio.dbc: VIO_PWM has {len(socs)} soc_<k> signals for n_soc up to {n}")
    return int(n)


def table(dbs: dict[str, Database], db: str, message: str, name: str) -> list[tuple[int, str]]:
    sig = signal(dbs, db, message, name)
    if not sig.choices:
        raise WireError(f"{db}.dbc: {message}.{name} has no value table (VAL_)")
    rows = sorted((int(v), str(n)) for v, n in sig.choices.items())
    for value, label in rows:
        if not IDENT.match(label):
            raise WireError(f"{db}.dbc: {message}.{name} value {value}: name {label!r} is not "
                            "an upper-case C identifier")
    return rows


def check_same_values(dbs: dict[str, Database]) -> None:
    for (db, message, name), source in SAME_VALUES:
        sig = signal(dbs, db, message, name)
        values = [v for v, _ in table(dbs, *source)]
        lo = sig.minimum if sig.minimum is not None else 0
        hi = sig.maximum if sig.maximum is not None else 2**sig.length - 1
        if not lo <= min(values) <= max(values) <= hi:
            raise WireError(f"{db}.dbc: {message}.{name} range [{lo}|{hi}] does not hold the "
                            f"values of {source[1]}.{source[2]} ({min(values)}..{max(values)})")


def c_float(v: float, suffix: str) -> str:
    text = repr(float(v))
    if "e" not in text and "." not in text:
        text += ".0"
    return text + suffix


def core_header(dbs: dict[str, Database]) -> str:
    tb = timebase(dbs)
    check_same_values(dbs)
    out = [*banner("gen_wire.py", "protocols/drive.dbc and vio.dbc"),
           "#ifndef FW_WIRE_GEN_H", "#define FW_WIRE_GEN_H", "",
           "/* PWM time base (vio.dbc HilTbclkHz, HilTbprd; drive.dbc HilSpeedLoopDivider) */",
           f"#define FW_TBPRD {tb.tbprd}u /* up-down count half period, ticks */",
           f"#define FW_PERIOD_TICKS {tb.period_ticks}u /* one PWM period, ticks */",
           f"#define FW_TBCLK_HZ {c_float(tb.tbclk_hz, 'f')} /* ticks per second */",
           f"#define FW_TS {c_float(tb.period_ticks / tb.tbclk_hz, 'f')} /* PWM period, s */",
           f"#define FW_SPEED_DIVIDER {tb.speed_loop_divider} /* speed loop every N-th ISR */",
           f"#define FW_MAX_SOC {max_soc(dbs)} /* ADC conversions per period (VIO_PWM.n_soc) */"]
    for db, message, name, prefix in CORE_TABLES:
        rows = table(dbs, db, message, name)
        out += ["", f"/* {message}.{name} ({db}.dbc) */"]
        out += [f"#define {prefix}{label} {value}" for value, label in rows]
        out.append(f"#define {prefix}WIRE_MAX {rows[-1][0]} /* the table's largest value */")
    out += ["", "#endif", ""]
    return "\n".join(out)


def fn_name(db: str, message: Message, sig: Signal) -> str:
    return f"hil_{db}_{camel_to_snake_case(message.name)}_{camel_to_snake_case(sig.name)}_name"


def host_files(dbs: dict[str, Database]) -> tuple[str, str]:
    tb = timebase(dbs)
    check_same_values(dbs)
    src = "protocols/drive.dbc, vio.dbc and bench.dbc"
    h = [*banner("gen_wire.py", src), "#ifndef HIL_WIRE_H", "#define HIL_WIRE_H", "",
         "#include <stdint.h>", "",
         "/* PWM time base (vio.dbc HilTbclkHz, HilTbprd; drive.dbc HilSpeedLoopDivider) */",
         f"#define HIL_TBCLK_HZ {c_float(tb.tbclk_hz, '')} /* ticks per second */",
         f"#define HIL_TBPRD {tb.tbprd} /* up-down count half period, ticks */",
         f"#define HIL_PERIOD_TICKS {tb.period_ticks} /* one PWM period, ticks */",
         f"#define HIL_PERIOD_NS {tb.period_ns}LL /* one PWM period, ns */",
         f"#define HIL_SPEED_LOOP_DIVIDER {tb.speed_loop_divider} /* PWM periods per speed-loop "
         "period */",
         f"#define HIL_MAX_SOC {max_soc(dbs)} /* ADC conversions per period (VIO_PWM.n_soc) */", "",
         "/* CAN ID ranges (database attributes HilIdFirst, HilIdLast): the 11-bit ids a",
         " * database owns. A receive filter matches (id & mask) == id for one of the blocks. */",
         "typedef struct {", "    uint32_t id, mask;", "} hil_id_block_t;"]
    c = [*banner("gen_wire.py", src), '#include "hil_wire.h"', "", "#include <stddef.h>"]
    for r in id_ranges(dbs):
        up, blocks = r.db.upper(), r.blocks()
        h += ["", f"#define HIL_{up}_ID_FIRST 0x{r.first:03X}u /* {r.db}.dbc */",
              f"#define HIL_{up}_ID_LAST 0x{r.last:03X}u",
              f"#define HIL_{up}_ID_BLOCKS {len(blocks)}",
              f"extern const hil_id_block_t hil_{r.db}_id_blocks[HIL_{up}_ID_BLOCKS];",
              f"static inline int hil_{r.db}_id_in_range(uint32_t id)", "{",
              f"    return id - HIL_{up}_ID_FIRST <= HIL_{up}_ID_LAST - HIL_{up}_ID_FIRST;", "}"]
        c += ["", f"const hil_id_block_t hil_{r.db}_id_blocks[HIL_{up}_ID_BLOCKS] = {{"]
        c += [f"    {{0x{i:03X}u, 0x{m:03X}u}}," for i, m in blocks]
        c.append("};")
    h += ["", "/* The name a value table gives a value, NULL when it names none. */"]
    for db in DATABASES:
        for message in dbs[db].messages:
            for sig in message.signals:
                if not sig.choices:
                    continue
                fn = fn_name(db, message, sig)
                h.append(f"const char *{fn}(long value);")
                c += ["", f"const char *{fn}(long value)", "{", "    switch (value) {"]
                c += [f'    case {int(v)}: return "{n}";' for v, n in sorted(
                    (int(v), str(n)) for v, n in sig.choices.items())]
                c += ["    default: return NULL;", "    }", "}"]
    h += ["", "#endif", ""]
    c.append("")
    return "\n".join(h), "\n".join(c)


@dataclass(frozen=True)
class SignalArray:
    """Signals ``<name>_<first>`` .. ``<name>_<first + count - 1>`` of one message, one C type."""

    db: str
    message: Message
    name: str
    first: int
    signals: tuple[Signal, ...]

    @property
    def c_type(self) -> str:
        return CodeGenSignal(self.signals[0]).type_name

    @property
    def prefix(self) -> str:
        return f"hil_{self.db}_{camel_to_snake_case(self.message.name)}_{self.name}"


def signal_arrays(dbs: dict[str, Database]) -> list[SignalArray]:
    """Every run of two or more signals ``<name>_<k>``, k consecutive, of one C type."""
    out: list[SignalArray] = []
    for db in DATABASES:
        for message in dbs[db].messages:
            groups: dict[str, list[tuple[int, Signal]]] = {}
            for sig in message.signals:
                m = ELEMENT.match(sig.name)
                if m is not None:
                    groups.setdefault(m["name"], []).append((int(m["k"]), sig))
            for name, members in groups.items():
                members.sort(key=lambda x: x[0])
                ks = [k for k, _ in members]
                sigs = tuple(s for _, s in members)
                if len(members) < 2 or ks != list(range(ks[0], ks[0] + len(ks))):
                    continue
                if len({CodeGenSignal(s).type_name for s in sigs}) != 1:
                    raise WireError(f"{db}.dbc: {message.name}.{name}_<k> signals of different "
                                    "C types cannot be one array")
                out.append(SignalArray(db, message, camel_to_snake_case(name), ks[0], sigs))
    return out


def array_files(dbs: dict[str, Database]) -> tuple[str, str]:
    src = "protocols/drive.dbc, vio.dbc and bench.dbc"
    h = [*banner("gen_wire.py", src), "#ifndef HIL_ARRAYS_H", "#define HIL_ARRAYS_H", "",
         '#include "hil_bench.h"', '#include "hil_drive.h"', '#include "hil_vio.h"', "",
         "/* Signals <name>_<k> as arrays: element j is signal <name>_<FIRST + j>. get returns 0",
         " * and set does nothing for a j outside 0 .. COUNT-1. */"]
    c = [*banner("gen_wire.py", src), '#include "hil_arrays.h"']
    for a in signal_arrays(dbs):
        msg = f"struct hil_{a.db}_{camel_to_snake_case(a.message.name)}_t"
        up = a.prefix.upper()
        members = [camel_to_snake_case(s.name) for s in a.signals]
        first, last = a.signals[0].name, a.signals[-1].name
        h += ["", f"/* {a.message.name}.{first} .. {last} ({a.db}.dbc) */",
              f"#define {up}_FIRST {a.first}", f"#define {up}_COUNT {len(a.signals)}",
              f"{a.c_type} {a.prefix}_get(const {msg} *m, int j);",
              f"void {a.prefix}_set({msg} *m, int j, {a.c_type} value);"]
        c += ["", f"{a.c_type} {a.prefix}_get(const {msg} *m, int j)", "{", "    switch (j) {"]
        c += [f"    case {j}: return m->{n};" for j, n in enumerate(members)]
        c += ["    default: return 0;", "    }", "}",
              "", f"void {a.prefix}_set({msg} *m, int j, {a.c_type} value)", "{",
              "    switch (j) {"]
        c += [f"    case {j}: m->{n} = value; break;" for j, n in enumerate(members)]
        c += ["    default: break;", "    }", "}"]
    h += ["", "#endif", ""]
    c.append("")
    return "\n".join(h), "\n".join(c)


def trace_files(dbs: dict[str, Database]) -> tuple[str, str]:
    msg = dbs["vio"].get_message_by_name("FW_TRACE")
    m = f"hil_vio_{camel_to_snake_case(msg.name)}"
    h = [*banner("gen_wire.py", "protocols/vio.dbc (FW_TRACE)"),
         "#ifndef FW_TRACE_GEN_H", "#define FW_TRACE_GEN_H", "",
         '#include "fw_core.h"', '#include "hil_vio.h"', "",
         "/* FW_TRACE from the core's status: every signal from the fw_status_t field of the",
         " * same name; integer signals saturated into their DBC range. */",
         f"void fwh_trace_from_status(const fw_status_t *s, struct {m}_t *m);", "",
         "#endif", ""]
    c = [*banner("gen_wire.py", "protocols/vio.dbc (FW_TRACE)"), '#include "fw_trace_gen.h"', "",
         "static long long sat(long long v, long long lo, long long hi)", "{",
         "    return v < lo ? lo : v > hi ? hi : v;", "}", "",
         f"void fwh_trace_from_status(const fw_status_t *s, struct {m}_t *m)", "{"]
    for sig in msg.signals:
        name = camel_to_snake_case(sig.name)
        if sig.is_float:
            c.append(f"    m->{name} = s->{sig.name};")
            continue
        if sig.scale != 1 or sig.offset != 0:
            raise WireError(f"vio.dbc: FW_TRACE.{sig.name}: an integer signal of the trace "
                            "carries the status value itself (scale 1, offset 0)")
        lo = int(sig.minimum) if sig.minimum is not None else (
            -(2 ** (sig.length - 1)) if sig.is_signed else 0)
        hi = int(sig.maximum) if sig.maximum is not None else (
            2 ** (sig.length - 1) - 1 if sig.is_signed else 2**sig.length - 1)
        c.append(f"    m->{name} = {m}_{name}_encode((double)sat((long long)s->{sig.name}, "
                 f"{lo}LL, {hi}LL));")
    c += ["}", ""]
    return "\n".join(h), "\n".join(c)


def main(argv: list[str]) -> int:
    if len(argv) != 4 or argv[1] not in ("core", "host", "arrays", "trace"):
        print(__doc__, file=sys.stderr)
        return 2
    mode, out_dir, protocols = argv[1], Path(argv[2]), Path(argv[3])
    try:
        dbs = load(protocols)
        files: dict[str, str] = {}
        if mode == "core":
            files["fw_wire_gen.h"] = core_header(dbs)
        elif mode == "host":
            files["hil_wire.h"], files["hil_wire.c"] = host_files(dbs)
        elif mode == "arrays":
            files["hil_arrays.h"], files["hil_arrays.c"] = array_files(dbs)
        else:
            files["fw_trace_gen.h"], files["fw_trace_gen.c"] = trace_files(dbs)
    except WireError as exc:
        print(f"gen_wire: {exc}", file=sys.stderr)
        return 1
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        write_if_changed(out_dir / name, text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
