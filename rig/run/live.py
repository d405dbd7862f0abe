"""The live Rerun view of a run (``rig run --live``): the telemetry the drive sends (TLM_*,
1 kHz) and the plant's truth, as they arrive: on the bus from the programs, in process from
the bench's outbox (the same frames, ``rig.bench.sil.OutboxPort``)."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable

from rig.data import capture
from rig.link.bus import BusLink, Signals
from rig.results import recording
from rig.run.monitor import Monitor
from rig.run.options import RunOptions
from rig.scenario import Scenario


def open_view(sc: Scenario, opts: RunOptions) -> recording.LiveView | None:
    """The run's live view: the stream given, the web viewer's server, or a native viewer;
    None (said on stderr) when none can open: the run goes on without it."""
    try:
        stream = opts.live_stream or recording.spawn_live(f"{sc.name} (live)", opts.live_url)
        return recording.LiveView(stream)
    except Exception as exc:  # no display, no viewer binary: run without live view
        print(f"rig: live view unavailable ({exc}); running without it", file=sys.stderr)
        return None


class LiveFeed:
    """Logs what ``link`` hears into ``view``; ``period_now`` is the plant's period as the
    rig knows it (the telemetry carries 16 bits of it)."""

    def __init__(self, view: recording.LiveView, link: BusLink, monitor: Monitor,
                 period_now: Callable[[], int | None]) -> None:
        self.view = view
        self.monitor = monitor
        self.period_now = period_now
        self._last_period = 0
        link.on("TLM_POS", self._position)
        link.on("TLM_CUR", self._current)
        link.on("TLM_REF", self._reference)
        link.on("TLM_PARAM", self._parameters)
        link.on("BENCH_TRUTH", self._truth)

    def _full_period(self, p16: int) -> int:
        """The period of a 16-bit period number, next to the plant's own report (or, where
        nobody reports it, as a real drive's bench: next to the last one worked out)."""
        base = self.period_now()
        if base is None:
            base = self._last_period
        cand = (base & ~0xFFFF) | p16
        if cand > base + 0x8000:
            cand -= 0x10000
        elif cand < base - 0x8000:
            cand += 0x10000
        self._last_period = max(cand, 0)
        return self._last_period

    def _position(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("speed", p, {"estimated": float(v["speed_hat"])})
        values = {"θ est": float(v["theta_hat"]), "θ": math.nan}  # θ: when the truth is known
        th = self.monitor.true_angle(int(v["period"]))
        if th is not None:
            true_deg = math.degrees(th) % 360.0
            values["θ"] = true_deg
            err = (float(v["theta_hat"]) - true_deg + 180.0) % 360.0 - 180.0
            self.view.add("error", p, {"θ est - θ": err})
        self.view.add("position", p, values)

    def _current(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("current", p, {"id": float(v["id"]), "iq": float(v["iq"])})
        self.view.add("torque", p, {"Te est": float(v["te_hat"])})

    def _reference(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("speed_ref", p, {"reference": float(v["speed_ref"])})

    def _parameters(self, v: Signals) -> None:
        p = self._full_period(int(v["period"]))
        self.view.add("params", p, {"Ld est (mH)": float(v["ld_hat"]) * 1e3,
                                    "Lq est (mH)": float(v["lq_hat"]) * 1e3,
                                    "λm est": float(v["lambda_hat"])})

    def _truth(self, v: Signals) -> None:
        p = int(v["period"])
        self.view.add("speed_true", p,
                      {"true": float(v["omega_m"]) * capture.RPM_PER_RAD_S})
        self.view.add("torque_true", p, {"Te": float(v["te"]), "TL": float(v["tl"])})

    def flush(self) -> None:
        self.view.flush()

    def close(self) -> None:
        self.view.close()
