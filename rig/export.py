"""Measurement files from a run's full-rate data, in the formats tools of the field open.

- ``write_mf4``: the merged capture (``capture/``) as ASAM MDF 4.10 with asammdf: one channel
  group per traced message (``BENCH_TRUTH``, ``BENCH_TRUTH_MAG``, ``FW_TRACE``) and one for the
  columns the rig derives, each channel named as in the capture (``truth.theta_e``,
  ``fw.theta_hat``, ``pos_err_deg``, ...), its unit and comment from the DBC (cantools), the
  master channel the simulated time ``period * 100 µs``. Samples keep the capture's types, so
  the values are the capture's, bit for bit.
- ``write_can_log``: every frame of the traces (``plant.trace``, ``fw.trace``: each record a
  ``struct canfd_frame``) with python-can's writers, by the file's suffix: ``.blf`` (Vector
  BLF), ``.asc`` (Vector ASCII), ``.log`` (SocketCAN candump -L). Channel 0 holds the plant's
  trace, channel 1 the firmware's; a frame's time is the run's start (``started`` in
  result.json) plus its ``period`` signal times 100 µs (the frames of one period in trace
  order, the plant's first).

Both need the run's full-rate data: kept by a run that did not pass, or by every run with
``rig run --keep-all``. A run without it raises ``ExportError`` with what to do.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np
from cantools.database.can import Message

from rig import capture, protocols
from rig.trace import CAN_EFF_FLAG, CANFD_FDF, MessageDecoder, TraceFile, frame_ids

CANFD_BRS = 0x01  # struct canfd_frame flags (linux/can.h)
LOG_SUFFIXES = (".blf", ".asc", ".log")
TRACES = (("plant.trace", 0), ("fw.trace", 1))  # file, channel in the log
DERIVED_GROUP = "derived"


class ExportError(Exception):
    """The run folder does not hold what the export needs (exit 2 at the command line)."""


def _no_full_rate(run_dir: Path, what: str) -> ExportError:
    return ExportError(
        f"{run_dir} has no {what}: a passing run keeps only result.json, report.md and "
        "recording.rrd. Run it again with `rig run SCENARIO --keep-all --out DIR` (a run that "
        "does not pass keeps its full-rate data anyway)")


def open_capture(run_dir: Path) -> capture.Capture:
    """The run's capture, or ExportError saying why there is none."""
    if not (run_dir / "result.json").is_file():
        raise ExportError(f"{run_dir} is not a run folder (no result.json)")
    if any(run_dir.glob("*/result.json")) and not (run_dir / "capture").exists():
        raise ExportError(f"{run_dir} is a suite folder: export one of its scenario folders "
                          f"({run_dir}/NAME)")
    if not (run_dir / "capture" / "meta.json").is_file():
        raise _no_full_rate(run_dir, "capture columns (capture/)")
    return capture.Capture(run_dir / "capture")


def _message(name: str) -> tuple[str, Message]:
    for db in protocols.DATABASES:
        try:
            return db, protocols.database(db).get_message_by_name(name)
        except KeyError:
            continue
    raise KeyError(f"message {name} is in no DBC of protocols/")


def channel_groups(cap: capture.Capture) -> list[dict[str, Any]]:
    """What goes into the MDF file: per group its name, comment and channels (column, unit,
    comment), from the trace specs (``rig.capture.default_specs``) and the DBC."""
    groups: list[dict[str, Any]] = []
    taken: set[str] = {"period"}
    for spec in capture.default_specs(Path("plant.trace"), Path("fw.trace")):
        for name, prefix in spec.messages.items():
            db, msg = _message(name)
            channels = []
            for sig in msg.signals:
                column = f"{prefix}.{sig.name}"
                if column not in cap:
                    continue
                note = f"{name}.{sig.name} (protocols/{db}.dbc)"
                if sig.comment:
                    note += f": {sig.comment}"
                channels.append({"column": column, "unit": sig.unit or "", "comment": note})
                taken.add(column)
            groups.append({"name": name, "comment": f"{spec.role}: {name} (protocols/{db}.dbc), "
                           "every PWM period", "channels": channels})
    derived = [{"column": c, "unit": capture.DERIVED_UNITS.get(c, ""),
                "comment": capture.DERIVED_COMMENTS.get(c, "derived by the rig (rig.capture)")}
               for c in cap.keys() if c not in taken]
    if derived:
        groups.append({"name": DERIVED_GROUP, "comment": "derived by the rig from the traces "
                       "(rig.capture): what the criteria's metrics read", "channels": derived})
    return groups


def write_mf4(run_dir: Path, dest: Path) -> dict[str, Any]:
    """Writes the capture as MDF 4.10 (deflate-compressed data blocks); returns a summary."""
    from asammdf import MDF, Signal

    cap = open_capture(run_dir)
    t = (np.asarray(cap["period"], dtype=np.float64)) * cap.ts
    mdf = MDF(version="4.10")
    n_channels = 0
    groups = channel_groups(cap)
    try:
        for g in groups:
            signals = [Signal(samples=np.asarray(cap[ch["column"]]), timestamps=t,
                              name=ch["column"], unit=ch["unit"], comment=ch["comment"])
                       for ch in g["channels"]]
            if signals:
                mdf.append(signals, acq_name=g["name"], comment=g["comment"])
                n_channels += len(signals)
        with _whole_or_nothing(dest) as tmp:
            mdf.save(tmp, overwrite=True, compression=2)
    finally:
        mdf.close()
    return {"path": str(dest), "groups": len(groups), "channels": n_channels,
            "samples": cap.n, "bytes": dest.stat().st_size}


def _fd_ids() -> set[int]:
    return {int(m.frame_id) for db in protocols.DATABASES
            for m in protocols.database(db).messages if m.is_fd}


def _period_decoders() -> dict[int, MessageDecoder]:
    """A decoder for every DBC message that carries a ``period`` signal, by frame ID."""
    out: dict[int, MessageDecoder] = {}
    for db in protocols.DATABASES:
        for msg in protocols.database(db).messages:
            if any(s.name == "period" for s in msg.signals):
                out[int(msg.frame_id)] = MessageDecoder(msg)
    return out


def frame_periods(records: np.ndarray, decoders: dict[int, MessageDecoder],
                  last: int = 0) -> np.ndarray:
    """The period of every trace record: its ``period`` signal, or for a frame without one
    the period of the record before it (``last`` before the first)."""
    ids = frame_ids(records["can_id"])
    periods = np.full(len(records), -1, dtype=np.int64)
    for frame_id, dec in decoders.items():
        sel = (ids == frame_id) & (records["len"] >= dec.length)
        if sel.any():
            periods[sel] = dec.decode_signal(records["data"][sel], "period").astype(np.int64)
    # carry the last known period forward over frames without one
    known = periods >= 0
    idx = np.where(known, np.arange(len(periods)), -1)
    np.maximum.accumulate(idx, out=idx)
    filled = np.where(idx >= 0, periods[np.maximum(idx, 0)], last)
    return filled


def _records(run_dir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every trace record (both traces), its channel and its period, in log order."""
    decoders = _period_decoders()
    parts, chans, pers = [], [], []
    for name, channel in TRACES:
        path = run_dir / name
        if not path.is_file():
            raise _no_full_rate(run_dir, f"trace {name}")
        tf = TraceFile.open(path)
        recs = np.asarray(tf.records())
        parts.append(recs)
        chans.append(np.full(len(recs), channel, dtype=np.int8))
        pers.append(frame_periods(recs, decoders))
    records = np.concatenate(parts) if parts else np.zeros(0)
    channels = np.concatenate(chans)
    periods = np.concatenate(pers)
    order = np.argsort(periods, kind="stable")  # within a period: the plant's frames first
    return records[order], channels[order], periods[order]


def start_time(run_dir: Path) -> float:
    """When the run started (result.json ``started``, POSIX seconds; 0 when unknown): the
    time of period 0 in a CAN log."""
    try:
        started = json.loads((run_dir / "result.json").read_text())["started"]
        return dt.datetime.fromisoformat(str(started)).timestamp()
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0


def messages(run_dir: Path, ts: float = capture.TS) -> Iterator[can.Message]:
    """The run's frames as python-can messages, in log order; a frame's time is the run's
    start plus its period times ``ts``."""
    t0 = start_time(run_dir)
    records, channels, periods = _records(run_dir)
    can_id = records["can_id"]
    ids_arr = frame_ids(can_id)
    ids = ids_arr.tolist()
    extended = ((can_id & CAN_EFF_FLAG) != 0).tolist()
    flags = records["flags"]
    # an FD frame: flagged so, longer than 8 bytes, or an FD message of the DBC (the
    # programs' traces do not always set the flag)
    fd_ids = np.asarray(sorted(_fd_ids()), dtype=np.uint32)
    fd = (((flags & CANFD_FDF) != 0) | (records["len"] > 8)
          | np.isin(ids_arr, fd_ids)).tolist()
    brs = ((flags & CANFD_BRS) != 0).tolist()
    lengths = records["len"].tolist()
    data = records["data"]
    times = (t0 + periods.astype(np.float64) * ts).tolist()
    chans = channels.tolist()
    for i, length in enumerate(lengths):
        yield can.Message(
            timestamp=times[i], arbitration_id=ids[i], is_extended_id=extended[i],
            is_fd=fd[i], bitrate_switch=brs[i], data=data[i, :length].tobytes(), dlc=length,
            channel=chans[i],
        )


def write_can_log(run_dir: Path, dest: Path) -> dict[str, Any]:
    """Writes every traced frame to ``dest`` (.blf, .asc or .log); returns a summary."""
    suffix = dest.suffix.lower()
    if suffix not in LOG_SUFFIXES:
        raise ExportError(f"{dest}: a CAN log is {', '.join(LOG_SUFFIXES)} (BLF, ASC, "
                          f"candump -L), not {suffix or 'a file without a suffix'}")
    if not (run_dir / "result.json").is_file():
        raise ExportError(f"{run_dir} is not a run folder (no result.json)")
    for name, _ in TRACES:
        if not (run_dir / name).is_file():
            raise _no_full_rate(run_dir, f"trace {name}")
    frames = 0
    with _whole_or_nothing(dest) as tmp:
        writer: can.io.generic.MessageWriter
        if suffix == ".blf":
            writer = can.BLFWriter(tmp)
        elif suffix == ".asc":
            writer = can.ASCWriter(tmp)
        else:
            writer = can.CanutilsLogWriter(tmp, channel="vcan0")
        try:
            for msg in messages(run_dir):
                writer.on_message_received(msg)
                frames += 1
        finally:
            writer.stop()
    return {"path": str(dest), "frames": frames, "bytes": dest.stat().st_size}


@contextlib.contextmanager
def _whole_or_nothing(dest: Path) -> Iterator[Path]:
    """A temporary file next to ``dest``, renamed to ``dest`` when the block succeeds and
    removed when it fails: a file is complete or not there."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.stem}.tmp-{os.getpid()}{dest.suffix}")
    try:
        yield tmp
        os.replace(tmp, dest)
    finally:
        tmp.unlink(missing_ok=True)
