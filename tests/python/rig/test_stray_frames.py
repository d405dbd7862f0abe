"""Issue 16.1 end to end: stray VIO_ADC frames on the channel during a lockstep run (the
campaign's 20 frames with a far period hijacked fw_host's ADC sequence for good, and the
rig's capture then allocated ~3e9 counters and was OOM-killed) are rejected and counted;
the run goes on with its own plant to its end, and then fails as foreign traffic (issue
23.7: frames no node of the run sent; its data is not its own)."""

from __future__ import annotations

import threading
import time
import uuid
from pathlib import Path

import can

from rig import protocols, scenario
from rig.run import runner


def _inject(out: Path, channel: str, done: threading.Event, drops: list[int]) -> None:
    deadline = time.monotonic() + 60
    while not (out / "fw.ready").exists() and time.monotonic() < deadline:
        time.sleep(0.005)
    m = protocols.database("vio").get_message_by_name("VIO_ADC_0")
    bus = can.Bus(interface="unixcan", channel=channel)
    try:
        for k in range(20):
            values = {s.name: 0 for s in m.signals} | {
                "period": 3_000_000_000 + k, "n_soc": 1, "vdc_code": 32768,
                "ia_0": 32768, "ib_0": 32768}
            bus.send(can.Message(arbitration_id=m.frame_id, data=m.encode(values),
                                 is_fd=True, is_extended_id=False))
    finally:
        drops.append(int(bus.stats["tx_drops"]))  # type: ignore[attr-defined]
        bus.shutdown()
        done.set()


def test_stray_adc_frames_do_not_take_the_run_over(tmp_path: Path) -> None:
    channel = f"sf{uuid.uuid4().hex[:8]}"
    out = tmp_path / "run"
    done = threading.Event()
    drops: list[int] = []
    injector = threading.Thread(target=_inject, args=(out, channel, done, drops), daemon=True)
    injector.start()
    sc = scenario.load_scenario(scenario.find("smoke"))
    result = runner.run_scenario(sc, runner.RunOptions(out=out, bus="unixcan", channel=channel,
                                                       progress=False, record=False))
    injector.join(timeout=60)
    assert done.is_set()
    c = result.counters
    assert result.failure is not None and result.failure.kind == "foreign_traffic", \
        result.failure
    assert "VIO_ADC_0" in result.failure.message and result.status == "error"
    assert c["plant.periods"] == 5000 and c["firmware.isr"] == 5000  # the run got to its end
    assert c["firmware.resyncs"] == 0
    # every stray frame that reached fw_host (on the bus since fw.ready) was rejected, none
    # followed; a busy receiver's full queue costs the sender counted drops (any receiver)
    rejected = c["firmware.rejects.future_period"] + c["firmware.rejects.stale_period"]
    assert rejected >= 1 and rejected + drops[0] >= 20, (rejected, drops)
    assert result.capture_loss["lost"] == 0
