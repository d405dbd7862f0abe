"""Cross-language check: random values are encoded by cantools (Python) and decoded by the
cantools-generated C code, and the C encoder must produce the same bytes.

Run by ctest with the path of the protocol_vectors program and the DBC files.
"""

from __future__ import annotations

import random
import subprocess
import sys

import cantools
from cantools.database.can import Message, Signal

VECTORS_PER_MESSAGE = 200


def random_value(sig: Signal, rng: random.Random, between: bool = False) -> float | int:
    """A physical value inside the DBC range that the signal represents exactly, or with
    `between` one up to 0.45 raw steps off such a value (inside the range): the C encoder must
    round it to the nearest raw value as the Python encoder does, not truncate it."""
    lo = sig.minimum if sig.minimum is not None else 0
    hi = sig.maximum if sig.maximum is not None else 1
    if sig.is_float:
        return rng.uniform(max(lo, -1e6), min(hi, 1e6))
    scale, offset = float(sig.scale), float(sig.offset)
    raw_lo = int(-(2 ** (sig.length - 1))) if sig.is_signed else 0
    raw_hi = int(2 ** (sig.length - 1) - 1) if sig.is_signed else int(2**sig.length - 1)
    raw_lo = max(raw_lo, int((lo - offset) / scale + 0.999999))
    raw_hi = min(raw_hi, int((hi - offset) / scale + 1e-9))
    raw = rng.randint(raw_lo, raw_hi)
    if between:
        off = rng.uniform(0.05, 0.45) * rng.choice((-1.0, 1.0))
        if raw == raw_lo:
            off = abs(off)
        elif raw == raw_hi:
            off = -abs(off)
        return (raw + off) * scale + offset
    if scale == 1 and offset == 0:
        return raw
    return raw * scale + offset


def check_message(tool: subprocess.Popen[str], msg: Message, rng: random.Random) -> int:
    failures = 0
    for _ in range(VECTORS_PER_MESSAGE):
        values = {s.name: random_value(s, rng) for s in msg.signals}
        data = msg.encode(values, strict=True)
        assert tool.stdin is not None and tool.stdout is not None
        tool.stdin.write(f"decode 0x{msg.frame_id:x} {data.hex()}\n")
        tool.stdin.flush()
        reply = tool.stdout.readline().split()
        if not reply or reply[0] != msg.name:
            print(f"{msg.name}: C decode failed: {reply}")
            return failures + 1
        c_values = dict(kv.split("=", 1) for kv in reply[1:])
        py_values = msg.decode(data, decode_choices=False)
        assert isinstance(py_values, dict)
        for sig in msg.signals:
            c = float(c_values[sig.name])
            p = float(py_values[sig.name])
            tol = 1e-6 * max(1.0, abs(p)) if sig.is_float else 1e-9 * max(1.0, abs(p))
            if abs(c - p) > tol:
                print(f"{msg.name}.{sig.name}: C decoded {c}, Python {p}")
                failures += 1
        failures += check_encode(tool, msg, py_values, data.hex())
        between = {s.name: random_value(s, rng, between=True) for s in msg.signals}
        failures += check_encode(tool, msg, between, msg.encode(between, strict=True).hex())
    return failures


def check_encode(tool: subprocess.Popen[str], msg: Message, values: dict[str, float | int],
                 want: str) -> int:
    """The C encoder's bytes for `values` against the Python encoder's `want`."""
    assert tool.stdin is not None and tool.stdout is not None
    kv = " ".join(f"{s.name}={values[s.name]!r}" for s in msg.signals)
    tool.stdin.write(f"encode 0x{msg.frame_id:x} {kv}\n")
    tool.stdin.flush()
    c_bytes = tool.stdout.readline().strip()
    if c_bytes != want:
        print(f"{msg.name}: C encoded {c_bytes}, Python {want} ({kv})")
        return 1
    return 0


def main() -> int:
    tool_path, *dbc_paths = sys.argv[1:]
    rng = random.Random(20220418)
    tool = subprocess.Popen([tool_path], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    failures = checked = 0
    for path in dbc_paths:
        db = cantools.database.load_file(path)
        for msg in db.messages:
            failures += check_message(tool, msg, rng)
            checked += 1
    assert tool.stdin is not None
    tool.stdin.close()
    tool.wait(timeout=10)
    print(f"{checked} messages x {VECTORS_PER_MESSAGE} vectors: {failures} mismatches")
    return 1 if failures or checked == 0 or tool.returncode != 0 else 0


if __name__ == "__main__":
    sys.exit(main())
