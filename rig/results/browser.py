"""Headless Chromium looking at the Rerun web viewer: a screenshot and what the viewer said.

Chromium (Debian's ``chromium`` package) runs headless with software GL (SwiftShader, no GPU)
in a new empty profile, driven over the DevTools protocol on a pipe
(``--remote-debugging-pipe``: no port, no extra package). Host names other than 127.0.0.1
resolve to nothing (``--host-resolver-rules``), so the page reaches only this machine: the
viewer's own calls outside (version check, telemetry, web fonts) fail at once, are counted,
and are told apart from the viewer's errors.

The protocol client is written here, not taken from a library, because the pipe is the
point: the DevTools libraries for Python (pychrome, websocket clients) reach Chromium over a
TCP port (one more port to find free and to leave held when the rig is killed), and the
browser drivers (Playwright, pyppeteer) download a browser build of their own, which this
rig's machines cannot fetch. Over the pipe the protocol is JSON messages ended by a NUL byte:
``_Pipe`` is that and nothing more.

``look()`` opens a URL of the web viewer, waits until the viewer holds the recording and
shows every expected view of its blueprint (the viewer's state, ``viewer_state()`` of its
JavaScript handle), waits until the picture is still, and saves a PNG screenshot.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import json
import os
import select
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

DEFAULT_CHROMIUM = "/usr/bin/chromium"
FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
)
LOOPBACK = ("127.0.0.1", "localhost", "::1", "[::1]")
JS_STATE = """(() => {
  const h = window._handle;
  if (!h) return null;
  if (h.has_panicked()) return {panic: String(h.panic_message())};
  return {state: Array.from(h.viewer_state() || [])};
})()"""


class BrowserError(RuntimeError):
    """Chromium is missing, did not start, or the page did not get where it should."""


def chromium_path() -> Path | None:
    """``$HIL_CHROMIUM``, else ``chromium`` on the PATH, else /usr/bin/chromium, if it is
    there."""
    for cand in (os.environ.get("HIL_CHROMIUM"), shutil.which("chromium"), DEFAULT_CHROMIUM):
        if cand and Path(cand).is_file() and os.access(cand, os.X_OK):
            return Path(cand)
    return None


class _Pipe:
    """The DevTools protocol over Chromium's fds 3 (commands in) and 4 (replies out)."""

    def __init__(self, argv: Sequence[str], log: Path) -> None:
        cmd_r, cmd_w = os.pipe()
        out_r, out_w = os.pipe()

        def child() -> None:  # runs in the child before exec: the pipes become fds 3 and 4
            os.dup2(cmd_r, 3)
            os.dup2(out_w, 4)

        with open(log, "wb") as fh:
            self.proc = subprocess.Popen([*argv, "--remote-debugging-pipe"], pass_fds=(3, 4),
                                         preexec_fn=child, stdin=subprocess.DEVNULL,
                                         stdout=fh, stderr=subprocess.STDOUT,
                                         start_new_session=True)
        os.close(cmd_r)
        os.close(out_w)
        self._w = cmd_w
        self._r = out_r
        self._buf = b""
        self._id = 0
        self.events: list[dict[str, Any]] = []

    def _pump(self, timeout: float) -> list[dict[str, Any]]:
        ready, _, _ = select.select([self._r], [], [], max(0.0, timeout))
        if ready:
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise BrowserError(f"chromium closed the DevTools pipe (exit {self.proc.poll()})")
            self._buf += chunk
        out = []
        while b"\0" in self._buf:
            raw, self._buf = self._buf.split(b"\0", 1)
            out.append(json.loads(raw))
        return out

    def call(self, method: str, params: dict[str, Any] | None = None,
             session: str | None = None, timeout: float = 30.0) -> dict[str, Any]:
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for m in self._pump(deadline - time.monotonic()):
                if m.get("id") == self._id:
                    if "error" in m:
                        raise BrowserError(f"{method}: {m['error']}")
                    return dict(m.get("result", {}))
                self.events.append(m)
        raise BrowserError(f"{method}: no answer within {timeout:g} s")

    def idle(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            self.events.extend(self._pump(left))

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.call("Browser.close", timeout=5.0)
        try:
            self.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            pass
        # its renderer and GPU processes too: the whole group
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
        for fd in (self._w, self._r):
            with contextlib.suppress(OSError):
                os.close(fd)


@dataclass
class Look:
    """What the browser saw: the screenshot, the viewer's state strings, its errors."""

    png: Path
    seconds: float
    state_text: str
    errors: list[str] = field(default_factory=list)
    blocked_requests: list[str] = field(default_factory=list)  # outside this machine
    panic: str = ""

    @property
    def ok(self) -> bool:
        return not self.errors and not self.panic


def _local(url: str) -> bool:
    host = urlparse(url).hostname or ""
    return host in LOOPBACK or url.startswith(("data:", "blob:", "about:"))


def _text(args: Sequence[dict[str, Any]]) -> str:
    return " ".join(str(a.get("value", a.get("description", ""))) for a in args)


def _errors(events: Sequence[dict[str, Any]]) -> tuple[list[str], list[str]]:
    """(the viewer's errors, the requests outside this machine that failed)."""
    urls: dict[str, str] = {}
    blocked: list[str] = []
    errors: list[str] = []
    fetch_errors: list[str] = []
    for e in events:
        method, p = e.get("method"), e.get("params", {})
        if method == "Network.requestWillBeSent":
            urls[p["requestId"]] = p["request"]["url"]
        elif method == "Network.loadingFailed":
            url = urls.get(p["requestId"], "?")
            if _local(url):
                errors.append(f"request failed: {url}: {p.get('errorText')}")
            else:
                blocked.append(url)
        elif method == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            errors.append("exception: " + str(d.get("exception", {}).get("description")
                                              or d.get("text")))
        elif method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            text = _text(p.get("args", []))
            (fetch_errors if text.startswith("TypeError: Failed to fetch") else errors).append(
                "console: " + text[:500])
        elif method == "Log.entryAdded" and p["entry"].get("level") == "error":
            entry = p["entry"]
            if entry.get("source") == "network" and not _local(entry.get("url", "")):
                continue  # a request outside this machine: counted by loadingFailed
            errors.append(f"log ({entry.get('source')}): {entry.get('text', '')[:500]}")
    # a failed fetch the viewer logs is fine only as one of the failed requests outside
    extra = len(fetch_errors) - len(blocked)
    if extra > 0:
        errors += fetch_errors[:extra]
    return errors, blocked


def look(url: str, png: Path, *, expect: Sequence[str] = (), width: int = 1600,
         height: int = 1000, timeout_s: float = 180.0, settle_s: float = 3.0,
         call_timeout_s: float = 90.0,
         chromium: Path | None = None, work: Path | None = None) -> Look:
    """Opens ``url`` in headless Chromium, waits until the viewer's state names every string
    of ``expect`` and the picture is still, and saves a screenshot to ``png``."""
    exe = chromium or chromium_path()
    if exe is None:
        raise BrowserError("chromium is not installed (Debian: apt-get install chromium; "
                           "./hil install does it as root)")
    base = Path(tempfile.mkdtemp(prefix="rig-chromium-", dir=work))
    profile = base / "profile"
    profile.mkdir()
    argv = [str(exe), *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}"]
    pipe = _Pipe(argv, base / "chromium.log")
    t0 = time.monotonic()
    try:
        target = pipe.call("Target.createTarget", {"url": "about:blank"})
        session = str(pipe.call("Target.attachToTarget",
                                {"targetId": target["targetId"], "flatten": True})["sessionId"])
        for domain in ("Runtime", "Log", "Network", "Page"):
            pipe.call(f"{domain}.enable", session=session)
        pipe.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height,
                  "deviceScaleFactor": 1, "mobile": False}, session=session)
        pipe.call("Page.navigate", {"url": url}, session=session)
        deadline = t0 + timeout_s
        state_text, panic = "", ""
        while True:
            pipe.idle(1.0)
            value = pipe.call("Runtime.evaluate", {"expression": JS_STATE,
                              "returnByValue": True}, session=session,
                              timeout=call_timeout_s)["result"].get("value")
            if isinstance(value, dict) and "panic" in value:
                panic = str(value["panic"])
                break
            if isinstance(value, dict):
                state_text = bytes(value.get("state") or []).decode("utf-8", "replace")
                if all(s in state_text for s in expect):
                    break
            if time.monotonic() > deadline:
                missing = [s for s in expect if s not in state_text]
                raise BrowserError(f"the viewer did not show {missing} within {timeout_s:g} s "
                                   f"(log: {base / 'chromium.log'})")
        # the views are laid out: wait until two screenshots a second apart are the same
        last = b""
        shot = b""
        still_deadline = time.monotonic() + max(settle_s, 1.0) * 10
        pipe.idle(settle_s)
        while time.monotonic() < still_deadline:
            shot = base64.b64decode(pipe.call("Page.captureScreenshot", {"format": "png"},
                                              session=session, timeout=call_timeout_s)["data"])
            if hashlib.sha256(shot).digest() == hashlib.sha256(last).digest():
                break
            last = shot
            pipe.idle(1.0)
        png.parent.mkdir(parents=True, exist_ok=True)
        png.write_bytes(shot)
        errors, blocked = _errors(pipe.events)
        return Look(png=png, seconds=time.monotonic() - t0, state_text=state_text,
                    errors=errors, blocked_requests=blocked, panic=panic)
    finally:
        pipe.close()
        shutil.rmtree(base, ignore_errors=True)
