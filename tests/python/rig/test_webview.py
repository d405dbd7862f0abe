"""The web viewer's server (rig.results.webview): it listens where it says, says when a port is
taken, and leaves no process behind (python -m rerun runs the viewer binary as a child)."""

from __future__ import annotations

import os
import socket
import subprocess
from pathlib import Path

import pytest

from rig.results import webview


def _group(pgid: int) -> str:
    return subprocess.run(["pgrep", "-g", str(pgid)], capture_output=True, text=True).stdout


def test_serves_then_leaves_nothing_behind(tmp_path: Path) -> None:
    home = tmp_path / "home"
    home.mkdir()
    viewer = webview.start(web_port=webview.free_port(), grpc_port=webview.free_port(),
                           log=tmp_path / "rerun.log", env={"HOME": str(home)})
    with viewer:
        # the binary alone (no python -m rerun wrapper around it, which a SIGKILL to the rig
        # left behind): one process, tied to this one's life
        assert _group(viewer.proc.pid).split() == [str(viewer.proc.pid)]
        for port in (viewer.web_port, viewer.grpc_port):
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
        assert viewer.grpc_url == f"rerun+http://127.0.0.1:{viewer.grpc_port}/proxy"
        assert viewer.url(renderer="webgl") == (
            f"http://127.0.0.1:{viewer.web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A"
            f"{viewer.grpc_port}%2Fproxy&renderer=webgl")
        with pytest.raises(webview.WebViewerError, match="already in use"):
            webview.start(web_port=viewer.web_port, grpc_port=webview.free_port())
    assert _group(viewer.proc.pid) == ""
    with pytest.raises(ProcessLookupError):
        os.killpg(viewer.proc.pid, 0)


def test_a_port_held_without_listening_is_taken() -> None:
    """A socket bound to the port but not listening: a connection finds nobody, but the
    viewer's server cannot bind it (it exited with status 1 and said nothing why)."""
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        port = int(held.getsockname()[1])
        with pytest.raises(webview.WebViewerError, match=f"port {port} is already in use"):
            webview.start(web_port=webview.free_port(), grpc_port=port)
        with pytest.raises(webview.WebViewerError, match=f"port {port} is already in use"):
            webview.start(web_port=port, grpc_port=webview.free_port())
