"""Fixtures of the rig's own tests: helper import path, the hil plugin, stand-in programs."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from pathlib import Path

# numpy before any test: pytester (test_plugin.py) restores sys.modules after its test, and
# numpy's C core cannot be imported a second time into a process. The rig imports numpy
# lazily, so without this the first import could fall inside such a test.
import numpy  # noqa: F401
import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def pytest_configure(config: pytest.Config) -> None:
    # The plugin is normally loaded through its pytest11 entry point; register it here when
    # the package is not installed with that entry point.
    if not config.pluginmanager.has_plugin("hil"):
        import rig.pytest_plugin as plugin

        config.pluginmanager.register(plugin, "hil")


@pytest.fixture(scope="session")
def fake_bin(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with stand-in ``plant_rt`` and ``fw_host`` programs (for HIL_BIN_DIR)."""
    d = tmp_path_factory.mktemp("fakebin")
    for name, role in (("plant_rt", "plant"), ("fw_host", "fw")):
        p = d / name
        p.write_text(
            f"#!{sys.executable}\n"
            "import sys\n"
            f"sys.path.insert(0, {str(HERE)!r})\n"
            "from standins.fake_nodes import main\n"
            f"sys.exit(main({role!r}))\n"
        )
        p.chmod(0o755)
    return d


@pytest.fixture
def with_fakes(fake_bin: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """HIL_BIN_DIR pointing at the stand-ins for the duration of a test."""
    monkeypatch.setenv("HIL_BIN_DIR", str(fake_bin))
    yield fake_bin


_serial = [0]


@pytest.fixture
def channel() -> str:
    """A unixcan channel no other test (or xdist worker) uses."""
    _serial[0] += 1
    return f"t-{os.getpid()}-{_serial[0]}"


@pytest.fixture(autouse=True)
def _private_unixcan_dir(tmp_path_factory: pytest.TempPathFactory,
                         monkeypatch: pytest.MonkeyPatch) -> None:
    # keep the tests' unixcan sockets out of the shared /tmp/unixcan
    base = tmp_path_factory.getbasetemp() / "unixcan"
    base.mkdir(exist_ok=True)
    monkeypatch.setenv("UNIXCAN_DIR", str(base))
