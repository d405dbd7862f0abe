"""CAN log files of a run, and which kind each is.

Two kinds, said in the file where its format has room for it (Vector ASC: a ``//`` comment
line; Vector BLF: a global marker; candump ``-L`` has none: ``result.json`` and the report
say it):

- a live capture (``rig run --can-log``): every frame that crossed the run's channel, as a
  node of the rig's own received it while the run ran (``LiveCapture``). On unixcan that node
  is lossless in lockstep (every sender waits for it, as for the run's nodes), so it holds
  every frame; in real time, or on SocketCAN (a kernel socket buffer that overflows), the
  frames it could not take are counted;
- rebuilt from the traces (``rig export --can-log``): the plant's, the firmware's and the
  rig's frames as each program traced them, timed by their PWM period.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import can

from rig import bus as rigbus

FORMATS = {"asc": ".asc", "blf": ".blf", "log": ".log"}  # --can-log FORMAT -> suffix
LIVE = "live capture"
REBUILT = "rebuilt from the traces"


def writer(path: Path, kind: str, detail: str,
           start: float | None = None) -> can.io.generic.MessageWriter:
    """A python-can writer by the file's suffix (.blf, .asc, else candump -L), saying in the
    file which ``kind`` of log it is where the format allows. ``start``: the time of the first
    frame to come (a rebuilt log's run start; a live one: now). BLF counts every frame's time
    from its first object, so the note must not be later than the frames: a log rebuilt
    after the run put its first frame at the export's time."""
    text = f"{kind}: {detail}"
    suffix = path.suffix.lower()
    out: can.io.generic.MessageWriter
    if suffix == ".blf":
        blf = can.BLFWriter(path)
        blf.log_event(text, timestamp=time.time() if start is None else start)
        out = blf
    elif suffix == ".asc":
        asc = can.ASCWriter(path)
        asc.file.write(f"// {text}\n")  # a comment: ASC readers skip it
        out = asc
    else:
        out = can.CanutilsLogWriter(path, channel="vcan0")
    return out


def says_kind_in_file(path: Path) -> bool:
    """Whether the format has room to say the kind (else only the run's result says it)."""
    return path.suffix.lower() in (".asc", ".blf")


class LiveCapture:
    """A node of the rig's own on the run's channel that writes every frame it receives to a
    log file, from ``start`` to ``stop`` (its own thread)."""

    def __init__(self, transport: str, channel: str, path: Path, *, lossless: bool) -> None:
        self.transport, self.channel, self.path = transport, channel, path
        self.lossless = lossless and transport == "unixcan"
        self.bus = rigbus.open_bus(transport, channel, lossless=self.lossless)
        how = ("a lossless node of the rig's own (every sender waits for it)" if self.lossless
               else "a listening node of the rig's own (the frames it could not take are "
               "counted)" if transport == "unixcan"
               else "a SocketCAN socket of the rig's own (the kernel drops what overflows "
               "its buffer, uncounted)")
        self.detail = f"every frame on {transport} channel {channel}, received by {how}"
        self._writer = writer(path, LIVE, self.detail)
        self.frames = 0
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="rig-can-log", daemon=True)
        self._thread.start()

    @property
    def socket_path(self) -> str:
        return str(getattr(self.bus, "socket_path", ""))

    def _run(self) -> None:
        try:
            while True:
                msg = self.bus.recv(timeout=0.05)
                if msg is not None:
                    self._writer.on_message_received(msg)
                    self.frames += 1
                elif self._stop.is_set():
                    return  # stopped, and nothing more came within the time-out
        except BaseException as exc:  # reported by stop()
            self._error = exc

    def stop(self) -> dict[str, Any]:
        """Takes what is still on its way, closes the file; what it holds, for result.json."""
        self._stop.set()
        self._thread.join(timeout=60.0)
        stats = dict(getattr(self.bus, "stats", {}) or {})
        self.bus.shutdown()
        self._writer.stop()
        missed = int(stats.get("rx_overflows", 0))
        out: dict[str, Any] = {
            "path": self.path.name, "kind": LIVE, "detail": self.detail, "frames": self.frames,
            "missed": missed if self.transport == "unixcan" else None,
            "kind_in_file": says_kind_in_file(self.path),
        }
        if self._error is not None:
            out["error"] = f"{type(self._error).__name__}: {self._error}"
        return out
