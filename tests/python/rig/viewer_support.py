"""What the tests of the Rerun viewers share: an environment without a display, and the
ports on this machine that listen."""

from __future__ import annotations

import os
import socket
import sys
import time
from pathlib import Path

from waits import EVENT_S

VENV_BIN = str(Path(sys.executable).parent)


def no_display_env(**extra: str) -> dict[str, str]:
    """This environment without a display, the venv's `rerun` on PATH (where the hang was)."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")}
    env["PATH"] = VENV_BIN + os.pathsep + env.get("PATH", "")
    return {**env, **extra}


def listening(port: int) -> bool:
    """Whether something on 127.0.0.1 takes a connection on ``port``."""
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
        return True
    except OSError:
        return False


def assert_ports_freed(*ports: int) -> None:
    """Waits (up to the event ceiling) until none of ``ports`` listens; fails if one still
    does."""
    deadline = time.monotonic() + EVENT_S
    while any(listening(p) for p in ports) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(listening(p) for p in ports), [p for p in ports if listening(p)]
