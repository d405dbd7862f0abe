"""Drive parameters: the table of protocols/parameters.csv and access over CAN (PARAM_REQ /
PARAM_RESP of protocols/drive.dbc).

Every request carries a sequence number and waits for the response with that number (others
are stale answers of timed-out requests and are ignored); a write is range-checked here first
(the drive checks again), then the value in the response and a second read must both equal the
value sent (float32, as on the wire). Status codes come from the DBC's value table.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from rig import protocols
from rig._paths import data_dir

PARAMS_FILE = "parameters.csv"


@dataclass(frozen=True)
class ParamInfo:
    id: int
    name: str
    unit: str
    minimum: float
    maximum: float
    default: float
    access: str
    description: str

    @property
    def writable(self) -> bool:
        return self.access == "rw"

    def problem(self, value: float) -> str | None:
        if not np.isfinite(value):
            return f"{self.name} = {value}: not finite"
        if not self.writable:
            return f"{self.name} is read-only"
        if value < self.minimum or value > self.maximum:
            return (f"{self.name} = {value:g} outside [{self.minimum:g}, {self.maximum:g}] "
                    f"{self.unit}")
        return None


@dataclass(frozen=True)
class ParamTable:
    by_id: Mapping[int, ParamInfo]
    by_name: Mapping[str, ParamInfo]
    path: Path

    def __iter__(self) -> Iterator[ParamInfo]:
        return iter(sorted(self.by_id.values(), key=lambda p: p.id))

    def __len__(self) -> int:
        return len(self.by_id)

    def lookup(self, key: str | int) -> ParamInfo:
        """By name, by id, or by an id written as a string."""
        if isinstance(key, int) or (isinstance(key, str) and key.isdigit()):
            pid = int(key)
            if pid not in self.by_id:
                raise ParamError(f"no parameter with id {pid} ({self.path.name})")
            return self.by_id[pid]
        if key not in self.by_name:
            close = [n for n in self.by_name if key.split("_")[0] in n][:5]
            hint = f" (similar: {', '.join(close)})" if close else ""
            raise ParamError(f"no parameter named {key!r}{hint}")
        return self.by_name[key]


@cache
def table(path: Path | None = None) -> ParamTable:
    p = path or data_dir("protocols") / PARAMS_FILE
    rows: list[ParamInfo] = []
    with p.open(newline="") as fh:
        for r in csv.DictReader(fh):
            rows.append(ParamInfo(int(r["id"]), r["name"], r["unit"], float(r["min"]),
                                  float(r["max"]), float(r["default"]), r["access"],
                                  r["description"]))
    return ParamTable({r.id: r for r in rows}, {r.name: r for r in rows}, p)


class ParamError(RuntimeError):
    """A parameter request that failed: unknown name, out of range, refused, no answer."""

    def __init__(self, message: str, status: str | None = None) -> None:
        self.status = status
        super().__init__(message)


class ParamTimeout(ParamError):
    pass


class FrameLink(Protocol):
    """What the parameter client needs from the bus (rig.link.bus.BusLink)."""

    def send(self, name: str, values: Mapping[str, Any]) -> None: ...

    def wait_for(self, name: str, predicate: Callable[[Mapping[str, Any]], bool],
                 timeout_s: float, what: str) -> Mapping[str, Any]: ...


OPS = protocols.choices("drive", "PARAM_REQ", "op")
STATUS = protocols.names("drive", "PARAM_RESP", "status")


@dataclass
class ParamClient:
    """PARAM_REQ / PARAM_RESP with sequence numbers, time-outs and read-back."""

    link: FrameLink
    timeout_s: float = 1.0
    retries: int = 1
    params: ParamTable | None = None
    seq: int = 0

    def __post_init__(self) -> None:
        if self.params is None:
            self.params = table()

    @property
    def t(self) -> ParamTable:
        assert self.params is not None
        return self.params

    def _request(self, op: str, pid: int, value: float = 0.0) -> tuple[str, float]:
        last: ParamTimeout | None = None
        for _ in range(self.retries + 1):
            self.seq = (self.seq + 1) % 256
            seq = self.seq
            self.link.send("PARAM_REQ", {"op": OPS[op.lower()], "seq": seq, "param_id": pid,
                                         "value": float(value)})
            t0 = time.monotonic()

            def answers(v: Mapping[str, Any], s: int = seq) -> bool:
                return int(v["seq"]) == s and int(v["param_id"]) == pid and \
                    int(v["op"]) == OPS[op.lower()]

            try:
                resp = self.link.wait_for("PARAM_RESP", answers, self.timeout_s,
                                          f"PARAM_RESP to {op} id {pid} (seq {seq})")
            except TimeoutError as exc:
                last = ParamTimeout(f"{op} parameter {pid}: no PARAM_RESP with seq {seq} "
                                    f"within {self.timeout_s:g} s "
                                    f"({time.monotonic() - t0:.2f} s): {exc}")
                continue
            return STATUS.get(int(resp["status"]), f"STATUS_{int(resp['status'])}"), \
                float(resp["value"])
        assert last is not None
        raise last

    def get(self, key: str | int) -> float:
        info = self.t.lookup(key)
        status, value = self._request("READ", info.id)
        if status != "OK":
            raise ParamError(f"read {info.name} (id {info.id}): {status}", status)
        return value

    def set(self, key: str | int, value: float, *, check_local: bool = True) -> float:
        """Writes, then verifies the echoed value and a fresh read (both float32-equal)."""
        info = self.t.lookup(key)
        if check_local and (why := info.problem(value)):
            raise ParamError(f"refused before sending: {why}", "LOCAL_RANGE")
        status, echoed = self._request("WRITE", info.id, value)
        if status != "OK":
            raise ParamError(f"write {info.name} = {value:g}: the drive answered {status} "
                             f"(value stays {echoed:g})", status)
        again = self.get(info.id)
        want = float(np.float32(value))
        if not (np.float32(echoed) == np.float32(want) == np.float32(again)):
            raise ParamError(f"write {info.name} = {value:g}: echoed {echoed:g}, reads back "
                             f"{again:g}", "READBACK")
        return again

    def list(self) -> list[tuple[ParamInfo, float]]:
        return [(p, self.get(p.id)) for p in self.t]

    def save(self) -> None:
        status, _ = self._request("SAVE", next(iter(self.t)).id)
        if status != "OK":
            raise ParamError(f"save: the drive answered {status}", status)

    def load(self) -> None:
        status, _ = self._request("LOAD", next(iter(self.t)).id)
        if status != "OK":
            raise ParamError(f"load: the drive answered {status}", status)
