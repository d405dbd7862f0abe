"""Lossless capture: merge the plant's and the firmware's trace files by PWM period index.

``build()`` reads the traces chunk by chunk, checks that every message of every trace
holds each period of the merged range exactly once (a gap or a duplicate is a capture loss
that fails the run, with counts), and writes one column per signal as ``.npy`` files in the
capture folder (memory-mapped: memory stays flat however long the run). Then it derives the
columns the metrics use, also chunk by chunk:

- ``theta_true_claim``: the plant's θ (unwrapped) interpolated linearly at the instant the
  firmware's estimate claims (``period·Ts + stamp·10 ns``),
- ``pos_err_deg``: θ̂ - θ at that instant, wrapped to ±180° (electrical),
- ``speed_true_rpm``, ``speed_hat_rpm``, ``speed_err_rpm`` (mechanical r/min),
- ``speed_ref_rpm`` (the scenario's ramped reference, when given), ``i_mag``, ``v_mag``.

Column names are ``<prefix>.<signal>`` with the prefix of the message (``truth``, ``mag``,
``fw``) and the signal names of the DBC.
"""

from __future__ import annotations

import contextlib
import json
import math
import mmap
import shutil
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from cantools.database.can import Message

from rig import protocols
from rig.data.trace import DEFAULT_CHUNK, MessageDecoder, TraceDecoder, TraceFile, frame_ids

TS = protocols.timebase().ts  # PWM period, 100 us: 2 * TBPRD ticks of TBCLK 100 MHz
TICKS_PER_PERIOD = protocols.timebase().period_ticks
TICK_S = TS / TICKS_PER_PERIOD
DEFAULT_POLE_PAIRS = 2  # docs/design.md §5: P = 4 poles

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)

# The columns _derive() adds to the DBC signals: their units and what they are (rig export).
DERIVED_UNITS = {
    "truth.theta_unwrapped": "rad", "speed_true_rpm": "r/min", "i_mag": "A",
    "speed_hat_rpm": "r/min", "v_mag": "V", "theta_true_claim": "rad", "pos_err_deg": "deg",
    "speed_err_rpm": "r/min", "speed_ref_rpm": "r/min",
}
DERIVED_COMMENTS = {
    "truth.theta_unwrapped": "the plant's electrical angle, unwrapped",
    "speed_true_rpm": "true mechanical speed",
    "i_mag": "true current magnitude sqrt(id^2 + iq^2)",
    "speed_hat_rpm": "estimated mechanical speed (omega_hat / pole pairs)",
    "v_mag": "commanded voltage magnitude sqrt(vd^2 + vq^2)",
    "theta_true_claim": "the plant's angle at the instant the firmware's estimate claims",
    "pos_err_deg": "position error theta_hat - theta at that instant, wrapped to +-180 deg "
                   "(electrical)",
    "speed_err_rpm": "estimated - true mechanical speed",
    "speed_ref_rpm": "the scenario's ramped speed reference",
}


@dataclass(frozen=True)
class TraceSpec:
    """A trace file and the messages it must hold for every period, with column prefixes."""

    role: str  # "plant" or "firmware"
    path: Path
    messages: Mapping[str, str]  # message name -> column prefix
    tail_tolerance: int = 0  # periods the trace may end early (the firmware's last ISR)
    also: tuple[str, ...] = ()  # other messages it may hold (not captured, not "unknown")


# the virtual I/O frames plant_rt --trace-vio (and the in-process bench) also trace: the ADC
# frames it sent, the PWM frames it received
VIO_TRACED = ("VIO_ADC_0", "VIO_ADC_1", "VIO_ADC_2", "VIO_PWM")


def default_specs(plant_trace: Path, fw_trace: Path) -> list[TraceSpec]:
    return [
        TraceSpec("plant", plant_trace, {"BENCH_TRUTH": "truth", "BENCH_TRUTH_MAG": "mag"},
                  also=VIO_TRACED),
        TraceSpec("firmware", fw_trace, {"FW_TRACE": "fw"}, tail_tolerance=1),
    ]


def _message(name: str) -> Message:
    for db in protocols.DATABASES:
        try:
            return protocols.database(db).get_message_by_name(name)
        except KeyError:
            continue
    raise KeyError(f"message {name} is in no DBC of protocols/")


@dataclass
class MessageLoss:
    trace: str
    message: str
    records: int = 0
    first: int | None = None
    last: int | None = None
    missing: int = 0  # periods of the merged range without a record
    duplicates: int = 0  # records beyond the first for a period
    out_of_order: int = 0  # records whose period is lower than the one before
    bad_length: int = 0
    outside: int = 0  # records of periods outside the expected range (stray, hijacked)

    @property
    def ok(self) -> bool:
        return (self.missing == 0 and self.duplicates == 0 and self.bad_length == 0
                and self.outside == 0)


@dataclass
class LossReport:
    first_period: int
    last_period: int
    expected: tuple[int, int] | None
    messages: list[MessageLoss] = field(default_factory=list)
    trailing_bytes: dict[str, int] = field(default_factory=dict)
    unknown_records: dict[str, int] = field(default_factory=dict)
    short_end: int = 0  # periods missing at the end beyond the tolerance

    @property
    def lost(self) -> int:
        return sum(m.missing for m in self.messages) + self.short_end

    @property
    def duplicates(self) -> int:
        return sum(m.duplicates for m in self.messages)

    @property
    def ok(self) -> bool:
        return (
            self.lost == 0
            and self.duplicates == 0
            and all(m.ok for m in self.messages)
            and not any(self.trailing_bytes.values())
            and self.last_period >= self.first_period
        )

    def summary(self) -> str:
        if self.ok:
            n = self.last_period - self.first_period + 1
            return f"complete: {n} periods [{self.first_period}, {self.last_period}]"
        parts = []
        if self.lost:
            parts.append(f"{self.lost} missing period records")
        if self.duplicates:
            parts.append(f"{self.duplicates} duplicate records")
        outside = sum(m.outside for m in self.messages)
        if outside:
            parts.append(f"{outside} records outside the run's periods "
                         f"[{self.expected[0] if self.expected else '?'}, "
                         f"{self.expected[1] if self.expected else '?'}]")
        for m in self.messages:
            if not m.ok:
                parts.append(
                    f"{m.trace}/{m.message}: missing {m.missing}, duplicates {m.duplicates}, "
                    f"bad length {m.bad_length}, outside {m.outside}, records {m.records} "
                    f"[{m.first}, {m.last}]"
                )
        if self.short_end:
            parts.append(f"traces end {self.short_end} periods before the expected end")
        for k, v in self.trailing_bytes.items():
            if v:
                parts.append(f"{k} ends in a partial record ({v} bytes)")
        if self.last_period < self.first_period:
            parts.append("no common period range")
        return "capture loss: " + "; ".join(parts)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["lost"] = self.lost
        d["duplicates"] = self.duplicates
        d["ok"] = self.ok
        d["periods"] = max(0, self.last_period - self.first_period + 1)
        return d


class Capture:
    """The merged capture on disk: columns as memory-mapped arrays, one row per period."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        meta = json.loads((folder / "meta.json").read_text())
        self.meta: dict[str, Any] = meta
        self.first_period: int = int(meta["first_period"])
        self.n: int = int(meta["n"])
        self.ts: float = float(meta["ts"])
        self.columns: list[str] = list(meta["columns"])
        self.loss: dict[str, Any] = meta.get("loss", {})
        self._cache: dict[str, np.ndarray] = {}

    def __contains__(self, name: object) -> bool:
        return name in self.columns

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._cache:
            if name not in self.columns:
                raise KeyError(f"capture has no column {name!r}")
            path = self.folder / f"{name}.npy"
            try:
                self._cache[name] = np.load(path, mmap_mode="r")
            except OSError:
                # A file system that cannot map files (9p in the VM runner): read it whole.
                self._cache[name] = np.load(path)
        return self._cache[name]

    def keys(self) -> list[str]:
        return list(self.columns)

    def release(self) -> None:
        """Drops the mapped pages read so far from the resident memory (long captures)."""
        for arr in self._cache.values():
            mm = getattr(arr, "_mmap", None)
            if mm is not None and hasattr(mmap, "MADV_DONTNEED"):
                with contextlib.suppress(OSError, ValueError):
                    mm.madvise(mmap.MADV_DONTNEED)

    def __len__(self) -> int:
        return self.n

    @property
    def duration(self) -> float:
        return self.n * self.ts

    def time(self, start: int = 0, stop: int | None = None) -> npt.NDArray[np.float64]:
        stop = self.n if stop is None else stop
        return (np.arange(start, stop, dtype=np.float64) + self.first_period) * self.ts


class _ColumnStore:
    """Columns as memory-mapped .npy files, so memory stays flat on long captures.

    Some file systems cannot map files (9p, which the VM runner mounts the checkout with):
    then the columns are built in a local temporary folder and moved into place by flush().
    """

    def __init__(self, folder: Path, n: int) -> None:
        self.folder = folder
        self.n = n
        self.cols: dict[str, np.memmap] = {}
        self._work = folder
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    def _open(self, name: str, dtype: npt.DTypeLike) -> np.memmap:
        return np.lib.format.open_memmap(
            self._work / f"{name}.npy", mode="w+", dtype=np.dtype(dtype), shape=(self.n,)
        )

    def create(self, name: str, dtype: npt.DTypeLike, fill: float | None = None) -> np.memmap:
        try:
            arr = self._open(name, dtype)
        except OSError:
            if self._tmp is not None or self.cols:
                raise
            self._tmp = tempfile.TemporaryDirectory(prefix="rig-capture-")
            self._work = Path(self._tmp.name)
            arr = self._open(name, dtype)
        if fill is not None and self.n:
            arr[:] = fill
        self.cols[name] = arr
        return arr

    def flush(self) -> None:
        for arr in self.cols.values():
            arr.flush()
        if self._tmp is not None:
            for name in self.cols:
                shutil.move(self._work / f"{name}.npy", self.folder / f"{name}.npy")
            self.cols = {}
            self._tmp.cleanup()
            self._tmp = None

    def release(self) -> None:
        """Drops the pages written so far from this process's resident memory. The mapping
        is shared: the data stays in the page cache and reaches the file as usual."""
        for arr in self.cols.values():
            mm = getattr(arr, "_mmap", None)
            if mm is not None and hasattr(mmap, "MADV_DONTNEED"):
                with contextlib.suppress(OSError, ValueError):
                    mm.madvise(mmap.MADV_DONTNEED)


def _storage_dtype(dec: MessageDecoder, name: str) -> np.dtype[Any]:
    sig = dec.message.get_signal_by_name(name)
    if sig.is_float and sig.length == 32 and sig.scale == 1 and sig.offset == 0:
        return np.dtype(np.float32)  # exact: the wire value is a float32
    if sig.is_float or sig.scale != 1 or sig.offset != 0:
        return np.dtype(np.float64)
    if sig.length <= 31 or (sig.length == 32 and sig.is_signed):
        return np.dtype(np.int32)
    return np.dtype(np.int64)


def _message_periods(
    spec: TraceSpec, decoders: Mapping[str, MessageDecoder], chunk: int
) -> Iterator[dict[str, np.ndarray]]:
    """Chunk by chunk, the period of every record of each message of a trace."""
    for records in TraceFile.open(spec.path).chunks(chunk):
        ids = frame_ids(records["can_id"])
        out: dict[str, np.ndarray] = {}
        for m in spec.messages:
            d = decoders[m]
            sel = (ids == d.frame_id) & (records["len"] >= d.length)
            out[m] = d.decode_signal(records["data"][sel], "period").astype(np.int64)
        yield out


def _scan(
    spec: TraceSpec, decoders: Mapping[str, MessageDecoder], chunk: int
) -> tuple[dict[str, MessageLoss], int, int]:
    """First pass over a trace: record counts, period span, order, malformed records."""
    tf = TraceFile.open(spec.path)
    losses = {m: MessageLoss(spec.role, m) for m in spec.messages}
    ids_known = [decoders[m].frame_id for m in spec.messages] + [
        int(_message(m).frame_id) for m in spec.also]
    unknown = 0
    prev: dict[str, int | None] = {m: None for m in spec.messages}
    for records in tf.chunks(chunk):
        ids = frame_ids(records["can_id"])
        unknown += int(np.count_nonzero(~np.isin(ids, ids_known)))
        for m in spec.messages:
            d = decoders[m]
            is_m = ids == d.frame_id
            short = is_m & (records["len"] < d.length)
            losses[m].bad_length += int(np.count_nonzero(short))
            p = d.decode_signal(records["data"][is_m & ~short], "period").astype(np.int64)
            if not len(p):
                continue
            ml = losses[m]
            ml.records += len(p)
            lo, hi = int(p.min()), int(p.max())
            ml.first = lo if ml.first is None else min(ml.first, lo)
            ml.last = hi if ml.last is None else max(ml.last, hi)
            last = prev[m]
            ml.out_of_order += int(np.count_nonzero(np.diff(p) < 0))
            if last is not None and p[0] < last:
                ml.out_of_order += 1
            prev[m] = int(p[-1])
    return losses, unknown, tf.trailing_bytes


def _counts(
    spec: TraceSpec, decoders: Mapping[str, MessageDecoder], chunk: int, lo: int, hi: int
) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """Records per period over [lo, hi] for each message (uint16, saturating), and the
    number of records outside [lo, hi]. Memory: (hi - lo + 1) entries, bounded by the
    caller (the run's periods)."""
    size = max(0, hi - lo + 1)
    counts = {m: np.zeros(size, dtype=np.uint16) for m in spec.messages}
    outside = dict.fromkeys(spec.messages, 0)
    for per in _message_periods(spec, decoders, chunk):
        for m, p in per.items():
            inside = (p >= lo) & (p <= hi)
            outside[m] += int(len(p) - np.count_nonzero(inside))
            p = p[inside] - lo
            if len(p) and size:
                c = np.bincount(p, minlength=size)
                counts[m] = np.minimum(counts[m] + c, 65535).astype(np.uint16)
    return counts, outside


class CaptureSpanError(ValueError):
    """The traces span far more periods than the run can have produced."""


def build(
    folder: str | Path,
    specs: Sequence[TraceSpec],
    *,
    expected: tuple[int, int] | None = None,
    pole_pairs: int = DEFAULT_POLE_PAIRS,
    speed_reference: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None = None,
    chunk: int = DEFAULT_CHUNK,
    max_span: int | None = None,
) -> tuple[Capture, LossReport]:
    """Merges the traces into ``folder`` and returns the capture and its loss report.

    ``expected`` is the inclusive period range the run should have produced (lockstep: 0 to
    the last granted period); records outside it are counted as ``outside`` (a loss) and
    memory stays bounded by its length. Without it the range is the overlap of all
    messages, and a trace spanning more than ``max_span`` periods (the scenario's period
    count and a margin) raises CaptureSpanError instead of allocating per period.
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    decoders = {m: MessageDecoder(_message(m)) for s in specs for m in s.messages}

    # pass 1: span, order and malformed records of every message; then counts per period
    losses: list[MessageLoss] = []
    spec_of: dict[str, TraceSpec] = {}
    trailing: dict[str, int] = {}
    unknown: dict[str, int] = {}
    for spec in specs:
        mloss, unk, trail = _scan(spec, decoders, chunk)
        trailing[spec.role] = trail
        unknown[spec.role] = unk
        for m, ml in mloss.items():
            losses.append(ml)
            spec_of[m] = spec
    firsts = [ml.first for ml in losses]
    lasts = [ml.last for ml in losses]
    if any(x is None for x in firsts) or any(x is None for x in lasts):
        start = expected[0] if expected is not None else 0
        end = start - 1
    elif expected is not None:
        start = expected[0]
        end = min(expected[1], *[int(x) for x in lasts if x is not None])
    else:
        start = max(int(x) for x in firsts if x is not None)
        end = min(int(x) for x in lasts if x is not None)
    short_end = 0
    if expected is not None:
        for ml in losses:
            have = start - 1 if ml.last is None else min(ml.last, expected[1])
            short_end = max(short_end, expected[1] - spec_of[ml.message].tail_tolerance - have)
    n = max(0, end - start + 1)

    for spec in specs:
        spans = [ml for ml in losses if ml.trace == spec.role and ml.first is not None]
        if not spans:
            continue
        lo = min(int(ml.first or 0) for ml in spans)
        hi = max(int(ml.last or 0) for ml in spans)
        if expected is not None:
            lo, hi = expected  # what lies outside is counted, never given an array entry
        elif max_span is not None and hi - lo + 1 > max_span:
            raise CaptureSpanError(
                f"the {spec.role} trace spans periods {lo} .. {hi} ({hi - lo + 1} periods), "
                f"more than the {max_span} this run can have produced: stray or corrupt "
                "records")
        counts, outside = _counts(spec, decoders, chunk, lo, hi)
        for ml in spans:
            ml.outside = outside[ml.message]
            c = counts[ml.message]
            ml.duplicates = int(np.sum(np.maximum(c.astype(np.int64) - 1, 0)))
            if n:
                a, b = max(start, lo), min(end, hi)
                inside = int(np.count_nonzero(c[a - lo : b - lo + 1])) if b >= a else 0
                ml.missing = n - inside
    for ml in losses:
        if ml.first is None:
            ml.missing = n

    report = LossReport(start, end, expected, losses, trailing, unknown, short_end)

    # pass 2: scatter every signal into its column
    store = _ColumnStore(out, n)
    fill_nan = not report.ok
    period_col = store.create("period", np.int64)
    if n:
        period_col[:] = np.arange(start, end + 1, dtype=np.int64)
    colnames: list[str] = ["period"]
    for spec in specs:
        for m, prefix in spec.messages.items():
            dec = decoders[m]
            for name in dec.names:
                if name == "period":
                    continue
                dt = _storage_dtype(dec, name)
                fill = math.nan if (fill_nan and dt.kind == "f") else None
                store.create(f"{prefix}.{name}", dt, fill)
                colnames.append(f"{prefix}.{name}")
        tdec = TraceDecoder([decoders[m].message for m in spec.messages])
        for records in TraceFile.open(spec.path).chunks(chunk):
            split = tdec.split(records)
            for m, prefix in spec.messages.items():
                cols = split.by_name[m]
                p = np.asarray(cols["period"], dtype=np.int64)
                sel = (p >= start) & (p <= end)
                if not sel.any():
                    continue
                idx = p[sel] - start
                for name, values in cols.items():
                    if name == "period":
                        continue
                    arr = store.cols[f"{prefix}.{name}"]
                    arr[idx] = np.asarray(values)[sel].astype(arr.dtype, copy=False)
            store.release()

    colnames += _derive(store, start, n, pole_pairs, speed_reference, chunk)
    store.flush()
    meta = {
        "first_period": start,
        "n": n,
        "ts": TS,
        "tick_s": TICK_S,
        "pole_pairs": pole_pairs,
        "columns": colnames,
        "loss": report.to_json(),
    }
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    return Capture(out), report


def _derive(
    store: _ColumnStore,
    start: int,
    n: int,
    pole_pairs: int,
    speed_reference: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None,
    chunk: int,
) -> list[str]:
    cols = store.cols
    names: list[str] = []

    def new(name: str, dtype: npt.DTypeLike = np.float64) -> np.memmap:
        names.append(name)
        return store.create(name, dtype)

    has_truth = "truth.theta_e" in cols
    has_fw = "fw.theta_hat" in cols
    if has_truth:
        unwrapped = new("truth.theta_unwrapped")
        speed_true = new("speed_true_rpm")
        i_mag = new("i_mag")
        prev_raw = prev_unw = math.nan
        for a in range(0, n, chunk):
            b = min(n, a + chunk)
            raw = np.asarray(cols["truth.theta_e"][a:b], dtype=np.float64)
            if math.isnan(prev_unw):
                base_raw, base_unw = raw[0], raw[0]
                d = np.diff(raw, prepend=raw[0])
            else:
                base_raw, base_unw = prev_raw, prev_unw
                d = np.diff(raw, prepend=base_raw)
            d = np.mod(d + math.pi, 2 * math.pi) - math.pi
            unw = base_unw + np.cumsum(d)
            unwrapped[a:b] = unw
            prev_raw, prev_unw = float(raw[-1]), float(unw[-1])
            speed_true[a:b] = np.asarray(cols["truth.omega_m"][a:b], np.float64) * RPM_PER_RAD_S
            i_mag[a:b] = np.hypot(
                np.asarray(cols["truth.id"][a:b], np.float64),
                np.asarray(cols["truth.iq"][a:b], np.float64),
            )
            store.release()
    if has_fw:
        speed_hat = new("speed_hat_rpm")
        v_mag = new("v_mag")
        for a in range(0, n, chunk):
            b = min(n, a + chunk)
            speed_hat[a:b] = (
                np.asarray(cols["fw.omega_hat"][a:b], np.float64) / pole_pairs * RPM_PER_RAD_S
            )
            v_mag[a:b] = np.hypot(
                np.asarray(cols["fw.vd"][a:b], np.float64),
                np.asarray(cols["fw.vq"][a:b], np.float64),
            )
            store.release()
    if has_truth and has_fw:
        claim = new("theta_true_claim")
        err = new("pos_err_deg")
        serr = new("speed_err_rpm")
        unwrapped = cols["truth.theta_unwrapped"]
        speed_true = cols["speed_true_rpm"]
        for a in range(0, n, chunk):
            b = min(n, a + chunk)
            stamp = np.asarray(cols["fw.stamp"][a:b], dtype=np.float64)
            x = np.arange(a, b, dtype=np.float64) + stamp / TICKS_PER_PERIOD
            th = _interp_rows(unwrapped, x, n)
            claim[a:b] = th
            hat = np.asarray(cols["fw.theta_hat"][a:b], dtype=np.float64)
            e = np.mod(np.degrees(hat - th) + 180.0, 360.0) - 180.0
            err[a:b] = e
            w = _interp_rows(speed_true, x, n)
            serr[a:b] = np.asarray(cols["speed_hat_rpm"][a:b], np.float64) - w
            store.release()
    if speed_reference is not None:
        ref = new("speed_ref_rpm")
        for a in range(0, n, chunk):
            b = min(n, a + chunk)
            t = (np.arange(a, b, dtype=np.float64) + start) * TS
            ref[a:b] = speed_reference(t)
            store.release()
    return names


def _interp_rows(column: np.ndarray, x: npt.NDArray[np.float64], n: int) -> np.ndarray:
    """Linear interpolation of ``column`` (one value per row) at fractional rows ``x``.

    NaN where ``x`` lies outside the captured rows."""
    out = np.full(x.shape, np.nan)
    ok = np.isfinite(x) & (x >= 0) & (x <= n - 1)
    if not ok.any():
        return out
    xv = x[ok]
    i0 = np.floor(xv).astype(np.int64)
    i1 = np.minimum(i0 + 1, n - 1)
    f = xv - i0
    lo, hi = int(i0.min()), int(i1.max())
    seg = np.asarray(column[lo : hi + 1], dtype=np.float64)
    y0 = seg[i0 - lo]
    y1 = seg[i1 - lo]
    out[ok] = y0 + (y1 - y0) * f
    return out
