"""Issue 23.11: ``rig commission --save-params FILE`` saves what the run identified (standstill
identified rs, Ld and Lq, reported PASSED, exited 1 and wrote nothing), writes the file whole
or not at all, never through a symbolic link, and replaces only a file it wrote itself; FILE
is checked before the run starts."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from commission_support import paper_truth

from rig.cli import main as rig_main
from rig.drive import commissioned


def _commission(channel: str, save: Path, out: Path) -> list[str]:
    return ["commission", "standstill", "--bench", "virtual", "--set", "can.transport=unixcan",
            "--set", f"can.channel={channel}", "--set", "modbus.port=0", "--out", str(out),
            "--quiet", "--save-params", str(save)]


def test_standstill_saves_the_parameters_it_identified(unix_channel: str, programs_built: None,
                                                       tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    save = tmp_path / "paper.toml"
    code = rig_main(_commission(unix_channel, save, tmp_path / "run"))
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "commissioning PASSED" in captured.out
    text = save.read_text()
    assert text.startswith(commissioned.HEADER)
    saved = tomllib.loads(text)["firmware"]
    truth = paper_truth()
    assert set(saved) == {"rs_ohm", "ld_h", "lq_h"}
    for key, rel in (("rs_ohm", 0.02), ("ld_h", 0.05), ("lq_h", 0.05)):
        assert abs(saved[key] / truth[key] - 1.0) <= rel, (key, saved[key], truth[key])
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp file


@pytest.mark.parametrize("target", ["symlink", "users_file", "directory", "no_folder",
                                    "linked_folder"])
def test_a_target_it_may_not_write_is_refused_before_the_run(
        target: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mine = tmp_path / "mine.toml"
    mine.write_text("my own notes\n")
    save = tmp_path / "saved.toml"
    if target == "symlink":
        save.symlink_to(mine)
        why = "symbolic link"
    elif target == "users_file":
        save = mine
        why = "was not written by --save-params"
    elif target == "directory":
        save.mkdir()
        why = "not a regular file"
    elif target == "linked_folder":
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
        (tmp_path / "linked").symlink_to(elsewhere, target_is_directory=True)
        save = tmp_path / "linked" / "saved.toml"
        why = "which is a symbolic link"
    else:
        save = tmp_path / "missing" / "saved.toml"
        why = "is not a folder"
    code = rig_main(_commission("never-used", save, tmp_path / "run"))
    err = capsys.readouterr().err
    assert code == 2, err
    assert why in err, err
    assert mine.read_text() == "my own notes\n"
    assert not (tmp_path / "run").exists()  # nothing started
    assert not (tmp_path / "elsewhere").exists() or not any((tmp_path / "elsewhere").iterdir())


def test_a_file_in_a_linked_folder_is_refused_at_the_write_too(tmp_path: Path) -> None:
    """The check before the run and the one before the write are the same: a link put in
    place while the run ran is refused as well."""
    from rig.commands import commission

    elsewhere = tmp_path / "elsewhere"
    (tmp_path / "a").mkdir()
    elsewhere.mkdir()
    (tmp_path / "a" / "b").symlink_to(elsewhere, target_is_directory=True)
    data = {"passed": True, "identified": {"rs_ohm": 1.93}, "written": {}}
    desc = type("D", (), {"virtual": None, "name": "lab"})()
    assert not commission._save_params(tmp_path / "a" / "b" / "saved.toml", data, desc)
    assert list(elsewhere.iterdir()) == []


WRITER = r"""
import resource, signal, sys
from pathlib import Path
from types import SimpleNamespace
from rig.commands import commission
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (100, 100))  # a disk that fills at 100 bytes
data = {"passed": True, "identified": {"rs_ohm": 1.93, "ld_h": 0.015, "lq_h": 0.032},
        "written": {"xsat_ldq_per_a": -0.00018}}
desc = SimpleNamespace(virtual=SimpleNamespace(profile="paper"), name="virtual")
print("saved" if commission._save_params(Path(sys.argv[1]), data, desc) else "not saved")
"""


def test_a_full_disk_leaves_the_saved_file_whole(tmp_path: Path) -> None:
    save = tmp_path / "paper.toml"
    before = commissioned.render({"xsat_ldq_per_a": -0.0002}, "paper", ["rig"])
    save.write_text(before)
    done = subprocess.run([sys.executable, "-c", WRITER, str(save)], capture_output=True,
                          text=True, timeout=60, check=False, env=dict(os.environ))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "not saved", done.stdout + done.stderr
    assert save.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["paper.toml"]
