"""The in-process bench (``bench/``, ``libsilbench.so``): plant and control core in one process.

Software in the loop: the real plant and the real firmware core linked together, with the bus
programs' own frame code between them (``bench/include/sil_bench.h``). The rig drives it as it
drives the bus in lockstep: the same DRIVE_LIMITS, DRIVE_CMD and LOAD_CMD frames (encoded by
``rig.link.bus.BusLink``) go in before each grant, and a grant runs the bench up to its
``run_until``. The bench writes the same trace files as ``plant_rt`` and ``fw_host``.
"""

from __future__ import annotations

import ctypes as C
import json
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can

from rig import _paths

INPROC = "inproc"  # the --bus name of the in-process bench
LIBRARY = "libsilbench.so"


class BenchError(RuntimeError):
    """The bench could not open (bad configuration, trace not writable) or its loop broke."""


class _Config(C.Structure):
    _fields_ = [
        ("profile_path", C.c_char_p),
        ("plant_sets", C.POINTER(C.c_char_p)),
        ("n_plant_sets", C.c_int),
        ("fw_sets", C.POINTER(C.c_char_p)),
        ("n_fw_sets", C.c_int),
        ("plant_trace", C.c_char_p),
        ("fw_trace", C.c_char_p),
        ("trace_vio", C.c_int),
        ("fw_from_plant", C.c_int),
    ]


_lib: C.CDLL | None = None


def library() -> C.CDLL:
    """The loaded ``libsilbench.so`` (loaded once per process)."""
    global _lib
    if _lib is None:
        lib = C.CDLL(str(_paths.library(LIBRARY)))
        lib.sil_bench_open.restype = C.c_void_p
        lib.sil_bench_open.argtypes = [C.POINTER(_Config), C.c_char_p, C.c_size_t]
        lib.sil_bench_close.restype = C.c_int
        lib.sil_bench_close.argtypes = [C.c_void_p]
        lib.sil_bench_frame.restype = C.c_int
        lib.sil_bench_frame.argtypes = [C.c_void_p, C.c_uint32, C.c_int, C.c_char_p, C.c_uint8,
                                        C.c_char_p, C.c_size_t]
        lib.sil_bench_run_until.restype = C.c_long
        lib.sil_bench_run_until.argtypes = [C.c_void_p, C.c_uint32]
        lib.sil_bench_next_period.restype = C.c_uint32
        lib.sil_bench_next_period.argtypes = [C.c_void_p]
        lib.sil_bench_counters_json.restype = C.c_int
        lib.sil_bench_counters_json.argtypes = [C.c_void_p, C.c_char_p, C.c_size_t]
        lib.sil_bench_journal_open.restype = C.c_int
        lib.sil_bench_journal_open.argtypes = [C.c_void_p, C.c_char_p, C.POINTER(C.c_uint32),
                                               C.POINTER(C.c_uint32), C.c_int, C.c_char_p,
                                               C.c_size_t]
        lib.sil_bench_outbox.restype = None
        lib.sil_bench_outbox.argtypes = [C.c_void_p, C.c_uint32, C.c_uint32]
        lib.sil_bench_take_frame.restype = C.c_int
        lib.sil_bench_take_frame.argtypes = [C.c_void_p, C.POINTER(C.c_uint32), C.c_char_p,
                                             C.POINTER(C.c_uint8)]
        lib.sil_bench_outbox_dropped.restype = C.c_uint64
        lib.sil_bench_outbox_dropped.argtypes = [C.c_void_p]
        lib.sil_bench_hardware_param.restype = C.c_char_p
        lib.sil_bench_hardware_param.argtypes = [C.c_int, C.POINTER(C.c_char_p),
                                                 C.POINTER(C.c_double)]
        _lib = lib
    return _lib


def hardware_params() -> dict[str, tuple[str, float]]:
    """The bench's own firmware-from-plant table (for C callers): parameter -> (key, factor)."""
    lib = library()
    out: dict[str, tuple[str, float]] = {}
    i = 0
    while True:
        key = C.c_char_p()
        factor = C.c_double()
        name = lib.sil_bench_hardware_param(i, C.byref(key), C.byref(factor))
        if name is None:
            return out
        out[name.decode()] = ((key.value or b"").decode(), factor.value)
        i += 1


def _strings(items: Sequence[str]) -> tuple[Any, list[bytes]]:
    raw = [s.encode() for s in items]
    arr = (C.c_char_p * max(1, len(raw)))(*raw)
    return arr, raw


class SilBench:
    """One bench: open with the plant's profile and ``--set`` overrides and fw_host's
    ``--set`` parameters, feed frames, run grants, read the counters, close."""

    def __init__(self, profile: Path | None, plant_sets: Sequence[str], fw_sets: Sequence[str],
                 plant_trace: Path | None = None, fw_trace: Path | None = None,
                 trace_vio: bool = False) -> None:
        self._lib = library()
        psets, self._keep_p = _strings(plant_sets)
        fsets, self._keep_f = _strings(fw_sets)
        self._keep = [psets, fsets]
        cfg = _Config(
            str(profile).encode() if profile else None, psets, len(plant_sets), fsets,
            len(fw_sets), str(plant_trace).encode() if plant_trace else None,
            str(fw_trace).encode() if fw_trace else None, int(trace_vio), 0,
        )
        err = C.create_string_buffer(1024)
        handle = self._lib.sil_bench_open(C.byref(cfg), err, len(err))
        if not handle:
            raise BenchError(err.value.decode(errors="replace"))
        self._b: int | None = handle
        self.rejected: list[str] = []

    def _handle(self) -> int:
        if self._b is None:
            raise BenchError("the bench is closed")
        return self._b

    def frame(self, can_id: int, data: bytes, fd: bool) -> int:
        """0 taken, 1 not for a bench node, -1 rejected (counted; reason kept)."""
        err = C.create_string_buffer(256)
        r = int(self._lib.sil_bench_frame(self._handle(), can_id, int(fd), bytes(data), len(data),
                                          err, len(err)))
        if r < 0:
            self.rejected.append(err.value.decode(errors="replace"))
        return r

    def journal(self, path: Path, windows: Sequence[tuple[int, int]] = ()) -> None:
        """Journals every call into the control core from now on (``core_journal.h``):
        everything, or the ISR index windows ``(start, length)`` each with the state at its
        start (``rig.target_m4`` replays it on another build of the core)."""
        starts = (C.c_uint32 * max(1, len(windows)))(*[w[0] for w in windows])
        lengths = (C.c_uint32 * max(1, len(windows)))(*[w[1] for w in windows])
        err = C.create_string_buffer(512)
        if self._lib.sil_bench_journal_open(self._handle(), str(path).encode(), starts, lengths,
                                            len(windows), err, len(err)) != 0:
            raise BenchError(err.value.decode(errors="replace"))

    def outbox(self, tlm_div: int, truth_every: int) -> None:
        """Keeps the frames the bus programs would send to the rig (fw_host's TLM_* every
        ``tlm_div`` speed-loop periods, plant_rt's BENCH_TRUTH every ``truth_every``
        periods) for ``take_frames``; the control loop computes the same either way."""
        self._lib.sil_bench_outbox(self._handle(), tlm_div, truth_every)

    def take_frames(self) -> list[tuple[int, bytes]]:
        """The outbox's frames, oldest first, as (can_id, data); it is empty after."""
        can_id, length, data = C.c_uint32(), C.c_uint8(), C.create_string_buffer(64)
        frames = []
        while self._lib.sil_bench_take_frame(self._handle(), C.byref(can_id), data,
                                             C.byref(length)):
            frames.append((can_id.value, data.raw[:length.value]))
        return frames

    @property
    def outbox_dropped(self) -> int:
        """Frames the outbox had no room for (not taken in time)."""
        return int(self._lib.sil_bench_outbox_dropped(self._handle()))

    def run_until(self, run_until: int) -> int:
        n = int(self._lib.sil_bench_run_until(self._handle(), run_until))
        if n < 0:
            raise BenchError(f"the closed loop broke at period {self.next_period}: "
                             f"{self.counters()}")
        return n

    @property
    def next_period(self) -> int:
        return int(self._lib.sil_bench_next_period(self._handle()))

    def counters(self) -> dict[str, Any]:
        buf = C.create_string_buffer(4096)
        n = self._lib.sil_bench_counters_json(self._handle(), buf, len(buf))
        if n >= len(buf):
            buf = C.create_string_buffer(n + 1)
            self._lib.sil_bench_counters_json(self._handle(), buf, len(buf))
        data: dict[str, Any] = json.loads(buf.value.decode())
        return data

    def close(self) -> None:
        """Flushes and closes the traces (BenchError when a trace write failed)."""
        if self._b is None:
            return
        rc = self._lib.sil_bench_close(self._b)
        self._b = None
        if rc != 0:
            raise BenchError("trace write error")

    def __enter__(self) -> SilBench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class BenchPort:
    """What the rig's link (``rig.link.bus.BusLink``) sends on in process: hands its frames
    to the bench (a stand-in for ``can.BusABC`` with the same message objects, so both paths
    encode identically)."""

    def __init__(self, bench: SilBench) -> None:
        self.bench = bench
        self.refused_faulted: list[str] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.bench.frame(int(msg.arbitration_id), bytes(msg.data), bool(msg.is_fd))

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """Nothing: the bench answers no frames (its counters are read directly)."""
        return None

    def shutdown(self) -> None:
        """The bench closes with its run (``SilBench.close``)."""

    def send_faulted(self, msg: can.Message) -> None:
        """A frame the rig corrupted on purpose (a scenario fault): its refusal is the
        receiver's protection at work, kept apart from the rig's own errors."""
        n = len(self.bench.rejected)
        self.send(msg)
        self.refused_faulted += self.bench.rejected[n:]
        del self.bench.rejected[n:]


class OutboxPort:
    """The frames the bench's programs send to the rig (``SilBench.outbox``) as a bus that a
    listening link reads (``BusLink.pump``): what a live view of an in-process run hears.
    Nothing goes the other way (the rig's frames go in through ``BenchPort``)."""

    def __init__(self, bench: SilBench) -> None:
        self.bench = bench
        self._frames: deque[tuple[int, bytes]] = deque()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise BenchError("the bench's outbox only listens: frames go in through BenchPort")

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if not self._frames:
            self._frames.extend(self.bench.take_frames())
        if not self._frames:
            return None
        can_id, data = self._frames.popleft()
        return can.Message(arbitration_id=can_id, data=data, is_extended_id=False,
                           is_fd=len(data) > 8)

    def shutdown(self) -> None:
        """The bench closes with its run (``SilBench.close``)."""
