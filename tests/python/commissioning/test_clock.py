"""Bench clocks on a real bus: the wall clock keeps the 10 ms drive-command cycle, the
lockstep clock grants exactly the periods asked for; and a virtual bench in real time runs
the connectivity step on the wall clock (as a real bench does)."""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from commission_support import MakeDesc

from rig import bus as rigbus
from rig import protocols
from rig.commissioning import commission
from rig.link.bus import BusLink
from rig.link.clock import BenchTimeout, WallClock


@pytest.fixture
def listener(unix_channel: str) -> Iterator[can.BusABC]:
    cmd = protocols.database("drive").get_message_by_name("DRIVE_CMD")
    bus = rigbus.open_bus("unixcan", unix_channel,
                          can_filters=[{"can_id": cmd.frame_id, "can_mask": 0x7FF}])
    yield bus
    bus.shutdown()


def test_wall_clock_cycles_every_10_ms(unix_channel: str, listener: can.BusABC) -> None:
    link = BusLink.open("unixcan", unix_channel)
    try:
        clock = WallClock(link)
        sent: list[float] = []

        def cycle() -> None:
            link.send("DRIVE_CMD", {"enable": 0, "fault_reset": 0, "ctrl_mode": 0,
                                    "fw_mode": 0, "alive": len(sent) % 256,
                                    "speed_ref": 0.0, "iq_ref": 0.0})
            sent.append(time.monotonic())

        idle: list[float] = []
        clock.on_cycle(cycle)
        clock.on_idle(lambda: idle.append(time.monotonic()))
        t0 = clock.now()
        clock.advance(0.3)
        assert 0.3 <= clock.now() - t0 < 0.4
        gaps = [b - a for a, b in itertools.pairwise(sent)]
        assert len(sent) <= 32 and min(gaps) > 0.0005  # one per 10 ms, never a burst
        assert sorted(gaps)[len(gaps) // 2] == pytest.approx(0.01, abs=0.002)
        assert 2 <= len(idle) <= 4  # every 100 ms
        got = 0
        while listener.recv(timeout=0.1) is not None:
            got += 1
        assert got == len(sent)
        with pytest.raises(BenchTimeout, match=r"not within 0\.05 s"):
            clock.wait(lambda: False, 0.05, "nothing")
    finally:
        link.close()


def test_lockstep_clock_grants_exact_periods(make_desc: MakeDesc, tmp_path: Path) -> None:
    from rig.commissioning.session import BenchSession
    from rig.link.clock import LockstepClock

    s = BenchSession(make_desc('virtual.programs=["plant_rt", "fw_host"]'), tmp_path)
    s.start()
    try:
        clock = s.clock
        assert isinstance(clock, LockstepClock)
        p0 = clock.period
        grants = clock.grants
        clock.advance(0.1234)
        assert clock.period == p0 + 1234
        assert clock.grants - grants == 3  # 0.05 s grants: 500 + 500 + 234
        assert s.link.wait_for("BENCH_PROGRESS", lambda v: True, 1.0, "progress")[
            "period"] == p0 + 1234
    finally:
        s.close()


def test_connectivity_on_the_wall_clock(make_desc: MakeDesc, tmp_path: Path) -> None:
    """A bench that runs on the wall clock, as the real one: fw_host (the DSP stand-in, no
    plant: it idles in INIT) and the load bench."""
    desc = make_desc("clock.mode=wall", 'virtual.programs=["fw_host", "loadbench"]')
    assert not desc.lockstep
    run = commission.commission(desc, ["connectivity"], tmp_path / "run")
    assert run.passed, run.report_path.read_text()
    checks = {c.name: c.detail for c in run.step("connectivity").checks}
    assert checks["bench clock"].startswith("wall:")
    assert checks["drive state"] == "INIT"
