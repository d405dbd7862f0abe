"""Writes the seed inputs of the fuzz harnesses into tests/fuzz/corpus/<harness>/ from the
sources of truth: frames encoded with the DBC files, console lines from
protocols/console.json, a parameter file from protocols/parameters.csv, the shipped
fidelity profiles. Run once when those change (the corpus is committed):

    .venv/bin/python tests/fuzz/make_seeds.py
"""

from __future__ import annotations

import csv
import json
import struct
import tomllib
from pathlib import Path

import cantools

ROOT = Path(__file__).resolve().parents[2]
PROTOCOLS = ROOT / "protocols"
OUT = Path(__file__).resolve().parent / "corpus"
UNIXCAN = tomllib.loads((PROTOCOLS / "unixcan.toml").read_text(encoding="utf-8"))
CANFD_FDF = UNIXCAN["fd_flags"]["fdf"]
FD_MAX_LEN = UNIXCAN["frame"]["fd_max_len"]


def record(frame_id: int, data: bytes, fd: bool) -> bytes:
    """One struct canfd_frame (72 bytes) as the programs receive it."""
    return struct.pack("<IBBBB", frame_id, len(data), CANFD_FDF if fd else 0, 0, 0) + \
        data.ljust(FD_MAX_LEN, b"\0")


def encode(db: cantools.database.can.Database, name: str, **values: float) -> bytes:
    m = db.get_message_by_name(name)
    full = {s.name: values.get(s.name, 0) for s in m.signals}
    return record(m.frame_id, m.encode(full, strict=False), bool(m.is_fd))


def frames() -> dict[str, bytes]:
    vio = cantools.database.load_file(PROTOCOLS / "vio.dbc")
    bench = cantools.database.load_file(PROTOCOLS / "bench.dbc")
    drive = cantools.database.load_file(PROTOCOLS / "drive.dbc")
    mid = {f"{c}_{k}": 32768 for c in ("ia", "ib") for k in range(16)}
    adc = b"".join(
        encode(vio, f"VIO_ADC_{i}", period=p, n_soc=16, vdc_code=32768,
               **{k: v for k, v in mid.items() if int(k.split("_")[1]) in range(7 * i, 7 * i + 7)})
        for p in range(4) for i in range(3))
    return {
        "adc_sequence": adc,
        "pwm": encode(vio, "VIO_PWM", period=1, cmp_a_up=2500, cmp_a_dn=2500, cmp_b_up=2500,
                      cmp_b_dn=2500, cmp_c_up=2500, cmp_c_dn=2500, n_soc=2, gate_enable=1,
                      soc_0=100, soc_1=9000),
        "drive": encode(drive, "DRIVE_CMD", enable=1, alive=1, speed_ref=1000.0)
        + encode(drive, "DRIVE_LIMITS", i_max=3.0, speed_max=3000.0, accel=1000.0)
        + encode(drive, "PARAM_REQ", op=1, id=1, value=2.0, seq=1),
        "bench": encode(bench, "BENCH_STEP", run_until=10, seq=1)
        + encode(bench, "LOAD_CMD", mode=1, torque=1.0),
    }


def datagrams() -> dict[str, bytes]:
    """Length-prefixed datagrams: the frames above, and sizes that are no frame."""
    out = {}
    for name, recs in frames().items():
        out[name] = b"".join(bytes([72]) + recs[i:i + 72] for i in range(0, len(recs), 72))
    out["sizes"] = b"".join(bytes([n]) + bytes(n) for n in (0, 1, 15, 16, 17, 71, 72, 73, 100))
    return out


def console() -> dict[str, bytes]:
    spec = json.loads((PROTOCOLS / "console.json").read_text())
    examples = {"param": "rs_ohm", "number": "1.5", "choice": None}
    out = {}
    for c in spec["commands"]:
        words = [c["name"]]
        for a in c["args"]:
            words.append(a["choices"][0] if a["type"] == "choice" else examples[a["type"]])
        out[c["name"]] = (" ".join(words) + "\r\n").encode()
    return out


def param_file() -> dict[str, bytes]:
    with (PROTOCOLS / "parameters.csv").open(newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["access"] == "rw"]
    text = "".join(f"{r['name']} = {r['default']}  # {r['unit']}\n" for r in rows)
    return {"defaults": text.encode(), "one": b"rs_ohm = 1.93\n"}


def profile() -> dict[str, bytes]:
    return {p.stem: p.read_bytes() for p in (ROOT / "plant_rt" / "profiles").glob("*.toml")}


def main() -> None:
    for harness, seeds in (("frames", frames()), ("datagrams", datagrams()),
                           ("console", console()),
                           ("param_file", param_file()), ("profile", profile())):
        folder = OUT / harness
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in seeds.items():
            (folder / f"seed-{name}").write_bytes(data)


if __name__ == "__main__":
    main()
