"""Measurement files from a run's full-rate data, in the formats tools of the field open.

- ``write_mf4``: ASAM MDF 4.10 with asammdf: one channel group per traced message
  (``BENCH_TRUTH``, ``BENCH_TRUTH_MAG``, ``FW_TRACE``) with channels named ``MESSAGE.signal``,
  units and comments from the DBC (cantools), value-to-text conversions from its value
  tables (``FW_TRACE.state`` reads ``RUN``), and one group for the columns the rig derives
  (named as in the capture: ``pos_err_deg``); the master channel the simulated time
  ``period * 100 µs``, the file's start time the run's, its header the scenario, profile,
  bus, verdict and versions (the rig's commit among them). Samples keep the capture's types,
  so the values are the capture's, bit for bit. The frames of the run are there too, raw, as
  an ASAM bus-logging group (``CAN_DataFrame``, source bus CAN) that asammdf's
  ``extract_bus_logging`` decodes with the DBC files.
- ``write_can_log``: every frame of the run with python-can's writers, by the file's suffix:
  ``.blf`` (Vector BLF), ``.asc`` (Vector ASCII), ``.log`` (SocketCAN candump -L). The traces
  hold them: ``plant.trace`` the plant's (the VIO_ADC frames it sent and the VIO_PWM frames it
  received, its truth), ``fw.trace`` the firmware's FW_TRACE, ``rig.trace`` the rig's (the
  drive protocol and the bench commands it sent, what it heard: DRIVE_STATUS, HEARTBEAT,
  TLM_*, BENCH_PROGRESS, ...), channels 0, 1 and 2 of the log. A frame's time is the run's
  start (``started`` in result.json) plus its period times 100 µs: the period it carries, or
  for a frame without one (DRIVE_CMD) the period it came in (``frame_periods``); within a
  period the rig's frames (the commands for it) first.

Both need the run's full-rate data: kept by a run that did not pass, or by every run with
``rig run --keep-all``. A run without it, or whose data is damaged (a trace cut short, a
foreign file), raises ``ExportError`` with what to do.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import getpass
import json
import os
import re
import stat
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import can
import numpy as np
from cantools.database.can import Message

from rig import protocols
from rig.bus import can_log
from rig.bus.unixcan_wire import WIRE
from rig.data import capture
from rig.data.trace import CAN_EFF_FLAG, CANFD_FDF, MessageDecoder, TraceError, TraceFile, frame_ids

CANFD_BRS = WIRE.brs  # struct canfd_frame flags: protocols/unixcan.toml
LOG_SUFFIXES = (".blf", ".asc", ".log")
MF4_SUFFIXES = (".mf4",)
# file, channel in the log, order within a period, whether a run must have it (rig.trace
# came later: a run folder from before it exports without the rig's frames)
TRACES = (("rig.trace", 2, 0, False), ("plant.trace", 0, 1, True), ("fw.trace", 1, 2, True))
FW_TAIL = 1  # periods fw.trace may end before the capture (its last ISR: capture.py)
DERIVED_GROUP = "derived"
DLC_OF_LENGTH = np.array([can.util.len2dlc(n) for n in range(65)], dtype=np.uint8)
BUS_GROUP = "CAN bus"


class ExportError(Exception):
    """The run folder does not hold what the export needs, or the destination is not a file
    to write (exit 2 at the command line)."""


def _no_full_rate(run_dir: Path, what: str) -> ExportError:
    return ExportError(
        f"{run_dir} has no {what}: a passing run keeps only result.json, report.md and "
        "recording.rrd. Run it again with `rig run SCENARIO --keep-all --out DIR` (a run that "
        "does not pass keeps its full-rate data anyway)")


def _result(run_dir: Path) -> dict[str, Any]:
    if not (run_dir / "result.json").is_file():
        raise ExportError(f"{run_dir} is not a run folder (no result.json)")
    try:
        data = json.loads((run_dir / "result.json").read_text())
    except (OSError, ValueError) as exc:
        raise ExportError(f"{run_dir}/result.json cannot be read: {exc}") from exc
    if not isinstance(data, dict):
        raise ExportError(f"{run_dir}/result.json is not a run's result")
    return data


def default_name(run_dir: Path) -> str:
    """The file name an export of ``run_dir`` takes without one given: the scenario's name as
    a plain file name (no folder, no leading dot: a ``scenario`` of ``../../x`` in
    result.json names ``x``, never a path), else the run folder's name."""
    name = str(_result(run_dir).get("scenario") or "")
    name = re.sub(r"[^A-Za-z0-9_.@+-]+", "_", name.replace("\\", "/").rsplit("/", 1)[-1])
    name = name.lstrip(".")
    return name or re.sub(r"[^A-Za-z0-9_.@+-]+", "_", run_dir.resolve().name).lstrip(".") \
        or "run"


def open_capture(run_dir: Path) -> capture.Capture:
    """The run's capture, or ExportError saying why there is none."""
    _result(run_dir)
    if any(run_dir.glob("*/result.json")) and not (run_dir / "capture").exists():
        raise ExportError(f"{run_dir} is a suite folder: export one of its scenario folders "
                          f"({run_dir}/NAME)")
    if not (run_dir / "capture" / "meta.json").is_file():
        raise _no_full_rate(run_dir, "capture columns (capture/)")
    try:
        cap = capture.Capture(run_dir / "capture")
        for column in ("period", *cap.keys()):
            if len(cap[column]) != cap.n:
                raise ValueError(f"column {column} has {len(cap[column])} rows, not {cap.n}")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ExportError(f"{run_dir}/capture is damaged ({type(exc).__name__}: {exc}); run "
                          "the scenario again with --keep-all") from exc
    return cap


def _message(name: str) -> tuple[str, Message]:
    for db in protocols.DATABASES:
        try:
            return db, protocols.database(db).get_message_by_name(name)
        except KeyError:
            continue
    raise KeyError(f"message {name} is in no DBC of protocols/")


# signals that carry another signal's values without a table of their own: FW_TRACE.state is
# the firmware's state, DRIVE_STATUS.state's values (gen_wire.py checks the range against it)
SAME_VALUES = {("FW_TRACE", "state"): ("drive", "DRIVE_STATUS", "state")}


def value_to_text(message: str, sig: Any) -> dict[str, object] | None:
    """An asammdf value-to-text conversion from the DBC value table of a signal (None when
    it has none)."""
    choices = sig.choices
    if not choices and (message, sig.name) in SAME_VALUES:
        db, other, name = SAME_VALUES[(message, sig.name)]
        choices = protocols.database(db).get_message_by_name(other).get_signal_by_name(
            name).choices
    if not choices:
        return None
    conv: dict[str, object] = {}
    for k, (value, name) in enumerate(sorted(choices.items())):
        conv[f"val_{k}"] = int(value)
        conv[f"text_{k}"] = str(name)
    conv["default_addr"] = b""
    return conv


def channel_groups(cap: capture.Capture) -> list[dict[str, Any]]:
    """What goes into the MDF file: per group its name, comment and channels (column, MDF
    name, unit, comment, value-to-text conversion), from the trace specs
    (``rig.data.capture.default_specs``) and the DBC."""
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
                note = f"{name}.{sig.name} (protocols/{db}.dbc; capture column {column})"
                if sig.comment:
                    note += f": {sig.comment}"
                channels.append({"column": column, "name": f"{name}.{sig.name}",
                                 "unit": sig.unit or "", "comment": note,
                                 "conversion": value_to_text(name, sig)})
                taken.add(column)
            groups.append({"name": name, "comment": f"{spec.role}: {name} (protocols/{db}.dbc), "
                           "every PWM period", "channels": channels})
    derived = [{"column": c, "name": c, "unit": capture.DERIVED_UNITS.get(c, ""),
                "comment": capture.DERIVED_COMMENTS.get(c, "derived by the rig (rig.data.capture)"),
                "conversion": None}
               for c in cap.keys() if c not in taken]
    if derived:
        groups.append({"name": DERIVED_GROUP, "comment": "derived by the rig from the traces "
                       "(rig.data.capture): what the criteria's metrics read", "channels": derived})
    return groups


def start_time(run_dir: Path) -> float:
    """When the run started (result.json ``started``, POSIX seconds; 0 when unknown): the
    time of period 0."""
    try:
        started = json.loads((run_dir / "result.json").read_text())["started"]
        return dt.datetime.fromisoformat(str(started)).timestamp()
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0


PROJECT = "sensorless IPMSM drive HIL rig (Mubarok & Liu, IEEE Access 2022)"


def set_header(header: Any, result: Mapping[str, Any]) -> None:
    """The MDF header of a run, in asammdf's own fields: its start time, author (who ran the
    export), project, subject (the drive, its profile and scenario) and description, and the
    run's identity, verdict and versions as further common properties (asammdf keeps them
    beside author and project, in the dictionary its field setters write: pinned version)."""
    started = result.get("started")
    if started:
        with contextlib.suppress(ValueError, TypeError):
            header.start_time = dt.datetime.fromisoformat(str(started))
    header.description = (f"{result.get('scenario')}: {result.get('description')} "
                          f"({result.get('status')})")
    try:
        header.author = getpass.getuser()
    except (KeyError, OSError):  # no user name for this uid (a container)
        header.author = f"uid {os.getuid()}"
    header.project = PROJECT
    header.subject = (f"the drive on the {result.get('profile')} profile, scenario "
                      f"{result.get('scenario')}")
    header.department = ""
    items: list[tuple[str, Any]] = [(k, result.get(k)) for k in (
        "scenario", "scenario_file", "figure", "profile", "mode", "bus", "channel", "started",
        "finished", "status")]
    items += [(f"version.{k}", v) for k, v in sorted((result.get("versions") or {}).items())]
    items.append(("commit", (result.get("versions") or {}).get("rig.commit", "unknown")))
    header._common_properties.update({k: str(v) for k, v in items if v not in (None, "")})


def write_mf4(run_dir: Path, dest: Path) -> dict[str, Any]:
    """Writes the capture and the run's frames as MDF 4.10 (deflate-compressed data blocks);
    returns a summary."""
    from asammdf import MDF, Signal

    cap = open_capture(run_dir)
    result = _result(run_dir)
    dest = checked_destination(dest, MF4_SUFFIXES, "an MDF4 file")
    t = (np.asarray(cap["period"], dtype=np.float64)) * cap.ts
    frames = _frames(run_dir, result)
    mdf = MDF(version="4.10")
    n_channels = 0
    groups = channel_groups(cap)
    try:
        set_header(mdf.header, result)
        for g in groups:
            signals = [Signal(samples=np.asarray(cap[ch["column"]]), timestamps=t,
                              name=ch["name"], unit=ch["unit"], comment=ch["comment"],
                              conversion=ch["conversion"])
                       for ch in g["channels"]]
            if signals:
                mdf.append(signals, acq_name=g["name"], comment=g["comment"])
                n_channels += len(signals)
        n_frames = _append_bus_logging(mdf, frames, cap.ts)
        with _whole_or_nothing(dest) as tmp:
            mdf.save(tmp, overwrite=True, compression=2)
    finally:
        mdf.close()
    return {"path": str(dest), "groups": len(groups) + (n_frames > 0), "channels": n_channels,
            "samples": cap.n, "frames": n_frames, "bytes": dest.stat().st_size}


def _append_bus_logging(mdf: Any, frames: tuple[np.ndarray, np.ndarray, np.ndarray],
                        ts: float) -> int:
    """The frames as an ASAM MDF bus-logging group (CAN_DataFrame, source bus CAN)."""
    from asammdf import Signal
    from asammdf.blocks.source_utils import Source

    records, channels, periods = frames
    if not len(records):
        return 0
    can_id = records["can_id"]
    fields = [("BusChannel", "<u1"), ("ID", "<u4"), ("IDE", "<u1"), ("DLC", "<u1"),
              ("DataLength", "<u1"), ("DataBytes", "(64,)u1"), ("Dir", "<u1"), ("EDL", "<u1"),
              ("BRS", "<u1"), ("ESI", "<u1")]
    data = np.zeros(len(records), dtype=[(f"CAN_DataFrame.{n}", k) for n, k in fields])
    data["CAN_DataFrame.BusChannel"] = channels.astype(np.uint8) + 1  # ASAM: 1 is the first
    data["CAN_DataFrame.ID"] = frame_ids(can_id)
    data["CAN_DataFrame.IDE"] = (can_id & CAN_EFF_FLAG) != 0
    lengths = records["len"]
    data["CAN_DataFrame.DataLength"] = lengths
    data["CAN_DataFrame.DLC"] = DLC_OF_LENGTH[lengths]
    data["CAN_DataFrame.DataBytes"] = records["data"]
    data["CAN_DataFrame.EDL"] = _is_fd(records)
    data["CAN_DataFrame.BRS"] = (records["flags"] & CANFD_BRS) != 0
    source = Source("rig traces", "plant.trace, fw.trace, rig.trace",
                    "every frame of the run, from the traces (rig export)",
                    Source.SOURCE_BUS, Source.BUS_TYPE_CAN)
    signal = Signal(samples=data, timestamps=periods.astype(np.float64) * ts,
                    name="CAN_DataFrame", comment="the run's frames (rig.data.export)",
                    source=source)
    mdf.append([signal], acq_name=BUS_GROUP, acq_source=source,
               comment="the run's CAN frames: channel 1 the plant's trace, 2 the firmware's, "
               "3 the rig's")
    return len(records)


def _fd_ids() -> set[int]:
    return {int(m.frame_id) for db in protocols.DATABASES
            for m in protocols.database(db).messages if m.is_fd}


def _is_fd(records: np.ndarray) -> np.ndarray:
    """An FD frame: flagged so, longer than 8 bytes, or an FD message of the DBC (the
    programs' traces do not always set the flag)."""
    fd_ids = np.asarray(sorted(_fd_ids()), dtype=np.uint32)
    return (((records["flags"] & CANFD_FDF) != 0) | (records["len"] > 8)
            | np.isin(frame_ids(records["can_id"]), fd_ids))


def _period_decoders(bits: int | None = None) -> dict[int, MessageDecoder]:
    """A decoder for every DBC message with a ``period`` signal (of ``bits`` bits), by ID."""
    out: dict[int, MessageDecoder] = {}
    for db in protocols.DATABASES:
        for msg in protocols.database(db).messages:
            for s in msg.signals:
                if s.name == "period" and (bits is None or s.length == bits):
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


def rig_frame_periods(records: np.ndarray) -> np.ndarray:
    """The period of every frame of the rig's trace, in lockstep terms: a frame with a 32-bit
    ``period`` (BENCH_PROGRESS, BENCH_COUNTERS) is at it; a 16-bit one (TLM_*) at the period
    with those low bits nearest the rig's time; a grant (BENCH_STEP) is sent at the
    rig's time and moves it to its ``run_until``, where the commands that follow it act;
    every other frame (DRIVE_CMD, DRIVE_STATUS, ...) is at the rig's time."""
    wide, narrow = _period_decoders(32), _period_decoders(16)
    ids = frame_ids(records["can_id"])
    own: dict[int, np.ndarray] = {}  # 32 and 16 bits: each record's period signal, else -1
    for bits, table in ((32, wide), (16, narrow)):
        own[bits] = np.full(len(records), -1, dtype=np.int64)
        for frame_id, dec in table.items():
            sel = (ids == frame_id) & (records["len"] >= dec.length)
            if sel.any():
                own[bits][sel] = dec.decode_signal(records["data"][sel], "period")
    step_dec = MessageDecoder(protocols.database("bench").get_message_by_name("BENCH_STEP"))
    sel = (ids == step_dec.frame_id) & (records["len"] >= step_dec.length)
    run_until = np.full(len(records), -1, dtype=np.int64)
    if sel.any():
        run_until[sel] = step_dec.decode_signal(records["data"][sel], "run_until")
    out = np.zeros(len(records), dtype=np.int64)
    now = 0
    for i, (p32, p16, until) in enumerate(zip(own[32].tolist(), own[16].tolist(),
                                               run_until.tolist(), strict=True)):
        if p32 >= 0:
            now = p32
            out[i] = now
        elif p16 >= 0:  # the period with those low bits nearest the rig's time
            out[i] = now + ((p16 - now + 0x8000) & 0xFFFF) - 0x8000
        else:
            out[i] = now
            if until >= 0:
                now = until
    return out


def _expected_range(result: Mapping[str, Any]) -> tuple[int, int] | None:
    cap = result.get("capture") or {}
    try:
        return int(cap["first_period"]), int(cap["last_period"])
    except (KeyError, TypeError, ValueError):
        return None


def _open_trace(run_dir: Path, name: str) -> TraceFile:
    try:
        tf = TraceFile.open(run_dir / name)
    except TraceError as exc:
        raise ExportError(f"{exc}: not a trace of this rig (damaged or replaced)") from exc
    if tf.trailing_bytes:
        raise ExportError(f"{run_dir / name} ends in a partial record ({tf.trailing_bytes} "
                          "bytes): the file was cut short")
    return tf


def _frames(run_dir: Path, result: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray,
                                                                 np.ndarray]:
    """Every trace record of the run, its channel and its period, in log order (by period;
    within one, the rig's, the plant's, the firmware's, each in trace order). A trace that
    ends before the capture's last period (cut short) is an ExportError, not a shorter log."""
    decoders = _period_decoders()
    expected = _expected_range(result)
    parts, chans, pers, ranks = [], [], [], []
    for name, channel, rank, required in TRACES:
        if not (run_dir / name).is_file():
            if required:
                raise _no_full_rate(run_dir, f"trace {name}")
            continue
        recs = np.asarray(_open_trace(run_dir, name).records())
        periods = (rig_frame_periods(recs) if name == "rig.trace"
                   else frame_periods(recs, decoders))
        if required and expected is not None:
            last = int(periods.max()) if len(periods) else -1
            tail = FW_TAIL if name == "fw.trace" else 0
            if last < expected[1] - tail:
                raise ExportError(
                    f"{run_dir / name} ends at period {last}, the run captured periods "
                    f"{expected[0]} .. {expected[1]}: the trace was cut short "
                    f"({len(recs)} records)")
        parts.append(recs)
        chans.append(np.full(len(recs), channel, dtype=np.int8))
        pers.append(periods)
        ranks.append(np.full(len(recs), rank, dtype=np.int8))
    records = np.concatenate(parts)
    periods = np.concatenate(pers)
    order = np.lexsort((np.concatenate(ranks), periods))  # stable within each key
    return records[order], np.concatenate(chans)[order], periods[order]


def messages(run_dir: Path, ts: float = capture.TS) -> Iterator[can.Message]:
    """The run's frames as python-can messages, in log order; a frame's time is the run's
    start plus its period times ``ts``."""
    t0 = start_time(run_dir)
    records, channels, periods = _frames(run_dir, _result(run_dir))
    can_id = records["can_id"]
    ids = frame_ids(can_id).tolist()
    extended = ((can_id & CAN_EFF_FLAG) != 0).tolist()
    fd = _is_fd(records).tolist()
    brs = ((records["flags"] & CANFD_BRS) != 0).tolist()
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
    """Writes every frame of the run to ``dest`` (.blf, .asc or .log); returns a summary."""
    result = _result(run_dir)
    dest = checked_destination(dest, LOG_SUFFIXES, "a CAN log (BLF, ASC, candump -L)")
    for name, _, _, required in TRACES:
        if required and not (run_dir / name).is_file():
            raise _no_full_rate(run_dir, f"trace {name}")
    _frames(run_dir, result)  # a damaged trace stops it before anything is written
    frames = 0
    with _whole_or_nothing(dest) as tmp:
        writer = can_log.writer(
            tmp, can_log.REBUILT, "the frames the plant (channel 0), the firmware (1) and the "
            "rig (2) traced, each at the run's start plus its PWM period; not a live capture "
            "(rig run --can-log)", start=start_time(run_dir))
        try:
            for msg in messages(run_dir):
                writer.on_message_received(msg)
                frames += 1
        finally:
            writer.stop()
    return {"path": str(dest), "frames": frames, "bytes": dest.stat().st_size,
            "kind": can_log.REBUILT, "kind_in_file": can_log.says_kind_in_file(dest)}


def checked_destination(dest: Path, suffixes: tuple[str, ...], what: str) -> Path:
    """Where a file is written: a name with one of ``suffixes`` (a folder: the caller picks
    the name), never a device, a FIFO or another special file (written whole into a
    temporary file and renamed, which would replace it)."""
    if dest.suffix.lower() not in suffixes:
        raise ExportError(f"{dest}: {what} is named *{' or *'.join(suffixes)}, not "
                          f"{dest.suffix or 'a name without a suffix'}")
    with contextlib.suppress(FileNotFoundError):
        mode = os.stat(dest).st_mode
        if not stat.S_ISREG(mode):
            raise ExportError(f"{dest} exists and is not a regular file: give a file name")
    return dest


@contextlib.contextmanager
def _whole_or_nothing(dest: Path) -> Iterator[Path]:
    """A temporary file next to ``dest`` (``rig.results.whole``: renamed to ``dest`` when the
    block succeeds, removed whatever ends it), its folder made first."""
    from rig.results.whole import whole

    dest.parent.mkdir(parents=True, exist_ok=True)
    with whole(dest) as tmp:
        yield tmp
