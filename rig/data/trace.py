"""Per-process binary trace files (docs/interfaces.md, "Trace files") and their vectorised decode.

A trace is a 16-byte header (``b"HILTRACE"``, ``u32`` version 1, ``u32`` record size 72)
followed by records that are exactly Linux ``struct canfd_frame``. Each record holds one DBC
message. This module reads traces in chunks through ``np.memmap`` (memory stays flat for
long runs) and decodes a message's signals for a whole chunk at once, straight from the
cantools signal definitions (start bit, length, byte order, signedness, float, scale,
offset). Signals the vectorised path cannot express (big-endian, wider than 64 bits across
their bytes) fall back to cantools' own per-frame decode.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np
import numpy.typing as npt
from cantools.database.can import Message, Signal

from rig.bus.unixcan_wire import WIRE

MAGIC = b"HILTRACE"
VERSION = 1
HEADER = struct.Struct("<8sII")
HEADER_SIZE = HEADER.size  # 16

# A record is a struct canfd_frame as the programs received it: the very datagram of the
# unixcan wire, whose layout and flag bits are protocols/unixcan.toml.
RECORD_SIZE = WIRE.fd_size
CAN_EFF_FLAG = WIRE.eff_flag
CAN_EFF_MASK = WIRE.eff_mask
CAN_SFF_MASK = WIRE.sff_mask
CANFD_FDF = WIRE.fdf

# struct canfd_frame, little-endian (x86-64 and every host this rig runs on).
RECORD_DTYPE = np.dtype(
    [
        ("can_id", "<u4"),
        ("len", "u1"),
        ("flags", "u1"),
        ("res0", "u1"),
        ("res1", "u1"),
        ("data", "u1", (WIRE.fd_max_len,)),
    ]
)
assert RECORD_DTYPE.itemsize == RECORD_SIZE

DEFAULT_CHUNK = 1 << 16  # records per chunk (4.7 MB)

Columns = dict[str, np.ndarray]


class TraceError(ValueError):
    """A trace file that is not a trace, or of an unsupported version."""


def frame_ids(can_id: npt.NDArray[np.uint32]) -> npt.NDArray[np.uint32]:
    """The arbitration ID of each raw ``can_id`` (flags stripped, SFF/EFF masked)."""
    eff = (can_id & CAN_EFF_FLAG) != 0
    return np.where(eff, can_id & CAN_EFF_MASK, can_id & CAN_SFF_MASK).astype(np.uint32)


@dataclass
class TraceFile:
    """An open trace: validated header, record count, chunked record access."""

    path: Path
    n_records: int
    trailing_bytes: int
    _records: np.memmap | None = field(default=None, repr=False)

    @classmethod
    def open(cls, path: str | Path) -> TraceFile:
        p = Path(path)
        size = p.stat().st_size
        if size < HEADER_SIZE:
            raise TraceError(f"{p}: {size} bytes, shorter than the 16-byte trace header")
        with p.open("rb") as fh:
            magic, version, rec_size = HEADER.unpack(fh.read(HEADER_SIZE))
        if magic != MAGIC:
            raise TraceError(f"{p}: not a HIL trace (magic {magic!r}, expected {MAGIC!r})")
        if version != VERSION:
            raise TraceError(f"{p}: trace version {version}, this rig reads version {VERSION}")
        if rec_size != RECORD_SIZE:
            raise TraceError(f"{p}: record size {rec_size}, expected {RECORD_SIZE}")
        body = size - HEADER_SIZE
        n = body // RECORD_SIZE
        records = (
            np.memmap(p, dtype=RECORD_DTYPE, mode="r", offset=HEADER_SIZE, shape=(n,))
            if n
            else None
        )
        return cls(path=p, n_records=n, trailing_bytes=body % RECORD_SIZE, _records=records)

    def chunks(self, chunk: int = DEFAULT_CHUNK) -> Iterator[np.ndarray]:
        """Consecutive blocks of records, read with plain sequential reads (no mapping, so
        the resident memory stays at one block however long the trace)."""
        if not self.n_records:
            return
        with self.path.open("rb") as fh:
            fh.seek(HEADER_SIZE)
            left = self.n_records
            while left > 0:
                count = min(chunk, left)
                block = np.fromfile(fh, dtype=RECORD_DTYPE, count=count)
                if len(block) != count:  # the file shrank under us
                    raise TraceError(f"{self.path}: short read")
                left -= count
                yield block

    def records(self) -> np.ndarray:
        """All records (a memory-mapped view; nothing is read until used)."""
        if self._records is None:
            return np.zeros(0, dtype=RECORD_DTYPE)
        return self._records


@dataclass(frozen=True)
class _Field:
    """How one signal is decoded: vectorised plan or cantools fallback."""

    name: str
    vectorised: bool
    byte0: int = 0
    n_bytes: int = 0
    shift: int = 0
    length: int = 0
    signed: bool = False
    is_float: bool = False
    scale: float = 1.0
    offset: float = 0.0
    scaled: bool = False


def _plan(signal: Signal) -> _Field:
    start, length = signal.start, signal.length
    if signal.byte_order != "little_endian" or signal.multiplexer_ids:
        return _Field(signal.name, vectorised=False)
    shift = start % 8
    n_bytes = (shift + length + 7) // 8
    if shift + length > 64:
        return _Field(signal.name, vectorised=False)
    if signal.is_float and not (shift == 0 and length in (32, 64)):
        return _Field(signal.name, vectorised=False)
    scale = float(signal.scale)
    offset = float(signal.offset)
    return _Field(
        name=signal.name,
        vectorised=True,
        byte0=start // 8,
        n_bytes=n_bytes,
        shift=shift,
        length=length,
        signed=bool(signal.is_signed),
        is_float=bool(signal.is_float),
        scale=scale,
        offset=offset,
        scaled=not (scale == 1.0 and offset == 0.0),
    )


class MessageDecoder:
    """Decodes one DBC message from arrays of trace records, vectorised per signal."""

    def __init__(self, message: Message) -> None:
        self.message = message
        self.frame_id = int(message.frame_id)
        self.length = int(message.length)
        self.fields = [_plan(s) for s in message.signals]
        self.fallback = [f.name for f in self.fields if not f.vectorised]

    @property
    def names(self) -> list[str]:
        return [f.name for f in self.fields]

    def decode_signal(self, data: npt.NDArray[np.uint8], name: str) -> np.ndarray:
        """One signal of every frame in ``data``."""
        f = next(f for f in self.fields if f.name == name)
        if f.vectorised:
            return _decode_field(np.ascontiguousarray(data[:, : self.length]), f)
        return self.decode(data)[name]

    def decode(self, data: npt.NDArray[np.uint8]) -> Columns:
        """Signals of ``data`` (shape ``(n, >= length)``): one array per signal name.

        Integer signals without scaling come out as ``int64``, float and scaled ones as
        ``float64`` (exactly what cantools computes per frame: ``raw * scale + offset``).
        """
        data = np.ascontiguousarray(data[:, : self.length])
        n = data.shape[0]
        out: Columns = {}
        for f in self.fields:
            if f.vectorised:
                out[f.name] = _decode_field(data, f)
        if self.fallback:
            values = {name: np.empty(n, dtype=np.float64) for name in self.fallback}
            for i in range(n):
                decoded = self.message.decode(
                    bytes(data[i]), decode_choices=False, scaling=True, allow_truncated=False
                )
                assert isinstance(decoded, dict)
                for name in self.fallback:
                    v = decoded[name]
                    values[name][i] = float(v) if isinstance(v, int | float) else math.nan
            out.update(values)
        return out


def _decode_field(data: npt.NDArray[np.uint8], f: _Field) -> np.ndarray:
    n = data.shape[0]
    if f.shift == 0 and f.length in (8, 16, 32, 64) and f.n_bytes * 8 == f.length:
        raw_bytes = np.ascontiguousarray(data[:, f.byte0 : f.byte0 + f.n_bytes])
        if f.is_float:
            kind = "<f4" if f.length == 32 else "<f8"
            with np.errstate(invalid="ignore"):  # signalling NaNs stay NaN, as in cantools
                return raw_bytes.view(kind).reshape(n).astype(np.float64)
        kind = ("<i" if f.signed else "<u") + str(f.n_bytes)
        ints = raw_bytes.view(kind).reshape(n)
        if f.length == 64 and not f.signed:
            # uint64 beyond int64: keep exact as float only if scaled
            return ints.astype(np.float64) * f.scale + f.offset if f.scaled else ints
        values = ints.astype(np.int64)
    else:
        acc = np.zeros(n, dtype=np.uint64)
        for j in range(f.n_bytes):
            acc |= data[:, f.byte0 + j].astype(np.uint64) << np.uint64(8 * j)
        acc >>= np.uint64(f.shift)
        if f.length < 64:
            acc &= np.uint64((1 << f.length) - 1)
        if f.signed:
            values = acc.view(np.int64).copy()
            if f.length < 64:
                sign = np.int64(1) << np.int64(f.length - 1)
                values = (values ^ sign) - sign
        else:
            values = acc.astype(np.int64)
    if f.scaled:
        return values.astype(np.float64) * f.scale + f.offset
    return values


@dataclass
class Split:
    """Records of one trace chunk, split by message, with the malformed ones counted."""

    by_name: dict[str, Columns]
    unknown: int
    bad_length: int


class TraceDecoder:
    """Decodes the messages of a set of DBC messages found in trace records."""

    def __init__(self, messages: Sequence[Message]) -> None:
        self.decoders = {m.name: MessageDecoder(m) for m in messages}
        self._by_id = {d.frame_id: d for d in self.decoders.values()}

    def split(self, records: np.ndarray) -> Split:
        ids = frame_ids(records["can_id"])
        lengths = records["len"]
        out: dict[str, Columns] = {}
        known = np.zeros(len(records), dtype=bool)
        bad = 0
        for frame_id, dec in self._by_id.items():
            sel = ids == frame_id
            known |= sel
            if not sel.any():
                out[dec.message.name] = {
                    name: np.zeros(0, dtype=np.float64) for name in dec.names
                }
                continue
            ok = sel & (lengths >= dec.length)
            bad += int(np.count_nonzero(sel & ~ok))
            out[dec.message.name] = dec.decode(records["data"][ok])
        return Split(by_name=out, unknown=int(np.count_nonzero(~known)), bad_length=bad)


class TraceWriter:
    """Writes a trace file (used by tests and by stand-in programs; the C side has its own)."""

    def __init__(self, path: str | Path) -> None:
        self._fh: BinaryIO = Path(path).open("wb")
        self._fh.write(HEADER.pack(MAGIC, VERSION, RECORD_SIZE))

    def write(self, frame_id: int, data: bytes, *, fd: bool = True) -> None:
        can_id = frame_id | (CAN_EFF_FLAG if frame_id > CAN_SFF_MASK else 0)
        rec = struct.pack("<IBBBB", can_id, len(data), CANFD_FDF if fd else 0, 0, 0)
        self._fh.write(rec + bytes(data).ljust(64, b"\0"))

    def write_records(self, records: np.ndarray) -> None:
        self._fh.write(np.ascontiguousarray(records, dtype=RECORD_DTYPE).tobytes())

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> TraceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def make_records(frame_id: int, payloads: Sequence[bytes]) -> np.ndarray:
    """Trace records for a list of payloads of one message (test helper, vectorised writers)."""
    rec = np.zeros(len(payloads), dtype=RECORD_DTYPE)
    rec["can_id"] = frame_id
    rec["flags"] = CANFD_FDF
    for i, p in enumerate(payloads):
        rec["len"][i] = len(p)
        rec["data"][i, : len(p)] = np.frombuffer(p, dtype=np.uint8)
    return rec


def decode_file(
    path: str | Path, messages: Sequence[Message], chunk: int = DEFAULT_CHUNK
) -> Iterator[Split]:
    """Chunk by chunk, the decoded messages of one trace file."""
    dec = TraceDecoder(messages)
    for records in TraceFile.open(path).chunks(chunk):
        yield dec.split(records)


def concat(parts: Sequence[Mapping[str, np.ndarray]]) -> Columns:
    """Concatenates per-chunk column dicts (tests and small traces only)."""
    if not parts:
        return {}
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
