"""The Rerun viewer processes: the web viewer (recordings or a live stream served to a
browser) and the native viewer window of a live run.

``start()`` runs rerun-sdk's own server (``python -m rerun --serve-web``, rerun-sdk 0.41): a
gRPC server on ``grpc_port`` that holds the recordings (files given, or whatever an SDK
streams to it: ``grpc_url``) and the web viewer (HTML + Wasm) on ``web_port``; ``url`` opens
the viewer connected to that server. Both listen on ``bind`` (default 127.0.0.1: this
machine only; ``--bind 0.0.0.0`` to view from another one).

The web viewer lives as long as the rig: the rerun binary is started directly (not through
``python -m rerun``, which runs it as a child of a Python process of its own: two processes,
only one of them ours) with the kernel's parent-death signal set (``PR_SET_PDEATHSIG``,
SIGKILL), so a rig killed by any signal, even SIGKILL, takes the server and its ports with it.
The rig's own handlers (``rig view``) stop it cleanly on the signals it can catch.

``start_native()`` opens a native viewer window whose gRPC server listens on 127.0.0.1 (rerun's
own ``spawn`` binds 0.0.0.0 and, on a machine without a display, leaves the SDK waiting for
a viewer that never comes); it needs a display (``has_display``).
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

DEFAULT_WEB_PORT = 9090  # Rerun's defaults
DEFAULT_GRPC_PORT = 9876
START_TIMEOUT_S = 30.0
NATIVE_SETTLE_S = 1.0  # a native viewer that fails to open its window exits within this


class WebViewerError(RuntimeError):
    """The server did not come up (port taken, rerun missing)."""


@dataclass
class WebViewer:
    proc: subprocess.Popen[bytes]
    bind: str
    web_port: int
    grpc_port: int
    log: Path | None = None

    @property
    def host(self) -> str:
        return "127.0.0.1" if self.bind in ("0.0.0.0", "::", "") else self.bind

    @property
    def grpc_url(self) -> str:
        return f"rerun+http://{self.host}:{self.grpc_port}/proxy"

    def url(self, **params: str) -> str:
        """The page that opens the viewer on this server (extra query parameters: e.g.
        ``renderer="webgl"``)."""
        query = f"url={quote(self.grpc_url, safe='')}"
        for k, v in params.items():
            query += f"&{k}" if v == "" else f"&{k}={quote(v, safe='')}"
        return f"http://{self.host}:{self.web_port}/?{query}"

    def running(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> None:
        """Ends the server: its whole process group (``python -m rerun`` runs the viewer
        binary as a child of its own)."""
        for sig in (signal.SIGTERM, signal.SIGKILL):
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.proc.pid, sig)
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                self.proc.poll()  # reap the leader, or the group looks alive
                if not _group_alive(self.proc.pid):
                    return
                time.sleep(0.05)

    def __enter__(self) -> WebViewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def free_port() -> int:
    """A TCP port that nothing listens on right now (for tests and parallel runs)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _listening(host: str, port: int) -> bool:
    with contextlib.suppress(OSError), socket.create_connection((host, port), timeout=0.5):
        return True
    return False


def _taken(host: str, port: int) -> bool:
    """Whether a server could not bind host:port now: a listener is there, or any other socket
    holds the port without listening."""
    return (_listening("127.0.0.1" if host in ("0.0.0.0", "::") else host, port)
            or _bind_refused(host, port))


def _bind_refused(host: str, port: int) -> bool:
    """Whether binding host:port fails, as it does for a socket that holds the port without
    listening: a connection finds nobody there, and the viewer exited at once with status 1
    and no word about why."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        # as a server binds: a port in TIME_WAIT only is free
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return True
    return False


def has_display() -> bool:
    """Whether a native window can open here (X11 or Wayland; the rig runs on Linux)."""
    return any(os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


NO_DISPLAY = "no display here (DISPLAY and WAYLAND_DISPLAY are unset)"


PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def rerun_binary() -> str:
    """The viewer binary rerun-sdk ships (``rerun_cli/rerun``; ``$RERUN_CLI_PATH`` as
    rerun's own launcher honours it)."""
    import importlib.util

    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or spec.origin is None:
        raise WebViewerError("rerun-sdk's viewer (rerun_cli) is not installed")
    path = Path(spec.origin).parent / "rerun"
    if not path.is_file():
        raise WebViewerError(f"rerun-sdk's viewer binary is missing: {path}")
    return str(path)


def _tied_to(parent: int) -> Any:
    """A ``preexec_fn`` that ties the child to ``parent``'s life: SIGKILL when it ends (the
    thread that started it: the rig starts its viewers from its main thread), and an exit at
    once if it already ended before the tie was made."""
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)  # (loaded before the fork)

    def tie() -> None:
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        if os.getppid() != parent:
            os._exit(1)

    return tie


def start(files: Sequence[Path] = (), *, web_port: int = DEFAULT_WEB_PORT,
          grpc_port: int = DEFAULT_GRPC_PORT, bind: str = "127.0.0.1",
          log: Path | None = None, env: Mapping[str, str] | None = None,
          timeout_s: float = START_TIMEOUT_S) -> WebViewer:
    """Starts the server (and waits until both ports answer)."""
    for port in (web_port, grpc_port):
        if _taken(bind, port):
            raise WebViewerError(f"port {port} is already in use (another viewer or "
                                 "program): choose another with --web-port / --grpc-port")
    argv = [rerun_binary(), "--serve-web", "--bind", bind,
            "--web-viewer-port", str(web_port), "--port", str(grpc_port),
            *[str(f) for f in files]]
    return _launch(argv, bind, web_port, grpc_port, (web_port, grpc_port), log, env,
                   timeout_s, tied=True)


def start_native(*, grpc_port: int = DEFAULT_GRPC_PORT, log: Path | None = None,
                 env: Mapping[str, str] | None = None,
                 timeout_s: float = START_TIMEOUT_S) -> str:
    """A native viewer window for a live stream, its gRPC server on 127.0.0.1:grpc_port; the
    URL an SDK streams to, once the server answers (a viewer already there is reused, as
    rerun does). It outlives the run: the window is the user's to close. WebViewerError when
    there is no display, or the viewer exits or does not listen within timeout_s."""
    url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    if not has_display():
        raise WebViewerError(f"{NO_DISPLAY}: use --web")
    if not _listening("127.0.0.1", grpc_port):
        if _bind_refused("127.0.0.1", grpc_port):
            raise WebViewerError(f"port {grpc_port} is in use by a program that is not a "
                                 "viewer: choose another with --grpc-port")
        argv = [sys.executable, "-m", "rerun", "--bind", "127.0.0.1", "--port", str(grpc_port)]
        viewer = _launch(argv, "127.0.0.1", 0, grpc_port, (grpc_port,), log, env, timeout_s)
        # its server listens before its window opens: a display it cannot use ends it
        # right after (winit), and it must not be taken for a viewer then
        deadline = time.monotonic() + NATIVE_SETTLE_S
        while time.monotonic() < deadline:
            if viewer.proc.poll() is not None:
                raise WebViewerError(f"the Rerun viewer exited with status "
                                     f"{viewer.proc.returncode} (no usable display?)")
            time.sleep(0.05)
    return url


def _launch(argv: list[str], bind: str, web_port: int, grpc_port: int, ports: Sequence[int],
            log: Path | None, env: Mapping[str, str] | None, timeout_s: float,
            tied: bool = False) -> WebViewer:
    """Starts a viewer process in a session of its own (``tied``: ended by the kernel when
    this process ends); waits (at most timeout_s) until ``ports`` answer, failing at once
    when it exits."""
    out = open(log, "wb") if log is not None else subprocess.DEVNULL
    try:
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True,
                                env={**os.environ, **(env or {})},
                                preexec_fn=_tied_to(os.getpid()) if tied else None)
    finally:
        if log is not None:
            out.close()  # type: ignore[union-attr]
    viewer = WebViewer(proc, bind, web_port, grpc_port, log)
    deadline = time.monotonic() + timeout_s
    try:
        while not all(_listening(viewer.host, port) for port in ports):
            if proc.poll() is not None:
                tail = log.read_text(errors="replace")[-2000:] if log is not None else ""
                raise WebViewerError(f"the Rerun viewer exited with status {proc.returncode}"
                                     + (f":\n{tail}" if tail else ""))
            if time.monotonic() > deadline:
                raise WebViewerError(f"the Rerun viewer did not listen on port(s) "
                                     f"{', '.join(map(str, ports))} within {timeout_s:g} s")
            time.sleep(0.1)
    except BaseException:  # (Ctrl-C, SIGTERM as Terminated too): no server left behind
        viewer.stop()
        raise
    return viewer
