"""Shared fixtures of the Python suites."""

from __future__ import annotations

import os
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from rig import bus as rigbus

# the tests' shared helpers (waits.py: the ceilings of every wait) import as top-level modules
sys.path.insert(0, str(Path(__file__).resolve().parent))


def available_transports() -> list[str]:
    """unixcan always; socketcan where the kernel has CAN and vcan0 exists (the VM)."""
    found = ["unixcan"]
    if rigbus.kernel_has_can() and rigbus.interface_exists("vcan0"):
        found.insert(0, "socketcan")
    return found


@pytest.fixture(params=available_transports())
def transport(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def channel(transport: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A channel nobody else uses: a fresh unixcan folder, or vcan0 (one test at a time)."""
    if transport == "socketcan":
        yield "vcan0"
        return
    base = tmp_path_factory.mktemp("unixcan")
    old = os.environ.get("UNIXCAN_DIR")
    os.environ["UNIXCAN_DIR"] = str(base)
    try:
        yield f"t{uuid.uuid4().hex[:8]}"
    finally:
        if old is None:
            os.environ.pop("UNIXCAN_DIR", None)
        else:
            os.environ["UNIXCAN_DIR"] = old
