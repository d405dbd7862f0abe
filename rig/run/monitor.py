"""What a scenario run hears on the bus (through ``rig.link.bus``): the counters of the
bench and the firmware, the drive's faults, and the latest truth and estimate for the
progress line."""

from __future__ import annotations

import math
from typing import Any

from rig import protocols
from rig.data import capture
from rig.link.bus import BusLink, Signals

FAULT_STATE = protocols.choices("drive", "DRIVE_STATUS", "state")["fault"]
TRUTH_KEPT = 4096  # periods of truth kept to match estimates against
TRUTH_LOOKBACK = 20  # periods back to the truth before, for the rotation per period


class Monitor:
    def __init__(self, link: BusLink) -> None:
        self.link = link
        self.counter_log: list[tuple[int, dict[str, float]]] = []  # every BENCH_COUNTERS
        self.faults = 0  # times the drive went into FAULT
        self._last_state: int | None = None
        self._truth_by_p16: dict[int, float] = {}
        link.on("BENCH_COUNTERS", self._counters)
        link.on("DRIVE_STATUS", self._status)
        link.on("BENCH_TRUTH", self._truth)

    def _counters(self, v: Signals) -> None:
        self.counter_log.append((int(v["period"]), {k: float(x) for k, x in v.items()}))

    def _status(self, v: Signals) -> None:
        state = int(v["state"])
        if state == FAULT_STATE and self._last_state != FAULT_STATE:
            self.faults += 1
        self._last_state = state

    def _truth(self, v: Signals) -> None:
        self._truth_by_p16[int(v["period"]) & 0xFFFF] = float(v["theta_e"])
        if len(self._truth_by_p16) > TRUTH_KEPT:
            self._truth_by_p16.clear()

    def true_angle(self, period16: int) -> float | None:
        """θ (rad) of the plant at a period (the 16 bits telemetry carries), when heard."""
        return self._truth_by_p16.get(period16)

    def snapshot(self) -> tuple[float | None, float | None]:
        """(speed r/min, position error deg) for the progress line, when the bus shows them."""
        speed = err = None
        truth = self.link.latest.get("BENCH_TRUTH")
        if truth:
            speed = float(truth["omega_m"]) * capture.RPM_PER_RAD_S
        pos = self.link.last("TLM_POS")
        if pos is not None:
            if speed is None:
                speed = float(pos["speed_hat"])
            # θ̂ of period k is the estimate late in that period (at its stamp, which TLM_POS
            # does not carry): against the truth at the period's start it would show about one
            # period of rotation as error (1.2° at 1000 r/min). Compared with the truth carried
            # on to the period's end (at the rotation per period since the last truth heard
            # before it), what is left is at most the stamp's distance to the end.
            k = int(pos["period"])
            th = self.true_angle(k)
            for back in range(1, TRUTH_LOOKBACK + 1):
                before = self.true_angle((k - back) & 0xFFFF)
                if th is not None and before is not None:
                    th += math.remainder(th - before, 2.0 * math.pi) / back
                    break
            if th is not None:
                err = (float(pos["theta_hat"]) - math.degrees(th) + 180.0) % 360.0 - 180.0
        return speed, err

    def counters(self) -> dict[str, float]:
        out: dict[str, float] = {}
        latest: dict[str, Any] = self.link.latest
        for name, prefix in (("BENCH_COUNTERS", "bench"), ("BENCH_REJECTS", "rejects")):
            for k, v in latest.get(name, {}).items():
                if k != "period":
                    out[f"{prefix}.{k}"] = float(v)
        status = latest.get("HEARTBEAT")
        if status:
            out["firmware.isr_overruns_heartbeat"] = float(status["isr_overruns"])
        drive = latest.get("DRIVE_STATUS")
        if drive:
            out["firmware.rx_rejected_status"] = float(drive["rx_rejected"])
            out["firmware.fault_code_last"] = float(drive["fault_code"])
        for reason, count in self.link.decoder.rejected.items():
            out[f"rig.rejected.{reason}"] = float(count)
        return out
