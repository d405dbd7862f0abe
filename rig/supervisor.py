"""Starts the rig's child programs, watches them, and stops them reliably.

Every child runs in its own session (``start_new_session``: a Ctrl-C on the terminal reaches
only the rig, which then stops the children in order) with ``PR_SET_PDEATHSIG = SIGKILL``
set in the child before ``exec`` (so a SIGKILLed rig leaves no orphans: the kernel kills
the children when the thread that started them dies; start children from the main thread).
stdout and stderr go to ``<name>.stdout.log`` / ``<name>.stderr.log`` in the log folder.

``stop()`` sends SIGTERM to each child's process group, waits a grace period, then
SIGKILLs what is left. ``check()`` raises :class:`ChildFailed` (with the log tail) as soon
as a child has exited while it should be running.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import json
import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

PR_SET_PDEATHSIG = 1
DEFAULT_GRACE_S = 2.0
POLL_S = 0.02
TAIL_LINES = 25


def _libc_prctl() -> Callable[..., int] | None:
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6", use_errno=True)
    except OSError:
        return None
    fn: Callable[..., int] = libc.prctl
    return fn


_PRCTL = _libc_prctl()


def _child_setup(parent_pid: int) -> Callable[[], None]:
    """preexec_fn: die with the parent (and exit at once if the parent is already gone)."""
    prctl = _PRCTL

    def setup() -> None:
        if prctl is not None:
            prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        if os.getppid() != parent_pid:
            os._exit(127)

    return setup


def tail(path: Path, lines: int = TAIL_LINES) -> str:
    """The last lines of a (log) file, '' when it does not exist."""
    try:
        with path.open("rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - 64 * 1024))
            data = fh.read().decode("utf-8", errors="replace")
    except OSError:
        return ""
    return "\n".join(data.splitlines()[-lines:])


def last_json_line(path: Path) -> dict[str, Any] | None:
    """The last line of a log that parses as a JSON object (the programs' exit counters)."""
    for line in reversed(tail(path, 200).splitlines()):
        line = line.strip()
        if line.startswith("{") and line.endswith("}"):
            try:
                value = json.loads(line)
            except ValueError:
                continue
            if isinstance(value, dict):
                return value
    return None


def log_names(child: str) -> tuple[str, str]:
    """The names of a child's stdout and stderr logs in the log folder."""
    return f"{child}.stdout.log", f"{child}.stderr.log"


def describe_status(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


class ChildFailed(RuntimeError):
    """A child exited while it should run, failed to start, or did not stop cleanly."""

    def __init__(self, name: str, what: str, log_tail: str = "", returncode: int | None = None):
        self.name = name
        self.what = what
        self.log_tail = log_tail
        self.returncode = returncode
        msg = f"{name}: {what}"
        if log_tail:
            msg += f"\n--- last lines of {name}'s log ---\n{log_tail}"
        super().__init__(msg)


@dataclass
class Child:
    name: str
    argv: list[str]
    proc: subprocess.Popen[bytes]
    stdout_log: Path
    stderr_log: Path
    ready_file: Path | None
    started: float
    stopping: bool = False
    killed: bool = False

    @property
    def pid(self) -> int:
        return self.proc.pid

    def log_tail(self, lines: int = TAIL_LINES) -> str:
        err = tail(self.stderr_log, lines)
        out = tail(self.stdout_log, lines)
        if err and out:
            return f"[stderr]\n{err}\n[stdout]\n{out}"
        return err or out

    def exit_counters(self) -> dict[str, Any] | None:
        return last_json_line(self.stderr_log) or last_json_line(self.stdout_log)


@dataclass
class StopReport:
    name: str
    returncode: int | None
    killed: bool
    clean: bool
    counters: dict[str, Any] | None = None
    log_tail: str = ""


@dataclass
class Supervisor:
    """Owns the child processes of one run (use as a context manager)."""

    log_dir: Path
    grace_s: float = DEFAULT_GRACE_S
    children: dict[str, Child] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.log_dir = Path(self.log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)

    # -- starting ----------------------------------------------------------------------
    def start(
        self,
        name: str,
        argv: Sequence[str],
        *,
        ready_file: Path | None = None,
        env: Mapping[str, str] | None = None,
        cwd: Path | None = None,
    ) -> Child:
        if name in self.children:
            raise ValueError(f"a child named {name!r} is already running")
        if ready_file is not None:
            Path(ready_file).unlink(missing_ok=True)
        out_name, err_name = log_names(name)
        out_log, err_log = self.log_dir / out_name, self.log_dir / err_name
        full_env = dict(os.environ)
        if env:
            full_env.update(env)
        with out_log.open("wb") as out, err_log.open("wb") as err:
            try:
                proc = subprocess.Popen(
                    list(argv),
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=err,
                    env=full_env,
                    cwd=cwd,
                    start_new_session=True,
                    preexec_fn=_child_setup(os.getpid()),
                    close_fds=True,
                )
            except OSError as exc:
                raise ChildFailed(name, f"could not start {argv[0]}: {exc}") from exc
        child = Child(name, list(argv), proc, out_log, err_log,
                      Path(ready_file) if ready_file else None, time.monotonic())
        self.children[name] = child
        return child

    def wait_ready(self, timeout_s: float, names: Sequence[str] | None = None) -> None:
        """Waits until each child's ready file exists; a child exiting first is a failure."""
        waiting = [self.children[n] for n in (names or list(self.children))]
        deadline = time.monotonic() + timeout_s
        while True:
            self.check()
            pending = [c for c in waiting if c.ready_file is not None and not c.ready_file.exists()]
            if not pending:
                return
            if time.monotonic() > deadline:
                c = pending[0]
                raise ChildFailed(
                    c.name, f"not ready after {timeout_s:g} s (no {c.ready_file})", c.log_tail()
                )
            time.sleep(POLL_S)

    # -- watching ----------------------------------------------------------------------
    def check(self) -> None:
        """Raises ChildFailed if a child that should be running has exited."""
        for c in self.children.values():
            if c.stopping:
                continue
            code = c.proc.poll()
            if code is not None:
                c.stopping = True  # reported once
                raise ChildFailed(
                    c.name,
                    f"exited unexpectedly ({describe_status(code)})",
                    c.log_tail(),
                    code,
                )

    def sleep(self, seconds: float) -> None:
        """Sleeps while watching the children."""
        deadline = time.monotonic() + seconds
        while True:
            self.check()
            left = deadline - time.monotonic()
            if left <= 0:
                return
            time.sleep(min(POLL_S, left))

    # -- stopping ----------------------------------------------------------------------
    def _signal(self, child: Child, sig: int) -> None:
        # The child leads its own session, so its group holds it: one signal, not two (a
        # second SIGTERM can land while the child is already exiting and kill it by default
        # action, turning a clean stop into -15). Only without the group signal it directly.
        try:
            os.killpg(child.proc.pid, sig)
            return
        except (ProcessLookupError, PermissionError):
            pass
        with contextlib.suppress(ProcessLookupError):
            child.proc.send_signal(sig)

    def stop(self, names: Sequence[str] | None = None, grace_s: float | None = None) -> dict[
        str, StopReport
    ]:
        """SIGTERM, wait up to the grace period, SIGKILL what is left. Never raises."""
        grace = self.grace_s if grace_s is None else grace_s
        targets = [self.children[n] for n in (names or list(self.children)) if n in self.children]
        reports: dict[str, StopReport] = {}
        try:
            for c in targets:
                already = c.proc.poll() is not None
                c.stopping = True
                if not already:
                    self._signal(c, signal.SIGTERM)
            deadline = time.monotonic() + grace
            for c in targets:
                while c.proc.poll() is None and time.monotonic() < deadline:
                    time.sleep(POLL_S)
        finally:
            # whatever happened above (even a second Ctrl-C): nothing survives this block
            for c in targets:
                if c.proc.poll() is None:
                    c.killed = True
                    self._signal(c, signal.SIGKILL)
                # the session may hold grandchildren: clean the group as well
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(c.proc.pid, signal.SIGKILL)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    c.proc.wait(timeout=5.0)
        for c in targets:
            code = c.proc.returncode
            clean = (not c.killed) and code == 0
            reports[c.name] = StopReport(
                c.name, code, c.killed, clean, c.exit_counters(),
                "" if clean else c.log_tail(),
            )
        return reports

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


class Terminated(BaseException):
    """Raised in the main thread when the rig receives SIGTERM or SIGHUP (like Ctrl-C)."""


def interruptible() -> None:
    """Makes SIGINT raise KeyboardInterrupt even when it was ignored at start-up.

    A non-interactive shell starts its background commands with SIGINT ignored, and Python
    then installs no KeyboardInterrupt handler: an explicit SIGINT (or Ctrl-C to the script's
    process group) would be lost and the children left running. The rig stops cleanly on it
    instead, as in the foreground."""
    try:
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
            signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread
        pass


@contextlib.contextmanager
def terminate_as_exception() -> Iterator[None]:
    """Turns SIGTERM/SIGHUP into :class:`Terminated` so ``finally`` blocks stop the children
    (and SIGINT into KeyboardInterrupt, even when inherited as ignored: :func:`interruptible`)."""
    interruptible()

    def handler(signum: int, frame: FrameType | None) -> None:
        raise Terminated(signal.Signals(signum).name)

    with _handlers((signal.SIGTERM, signal.SIGHUP), handler):
        yield


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP wait until the block is done, then take their course (the
    handlers in force before it: KeyboardInterrupt, :class:`Terminated`, or the default
    action): a result file written in the block is whole, whatever arrives meanwhile. By
    Python handlers, not the signal mask: a signal that reaches another thread would still
    run the main thread's handler in the middle of the block."""
    got: list[int] = []

    def note(signum: int, frame: FrameType | None) -> None:
        got.append(signum)

    previous: dict[int, Any] = {}
    try:
        with _handlers((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), note) as previous:
            yield
    finally:  # the handlers in force before the block take what came meanwhile
        for signum in dict.fromkeys(got):
            if previous.get(signum) not in (signal.SIG_IGN, None):
                signal.raise_signal(signum)


class VerdictGuard:
    """Once a command's verdict is decided and written, a signal no longer changes its exit
    status: ``hold`` makes SIGINT, SIGTERM and SIGHUP only noted (the little that is left,
    printing and reports of the written result, finishes and the command exits with the
    verdict's status), ``release`` puts back the handlers that were in force. In the main
    thread only (elsewhere nothing changes)."""

    def __init__(self) -> None:
        self.noted: list[int] = []
        self._previous: dict[int, Any] = {}

    def hold(self) -> None:
        if self._previous:
            return

        def note(signum: int, frame: FrameType | None) -> None:
            self.noted.append(signum)

        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            try:
                self._previous[sig] = signal.signal(sig, note)
            except ValueError:  # not the main thread
                pass

    def release(self) -> None:
        for signum, h in self._previous.items():
            signal.signal(signum, h)
        self._previous = {}


@contextlib.contextmanager
def _handlers(signals: Iterable[int], handler: Callable[[int, FrameType | None], None]
              ) -> Iterator[dict[int, Any]]:
    """``handler`` for ``signals`` inside the block, the previous handlers (yielded) restored
    after it. Outside the main thread no handler can be set: nothing changes there."""
    previous: dict[int, Any] = {}
    for sig in signals:
        try:
            previous[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread
            pass
    try:
        yield previous
    finally:
        for signum, h in previous.items():
            signal.signal(signum, h)
