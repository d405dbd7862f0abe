"""A scenario's start loads only what the closed loop needs (``rig bench startup`` measures
the CPU it takes): the libraries a run needs only afterwards (rerun for the recording,
matplotlib for the figures, asammdf for export, pyarrow and dask for sweeps) are not loaded
before its first grant, and python-can's MF4 support, whose asammdf import is deferred
(rig._defer_mf4), still works when used."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from rig.benchmarks import startup


def test_nothing_heavy_is_loaded_before_the_closed_loop_starts(tmp_path: Path) -> None:
    mark, _imports, _cpu, _wall = startup._child(
        ["run", "smoke", "--bus", "inproc", "--no-record", "--quiet", "--out",
         str(tmp_path / "run")])
    assert mark["loaded"] == []  # none of startup.HEAVY
    assert (tmp_path / "run" / "result.json").is_file()


def test_python_can_mf4_still_writes_and_reads_after_the_rig(tmp_path: Path) -> None:
    code = f"""
import sys
import rig.link.bus  # imports python-can (and cantools) the rig's way
import can
assert "asammdf" not in sys.modules, "asammdf was imported with can"
path = {str(tmp_path / "x.mf4")!r}
writer = can.Logger(path)
assert isinstance(writer, can.io.mf4.MF4Writer) and isinstance(writer, can.MF4Writer)
for i in range(20):
    writer.on_message_received(can.Message(timestamp=1.0 + i / 100, arbitration_id=0x100 + i,
                                           data=bytes([i] * 8)))
writer.stop()
got = list(can.LogReader(path))
assert [m.arbitration_id for m in got] == [0x100 + i for i in range(20)], got
assert bytes(got[7].data) == bytes([7] * 8)
print("ok")
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, check=False)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_largest_imports_reads_importtime_lines() -> None:
    text = ("import time: self [us] | cumulative | imported package\n"
            "import time:       100 |        150 |   numpy._core\n"
            "import time:        50 |       2000 | numpy\n"
            "import time:        10 |        500 | rig\n")
    total, top = startup.largest_imports(text, 1)
    assert total == 2.5 and top == [{"module": "numpy", "cumulative_ms": 2.0}]
