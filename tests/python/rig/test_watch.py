"""``rig watch`` (issue 37.2) without a bench to watch: what it refuses, and its viewer's life.
With a running bench: tests/python/commissioning/test_live_bench.py."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from viewer_support import assert_ports_freed, no_display_env

from rig.results import webview


def _env(base: Path) -> dict[str, str]:
    base.chmod(0o700)
    env = no_display_env(UNIXCAN_DIR=str(base))
    env.pop("HIL_CHANNEL", None)
    return env


def _watch(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rig", "watch", *args], env=env,
                          capture_output=True, text=True, timeout=120, check=False)


def test_a_bench_that_starts_its_own_programs_is_refused(tmp_path: Path) -> None:
    done = _watch(_env(tmp_path), "--bench", "virtual", "--for", "1")
    assert done.returncode == 2 and "bring one up with `rig up`" in done.stderr, done.stderr


def test_save_refuses_a_file_that_exists_and_a_viewer_option(tmp_path: Path) -> None:
    env = _env(tmp_path)
    kept = tmp_path / "notes.rrd"
    kept.write_text("mine")
    done = _watch(env, "--bus", "unixcan", "--channel", "w1", "--save", str(kept))
    assert done.returncode == 2 and "exists; refused" in done.stderr, done.stderr
    assert kept.read_text() == "mine"
    done = _watch(env, "--bus", "unixcan", "--channel", "w1", "--save",
                  str(tmp_path / "new.rrd"), "--web")
    assert done.returncode == 2 and "--save writes a file" in done.stderr, done.stderr


def test_without_a_display_the_web_viewer_lives_as_long_as_the_watch(tmp_path: Path) -> None:
    """Nothing on the channel: it says so, keeps listening, detaches at --for, exit 0, and
    the web viewer's ports are free again."""
    web, grpc = webview.free_port(), webview.free_port()
    done = _watch(_env(tmp_path), "--bus", "unixcan", "--channel", "quiet", "--web-port",
                  str(web), "--grpc-port", str(grpc), "--for", "8")
    assert done.returncode == 0, done.stderr
    assert "no display here" in done.stderr and f":{web}/" in done.stderr, done.stderr
    assert "nothing heard on unixcan quiet" in done.stderr, done.stderr
    assert "detached (0 frames heard" in done.stderr, done.stderr
    assert_ports_freed(web, grpc)
