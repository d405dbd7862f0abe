"""Issue 16.8: output-path problems are exit 3 with a message before any program starts,
and a result file is whole or absent (never truncated by a full disk)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from rig import outputs
from rig.cli import main as rig_main


@pytest.mark.parametrize("where", ["through_a_file", "proc"])
def test_rig_run_refuses_an_output_path_it_cannot_use(
        where: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if where == "through_a_file":
        (tmp_path / "plain").write_text("a file")
        out = tmp_path / "plain" / "run"
    else:
        out = Path("/proc/self/rig-out")
    code = rig_main(["run", "smoke", "--bus", "unixcan", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 3, err
    assert "output folder" in err and str(out) in err
    assert "Traceback" not in err
    assert "plant_rt" not in err  # nothing was started


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_folder_is_refused(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    with pytest.raises(outputs.OutputError, match="cannot write"):
        outputs.prepare(ro)


def test_not_enough_room_is_refused(tmp_path: Path) -> None:
    with pytest.raises(outputs.OutputError, match="MB free"):
        outputs.prepare(tmp_path, periods=10**15)


WRITER = r"""
import resource, signal, sys
from pathlib import Path
from rig import outputs
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))  # a disk that fills at 1000 bytes
try:
    outputs.write_text(Path(sys.argv[1]), "x" * 5000)
except outputs.OutputError as exc:
    print("refused:", exc)
"""


def test_a_full_disk_leaves_the_previous_result_whole(tmp_path: Path) -> None:
    result = tmp_path / "result.json"
    outputs.write_text(result, '{"complete": true}')
    done = subprocess.run([sys.executable, "-c", WRITER, str(result)], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "refused: cannot write" in done.stdout
    assert result.read_text() == '{"complete": true}'
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]  # no temporary left
