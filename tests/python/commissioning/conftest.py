"""Fixtures of the commissioning tests: the virtual bench of rig/benches/virtual.toml on a
bus channel of its own (unixcan here; SocketCAN vcan0 for the tests marked vcan), Modbus on
a free loopback port."""

from __future__ import annotations

import contextlib
import shutil
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from rig import _paths
from rig.bench import description as bd
from rig.commissioning.session import BenchSession

sys.path.insert(0, str(Path(__file__).resolve().parent))

from commission_support import MakeDesc
from waits import EVENT_S, ceiling

# The virtual bench with wall-time ceilings a loaded machine cannot reach (the console's and
# Modbus's replies, the load bench's watchdog, the programs' readiness): a test that tests
# one of these time-outs names its own after these.
GENEROUS = [f"console.timeout_s={EVENT_S:g}", f"modbus.timeout_s={EVENT_S:g}",
            f"modbus.watchdog_timeout_ms={min(60000, round(EVENT_S * 1e3))}",
            f"virtual.ready_timeout_s={ceiling(300.0):g}"]


@pytest.fixture(scope="session")
def programs_built() -> None:
    for name in ("plant_rt", "fw_host"):
        try:
            _paths.binary(name)
        except FileNotFoundError as exc:
            pytest.skip(f"{name} is not built: {exc}")


def _unix_channel() -> Iterator[str]:
    from rig.bus import unixcan

    name = f"cm-{uuid.uuid4().hex[:10]}"
    yield name
    with contextlib.suppress(OSError):
        shutil.rmtree(unixcan.base_dir() / name)


@pytest.fixture
def unix_channel() -> Iterator[str]:
    yield from _unix_channel()


@pytest.fixture
def make_desc(unix_channel: str, programs_built: None) -> MakeDesc:
    """``make_desc(*overrides)``: rig/benches/virtual.toml on this test's unixcan channel."""

    def make(*overrides: str) -> bd.BenchDescription:
        return bd.load("virtual", ["can.transport=unixcan", f"can.channel={unix_channel}",
                                   "modbus.port=0", *GENEROUS, *overrides])

    return make


@pytest.fixture(scope="module")
def module_bench(tmp_path_factory: pytest.TempPathFactory, programs_built: None
                 ) -> Iterator[BenchSession]:
    """A running virtual bench (lockstep) shared by a module's tests, console and Modbus
    open. Tests leave the drive disabled and the load off."""
    chan_gen = _unix_channel()
    chan = next(chan_gen)
    desc = bd.load("virtual", ["can.transport=unixcan", f"can.channel={chan}", "modbus.port=0",
                               *GENEROUS])
    s = BenchSession(desc, tmp_path_factory.mktemp("bench"))
    try:
        s.start()
        s.require()
        s.clock.advance(0.01)
        yield s
    finally:
        with contextlib.suppress(Exception):
            s.safe_stop()
        s.close()
        with contextlib.suppress(StopIteration):
            next(chan_gen)
