"""Issue 23.4, 23.8, 23.9: the rig stops when told to, and leaves its results whole.

- SIGTERM while a run works out its results (merging, judging, recording) wrote nothing and
  exited 130: now result.json and report.md are there, whole, saying it was interrupted;
- `rig run --live` on a machine without a display hung for good after the run (the native
  viewer never came up, rerun's flush waited for it in native code: SIGTERM and SIGINT did
  nothing); now the live view goes to the web viewer, and a viewer that fails to start is
  reported at once;
- `rig view DIR` without a display: a hint to use --web, not winit's error; the native
  viewer's gRPC server listens on 127.0.0.1 (it was 0.0.0.0);
- `rig view --web` stopped by SIGTERM left the Rerun server holding both ports.

No display here (these tests remove DISPLAY and WAYLAND_DISPLAY, or set one nobody serves).
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from viewer_support import assert_ports_freed, listening, no_display_env
from waits import EVENT_S

from rig.results import webview


def _rig(*args: str, env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "rig", *args], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def test_sigterm_while_the_results_are_worked_out_leaves_them_whole(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = _rig("run", "table2_1000rpm_1nm", "--bus", "inproc", "--out", str(out), "--quiet",
                env=no_display_env())
    deadline = time.monotonic() + 300
    # capture/ is made when the merge starts, after the bench stopped: the post-processing
    # (merge, verdicts, recording) takes about 2 s from then on here
    while not (out / "capture").exists():
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline
        time.sleep(0.002)
    proc.send_signal(signal.SIGTERM)
    text, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, text
    data = json.loads((out / "result.json").read_text())
    assert data["status"] == "interrupted" and data["passed"] is False, data["failure"]
    assert "while the results were worked out" in data["failure"]["message"]
    assert data["criteria"] and all(c["outcome"] == "not_evaluated" for c in data["criteria"])
    assert "interrupted" in (out / "report.md").read_text()
    assert not list(out.glob(".*.tmp-*"))


@pytest.mark.parametrize("target", ["smoke", "quick"])
def test_sigterm_after_the_verdict_is_written_keeps_the_verdict_s_exit_status(
        tmp_path: Path, target: str) -> None:
    """A run (or suite: ``quick``) that passed and wrote result.json, then got SIGTERM, exited
    143 (or 130): the verdict is decided and written, the exit status is its own."""
    delivered = 0
    for attempt in range(5):
        out = tmp_path / f"run{attempt}"
        proc = _rig("run", target, "--bus", "inproc", "--out", str(out), "--quiet",
                    "--no-record", "--no-figures", env=no_display_env())
        deadline = time.monotonic() + 300
        while not (out / "result.json").exists():  # renamed into place whole
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline
            time.sleep(0.0002)
        if proc.poll() is not None:  # done before the signal: try again
            proc.communicate()
            continue
        proc.send_signal(signal.SIGTERM)
        delivered += 1
        text, _ = proc.communicate(timeout=120)
        assert json.loads((out / "result.json").read_text())["passed"], text
        assert proc.returncode == 0, text
    assert delivered >= 3


@pytest.mark.parametrize("bus", ["unixcan", "inproc"])
def test_live_without_a_display_uses_the_web_viewer_and_ends(tmp_path: Path, channel: str,
                                                            bus: str) -> None:
    web, grpc = webview.free_port(), webview.free_port()
    out = tmp_path / "run"
    where = ["--bus", "unixcan", "--channel", channel] if bus == "unixcan" else ["--bus", bus]
    proc = _rig("run", "smoke", *where, "--live",
                "--web-port", str(web), "--grpc-port", str(grpc), "--out", str(out),
                "--quiet", env=no_display_env())
    try:
        text, _ = proc.communicate(timeout=180)
    except subprocess.TimeoutExpired:
        proc.kill()
        text, _ = proc.communicate()
        pytest.fail(f"rig run --live without a display did not end:\n{text}")
    assert proc.returncode == 0, text
    assert "no display here" in text and "web viewer" in text and f":{web}/" in text, text
    assert json.loads((out / "result.json").read_text())["passed"]
    assert_ports_freed(web, grpc)  # the server ended with the run


def test_a_live_viewer_that_cannot_open_is_reported_at_once(tmp_path: Path,
                                                           channel: str) -> None:
    """A display that does not answer: the native viewer exits at start; the run says so and
    goes on without a live view (with rerun's own spawn it waited for ever)."""
    out = tmp_path / "run"
    proc = _rig("run", "smoke", "--bus", "unixcan", "--channel", channel, "--live",
                "--out", str(out), "--quiet", env=no_display_env(DISPLAY=":97"))
    try:
        text, _ = proc.communicate(timeout=180)
    except subprocess.TimeoutExpired:
        proc.kill()
        text, _ = proc.communicate()
        pytest.fail(f"rig run --live with a dead display did not end:\n{text}")
    assert proc.returncode == 0, text
    # at its start, as a rule; on a loaded machine its window may fail after the rig took
    # it for started: then the last flush gives up after its 5 s
    assert ("live view unavailable" in text and "Rerun viewer exited" in text) or (
        "did not take the last rows within 5 s" in text), text


def _a_run(tmp_path: Path) -> Path:
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "rig", "run", "smoke", "--bus", "inproc",
                           "--out", str(out), "--quiet"], env=no_display_env(), capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return out


def test_view_without_a_display_says_use_web(tmp_path: Path) -> None:
    out = _a_run(tmp_path)
    done = subprocess.run([sys.executable, "-m", "rig", "view", str(out)], env=no_display_env(),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 3, done.stderr
    assert "no display here" in done.stderr and f"rig view --web {out}" in done.stderr
    assert "winit" not in done.stderr and "Traceback" not in done.stderr
    # the native viewer's gRPC server listens on this machine only. Its window needs an X
    # server: a silent one (it takes the connection, never answers) holds the viewer in its
    # handshake, so the server is seen listening whatever order the viewer's threads run in
    # (with a display that refuses, the window's error could end it before the server was up)
    x_server, display = _silent_x_server()
    grpc = webview.free_port()
    proc = subprocess.Popen([sys.executable, "-m", "rig", "view", str(out), "--grpc-port",
                             str(grpc)], env=no_display_env(DISPLAY=display), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        while not (binds := _tcp_listeners(grpc)):
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline, "the viewer's gRPC server never listened"
            time.sleep(0.05)
        assert binds == {"127.0.0.1"}, binds
        # `rig view` is the viewer (exec): SIGTERM ends the window and frees the port
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=EVENT_S)
        assert not _tcp_listeners(grpc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        x_server.close()


def _silent_x_server() -> tuple[socket.socket, str]:
    """A TCP listener on 127.0.0.1:6000+N (X display N), and the DISPLAY that names it."""
    for port in range(6100, 7000):
        server = socket.socket()
        try:
            server.bind(("127.0.0.1", port))
        except OSError:
            server.close()
            continue
        server.listen(4)
        return server, f"127.0.0.1:{port - 6000}"
    raise AssertionError("no free port in 6100-6999 for an X display")


def _tcp_listeners(port: int) -> set[str]:
    """The IPv4 addresses a socket on this machine listens on at ``port`` (/proc/net/tcp:
    little-endian hex address, state 0A is LISTEN)."""
    found: set[str] = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address, hex_port = local.split(":")
        if state == "0A" and int(hex_port, 16) == port:
            found.add(socket.inet_ntoa(bytes.fromhex(address)[::-1]))
    return found


def test_view_web_stopped_by_sigterm_frees_both_ports(tmp_path: Path) -> None:
    out = _a_run(tmp_path)
    web, grpc = webview.free_port(), webview.free_port()
    proc = _rig("view", "--web", str(out), "--web-port", str(web), "--grpc-port", str(grpc),
                env=no_display_env())
    deadline = time.monotonic() + 60
    while not (listening(web) and listening(grpc)):
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline, "the web viewer never listened"
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=30)
    assert_ports_freed(web, grpc)


def _children(pid: int) -> set[int]:
    """Every process below ``pid`` (from /proc: each process's parent)."""
    parent: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        parent[int(stat.parent.name)] = int(text.rsplit(")", 1)[1].split()[1])
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        kids = {c for c, pp in parent.items() if pp == p}
        found |= kids
        todo += list(kids)
    return found


def _gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return state == "Z"  # (a zombie holds no port: its parent has not waited for it yet)


@pytest.mark.parametrize("sig", ["SIGKILL", "SIGQUIT", "SIGUSR1", "SIGALRM"])
def test_view_web_killed_by_any_signal_takes_the_server_with_it(tmp_path: Path,
                                                                sig: str) -> None:
    """Issue 36.7: killed by SIGKILL, SIGQUIT, SIGUSR1 or SIGALRM, `rig view --web` left the
    Rerun web server (two processes) running, holding both ports."""
    out = _a_run(tmp_path)
    web, grpc = webview.free_port(), webview.free_port()
    proc = _rig("view", "--web", str(out), "--web-port", str(web), "--grpc-port", str(grpc),
                env=no_display_env())
    deadline = time.monotonic() + 60
    while not (listening(web) and listening(grpc)):
        assert proc.poll() is None, proc.communicate()[0]
        assert time.monotonic() < deadline, "the web viewer never listened"
        time.sleep(0.1)
    server = _children(proc.pid)
    assert server, "the web viewer is not a child of the rig"
    proc.send_signal(getattr(signal, sig))
    proc.communicate(timeout=30)
    deadline = time.monotonic() + EVENT_S
    while (any(not _gone(p) for p in server) or listening(web) or listening(grpc)) \
            and time.monotonic() < deadline:
        time.sleep(0.1)
    assert [p for p in server if not _gone(p)] == []
    assert not listening(web) and not listening(grpc)
