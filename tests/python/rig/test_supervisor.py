"""Supervisor: ready files, crash detection with log tail, clean and forced stops, no orphans."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import psutil
import pytest
from waits import EVENT_S, RUN_S

from rig.supervisor import ChildFailed, Supervisor

CHILD = textwrap.dedent(r'''
    import json, os, signal, subprocess, sys, time
    ready, mode = sys.argv[1], sys.argv[2]
    gc = None
    if mode != "nogc":
        # a grandchild in the child's session: stop() must clean it as well
        gc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    def on_term(signum, frame):
        print(json.dumps({"node": "standin", "periods": 42}), file=sys.stderr, flush=True)
        sys.exit(0)
    if mode == "ignore_term":
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    else:
        signal.signal(signal.SIGTERM, on_term)
    print("standin on stdout", flush=True)
    print("standin: configured", file=sys.stderr, flush=True)
    if mode == "slow_ready":
        time.sleep(30)
    with open(ready + ".tmp", "w") as fh:
        fh.write(f"{os.getpid()} {gc.pid if gc else 0}")
    os.replace(ready + ".tmp", ready)
    if mode == "crash":
        # crashes once told to (the test's go file): not at a time that assumes how soon the
        # other children are ready
        while not os.path.exists(ready + ".go"):
            time.sleep(0.01)
        print("fatal: injected fault in the model", file=sys.stderr, flush=True)
        os._exit(7)
    while True:
        time.sleep(0.05)
''')


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _pids(ready: Path) -> list[int]:
    child, grandchild = (int(x) for x in ready.read_text().split())
    return [p for p in (child, grandchild) if p]


def _wait_gone(pids: list[int], timeout: float = EVENT_S) -> list[int]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        left = [p for p in pids if _alive(p)]
        if not left:
            return []
        time.sleep(0.02)
    return [p for p in pids if _alive(p)]


def _start(sup: Supervisor, tmp: Path, name: str, mode: str) -> Path:
    ready = tmp / f"{name}.ready"
    sup.start(name, [sys.executable, "-c", CHILD, str(ready), mode], ready_file=ready)
    return ready


def test_crash_is_reported_quickly_with_log_tail(tmp_path: Path) -> None:
    with Supervisor(tmp_path, grace_s=1.0) as sup:
        ready = _start(sup, tmp_path, "plant_rt", "crash")
        _start(sup, tmp_path, "fw_host", "run")
        sup.wait_ready(EVENT_S)
        pids = _pids(ready) + _pids(tmp_path / "fw_host.ready")
        t0 = time.monotonic()
        Path(f"{ready}.go").touch()  # plant_rt crashes now
        with pytest.raises(ChildFailed) as info:
            sup.sleep(RUN_S)
        # the crash ends the sleep long before its end; the bound is loose on purpose: a
        # loaded machine (CI, a VM beside it) must not make this flaky
        assert time.monotonic() - t0 < RUN_S / 2
    err = info.value
    assert err.name == "plant_rt" and err.returncode == 7
    assert "exit status 7" in str(err)
    assert "fatal: injected fault in the model" in err.log_tail
    assert "standin: configured" in err.log_tail
    assert (tmp_path / "plant_rt.stderr.log").read_text().startswith("standin: configured")
    assert "standin on stdout" in (tmp_path / "plant_rt.stdout.log").read_text()
    assert _wait_gone(pids) == []


def test_clean_stop_collects_exit_counters(tmp_path: Path) -> None:
    sup = Supervisor(tmp_path, grace_s=3.0)
    ready = _start(sup, tmp_path, "fw_host", "run")
    sup.wait_ready(EVENT_S)
    pids = _pids(ready)
    reports = sup.stop()
    rep = reports["fw_host"]
    assert rep.clean and rep.returncode == 0 and not rep.killed
    assert rep.counters == {"node": "standin", "periods": 42}
    assert _wait_gone(pids) == []


def test_child_ignoring_sigterm_is_killed_after_the_grace_period(tmp_path: Path) -> None:
    sup = Supervisor(tmp_path, grace_s=0.5)
    ready = _start(sup, tmp_path, "plant_rt", "ignore_term")
    sup.wait_ready(EVENT_S)
    pids = _pids(ready)
    t0 = time.monotonic()
    rep = sup.stop()["plant_rt"]
    assert 0.4 < time.monotonic() - t0 < EVENT_S  # the grace period (0.5 s) waited, then the kill
    assert rep.killed and not rep.clean and rep.returncode == -signal.SIGKILL
    assert "standin: configured" in rep.log_tail
    assert _wait_gone(pids) == []


def test_not_ready_in_time(tmp_path: Path) -> None:
    with Supervisor(tmp_path, grace_s=0.5) as sup:
        _start(sup, tmp_path, "plant_rt", "slow_ready")
        with pytest.raises(ChildFailed, match=r"plant_rt: not ready after 0\.5 s"):
            sup.wait_ready(0.5)


def test_missing_program_is_a_clear_failure(tmp_path: Path) -> None:
    with Supervisor(tmp_path) as sup, pytest.raises(ChildFailed, match="could not start"):
        sup.start("plant_rt", [str(tmp_path / "no_such_program")])


DRIVER = textwrap.dedent(r'''
    import sys, time
    from pathlib import Path
    from rig.supervisor import Supervisor, terminate_as_exception
    tmp, child_code, mode = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
    with terminate_as_exception():
        with Supervisor(tmp, grace_s=1.0) as sup:
            for name in ("plant_rt", "fw_host"):
                ready = tmp / f"{name}.ready"
                sup.start(name, [sys.executable, "-c", child_code, str(ready), mode],
                          ready_file=ready)
            sup.wait_ready(float(sys.argv[4]))
            print("ready", flush=True)
            while True:
                sup.sleep(0.1)
''')


def _driver(tmp: Path, mode: str) -> tuple[subprocess.Popen[str], list[int]]:
    proc = subprocess.Popen([sys.executable, "-c", DRIVER, str(tmp), CHILD, mode, str(EVENT_S)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "ready"
    pids = _pids(tmp / "plant_rt.ready") + _pids(tmp / "fw_host.ready")
    assert all(_alive(p) for p in pids)
    return proc, pids


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupting_the_rig_stops_every_child(tmp_path: Path, sig: int) -> None:
    proc, pids = _driver(tmp_path, "run")
    proc.send_signal(sig)
    proc.wait(timeout=EVENT_S)
    assert proc.returncode != 0
    assert _wait_gone(pids) == []


def test_sigkilled_rig_leaves_no_orphans(tmp_path: Path) -> None:
    # PR_SET_PDEATHSIG: the kernel kills the children when the rig dies without cleaning up
    proc, pids = _driver(tmp_path, "nogc")
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=EVENT_S)
    assert _wait_gone(pids) == []
