"""rig.drive.console.ConsoleClient against fw_host's console pty on a running virtual bench: every
command of protocols/console.json, every error code, line limits, time-outs, URLs, and the
``rig console`` command line."""

from __future__ import annotations

import csv
import os
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from waits import EVENT_S, RUN_S

from rig import _paths
from rig.commissioning.session import BenchSession
from rig.drive.console import (
    ConsoleClient,
    ConsoleError,
    ConsoleLinkError,
    ConsoleTimeout,
    ConsoleUsageError,
    grammar,
)

NUM = re.compile(r"[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?|nan|-?inf")


def csv_params() -> dict[str, dict[str, str]]:
    with (_paths.data_dir("protocols") / "parameters.csv").open(newline="") as fh:
        return {r["name"]: r for r in csv.DictReader(fh)}


@pytest.fixture
def bench(module_bench: BenchSession) -> Iterator[BenchSession]:
    """The shared bench with the console as the only commander; restored afterwards."""
    s = module_bench
    s.drive.in_command = False  # no cyclic DRIVE_CMD: the console owns the drive command
    con = s.console
    assert con is not None
    yield s
    con.timeout_s = EVENT_S  # (as the fixture's bench: conftest.GENEROUS)
    for line in ("reset", "disable", "mode speed", "fwmode realtime", "speed 0", "iq 0"):
        con.call(*line.split())
    for name in ("rs_ohm", "i_max_a"):
        con.set(name, float(csv_params()[name]["default"]))
    s.clock.advance(0.005)
    assert con.status()["state"] == "IDLE"


def snapshot(con: ConsoleClient) -> list[str]:
    return [line for line in con.call("params").data if "access=rw" in line]


def state(s: BenchSession) -> str:
    assert s.console is not None
    return s.console.status()["state"]


def advance_until(s: BenchSession, want: Callable[[], bool], bench_s: float = 1.0) -> None:
    s.clock.wait(want, bench_s, "console test condition", step_s=0.005)


def test_every_grammar_command_is_covered(bench: BenchSession) -> None:
    """A command added to console.json fails here until it has a test below."""
    assert set(grammar().commands) == set(COVERED)


def test_help_version_ping(bench: BenchSession) -> None:
    con = bench.console
    assert con is not None
    spec = grammar()
    reply = con.call("help")
    assert reply.payload == str(len(spec.commands))
    assert len(reply.data) == len(spec.commands)
    for line, cmd in zip(reply.data, spec.commands.values(), strict=True):
        assert line.startswith(cmd.name) and line.endswith(f" : {cmd.summary}"), line
    assert con.help() == list(reply.data)
    v = con.version()
    assert set(v) >= {"fw_host", "core", "console"} and v["console"] == str(spec.version)
    con.ping()
    assert con.request("ping").final == "OK"


def test_status_and_counters(bench: BenchSession) -> None:
    con = bench.console
    assert con is not None
    st = con.status()
    assert st["state"] == "IDLE" and st["fault_name"] == "NONE" and st["enable"] == "0"
    for key in ("speed_ref", "speed_ramp", "speed", "iq_ref_cmd", "id", "iq", "id_ref",
                "iq_ref", "theta"):
        assert NUM.fullmatch(st[key]), (key, st[key])
    before = int(con.counters()["isr"])
    period = int(st["period"])
    bench.clock.advance(0.01)
    after = con.counters()
    assert int(after["isr"]) == before + 100  # 10 ms of lockstep bench time = 100 ISRs
    assert int(con.status()["period"]) == period + 100
    assert {"console_lines", "console_errors", "param_reqs"} <= set(after)


def test_params_get_set_against_the_csv(bench: BenchSession) -> None:
    con = bench.console
    assert con is not None
    rows = con.params()
    table = csv_params()
    assert [r["name"] for r in rows] == sorted(table, key=lambda n: int(table[n]["id"]))
    for r in rows:
        t = table[r["name"]]
        assert r["id"] == t["id"] and r["access"] == t["access"]
        assert float(r["min"]) == pytest.approx(float(t["min"]), rel=1e-6)
        assert float(r["max"]) == pytest.approx(float(t["max"]), rel=1e-6)
    assert con.get("rs_ohm") == pytest.approx(1.93, rel=1e-6)
    assert con.set("rs_ohm", 2.25) == 2.25
    assert con.call("get", "rs_ohm").payload == "2.25"


def test_drive_commands_speed_iq_mode_fwmode_enable_disable(bench: BenchSession) -> None:
    s, con = bench, bench.console
    assert con is not None and s.load is not None
    s.load.speed_hold(0.0)  # locked rotor
    assert con.mode("current") == "current"
    assert con.fwmode("id_zero") == "id_zero"
    assert con.iq(0.5) == 0.5
    assert con.speed(250.5) == 250.5
    con.enable()
    advance_until(s, lambda: state(s) == "RUN")
    st = con.status()
    assert (st["owner"], st["ctrl"], st["fw"], st["enable"]) == ("console", "current",
                                                                  "id_zero", "1")
    assert float(st["iq_ref_cmd"]) == 0.5 and float(st["speed_ref"]) == 250.5
    s.clock.advance(0.05)
    assert float(con.status()["iq"]) == pytest.approx(0.5, abs=0.05)
    con.disable()
    advance_until(s, lambda: state(s) == "IDLE")
    s.load.off()


def test_reset_after_a_fault_and_faulted_enable(bench: BenchSession) -> None:
    s, con = bench, bench.console
    assert con is not None
    # one DRIVE_CMD enable over CAN and then silence: the command time-out faults the drive
    s.link.send("DRIVE_CMD", {"enable": 1, "fault_reset": 0, "ctrl_mode": 1, "fw_mode": 2,
                              "alive": 1, "speed_ref": 0.0, "iq_ref": 0.0})
    advance_until(s, lambda: state(s) == "FAULT")
    assert con.status()["fault_name"] == "CMD_TIMEOUT"
    with pytest.raises(ConsoleError) as e:
        con.enable()
    assert e.value.code == 11 and e.value.name == "FAULTED"
    assert con.status()["state"] == "FAULT"  # nothing changed
    con.reset()
    advance_until(s, lambda: state(s) == "IDLE")
    assert con.status()["fault_name"] == "NONE"


def test_save_and_load(bench: BenchSession) -> None:
    con = bench.console
    assert con is not None
    n_rw = sum(1 for r in csv_params().values() if r["access"] == "rw")
    assert con.set("rs_ohm", 2.5) == 2.5
    assert con.save() == n_rw
    store = (bench.dir / "params.txt").read_text()
    assert re.search(r"^rs_ohm = 2\.5\b", store, re.M), store
    assert con.set("rs_ohm", 3.0) == 3.0
    assert con.load() == 1  # one parameter changed back
    assert con.get("rs_ohm") == 2.5


ERRORS = [
    ("spin", 1), ("HELP", 1), ("get", 4), ("get rs_ohm extra", 4), ("speed", 4),
    ("enable now", 4), ("speed fast", 5), ("set rs_ohm 0x10", 5), ("set rs_ohm nan", 5),
    ("mode torque", 5), ("fwmode mtpa", 5), ("get bogus", 6), ("set bogus 1", 6),
    ("set fw_version 2", 7), ("set rs_ohm 1000", 8), ("set ld_h 0.05", 8),
    ("speed 5000", 8), ("iq 50", 8),
]


@pytest.mark.parametrize(("line", "code"), ERRORS, ids=[e[0] for e in ERRORS])
def test_error_replies_change_nothing(bench: BenchSession, line: str, code: int) -> None:
    con = bench.console
    assert con is not None
    before, st0 = snapshot(con), con.status()
    reply = con.request(line)
    assert not reply.ok and reply.code == code, reply.line
    assert reply.error_name == grammar().errors[code]
    assert reply.message.strip()
    assert snapshot(con) == before
    st1 = con.status()
    for key in ("state", "enable", "ctrl", "fw", "speed_ref", "iq_ref_cmd"):
        assert st1[key] == st0[key], key


def test_bad_character_and_overlong_lines(bench: BenchSession) -> None:
    con = bench.console
    assert con is not None
    limit = grammar().max_line
    before = snapshot(con)
    con.write_raw(b"set rs_ohm 5\x01\r\n")
    assert con.read_reply().code == 2
    long_line = "set rs_ohm 5" + " " * (limit - 12) + "0"  # limit + 1 characters
    assert len(long_line) == limit + 1
    reply = con.request(long_line)
    assert reply.code == 3 and reply.error_name == "LINE_TOO_LONG"
    con.write_raw(b"set rs_ohm 5" + b"9" * 200 + b"\x02\r\n")  # both: ERR 3 wins
    assert con.read_reply().code == 3
    assert snapshot(con) == before
    at_limit = "get rs_ohm" + " " * (limit - 10)  # exactly the limit: accepted
    assert con.request(at_limit).ok
    with pytest.raises(ConsoleUsageError):
        con.call("set", "rs_ohm", "5" * limit)  # the client refuses before sending


def test_busy_while_enabled_and_store_error(bench: BenchSession) -> None:
    s, con = bench, bench.console
    assert con is not None and s.load is not None
    s.load.speed_hold(0.0)
    con.call("mode", "current")
    con.call("fwmode", "id_zero")
    con.enable()
    advance_until(s, lambda: state(s) == "RUN")
    before = snapshot(con)
    r = con.request("set rs_ohm 2")
    assert r.code == 9 and r.error_name == "BUSY"
    assert con.request("set pll_bw_hz 80").ok  # ids >= 100 are not configuration
    con.disable()
    advance_until(s, lambda: state(s) == "IDLE")
    s.load.off()
    assert con.set("pll_bw_hz", 60.0) == 60.0
    assert snapshot(con) == before
    store = s.dir / "params.txt"
    good = store.read_text()
    try:
        store.write_text("rs_ohm = banana\n")
        r = con.request("load")
        assert r.code == 10 and r.error_name == "STORE_ERROR" and "params.txt" in r.message
        assert snapshot(con) == before
    finally:
        store.write_text(good)


def test_local_checks_send_nothing(bench: BenchSession) -> None:
    con = bench.console
    assert con is not None
    lines = int(con.counters()["console_lines"])
    for bad in (("spin",), ("speed", "fast"), ("mode", "torque"), ("get",)):
        with pytest.raises(ConsoleUsageError):
            con.call(*bad)
    assert int(con.counters()["console_lines"]) == lines + 1  # only the counters request


COVERED = {
    "help": test_help_version_ping, "version": test_help_version_ping,
    "ping": test_help_version_ping, "status": test_status_and_counters,
    "counters": test_status_and_counters, "params": test_params_get_set_against_the_csv,
    "get": test_params_get_set_against_the_csv, "set": test_params_get_set_against_the_csv,
    "enable": test_drive_commands_speed_iq_mode_fwmode_enable_disable,
    "disable": test_drive_commands_speed_iq_mode_fwmode_enable_disable,
    "speed": test_drive_commands_speed_iq_mode_fwmode_enable_disable,
    "iq": test_drive_commands_speed_iq_mode_fwmode_enable_disable,
    "mode": test_drive_commands_speed_iq_mode_fwmode_enable_disable,
    "fwmode": test_drive_commands_speed_iq_mode_fwmode_enable_disable,
    "reset": test_reset_after_a_fault_and_faulted_enable,
    "save": test_save_and_load, "load": test_save_and_load,
}


# -- links -----------------------------------------------------------------------------


def test_silent_port_times_out_clearly() -> None:
    master, slave = os.openpty()
    try:
        con = ConsoleClient(os.ttyname(slave), timeout_s=0.3)
        t0 = time.monotonic()
        with pytest.raises(ConsoleTimeout, match=r"no reply to 'ping' within 0.3 s"):
            con.ping()
        assert 0.3 <= time.monotonic() - t0 < EVENT_S  # the time-out waited, nothing hangs
        con.close()
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port_is_a_link_error() -> None:
    with pytest.raises(ConsoleLinkError, match="cannot open"):
        ConsoleClient("/dev/does-not-exist-ttyX").open()


def test_socket_url_reaches_the_same_console(bench: BenchSession) -> None:
    """``socket://`` (a terminal server): a TCP bridge to the pty stands in for one."""
    pty_path = bench.endpoints.console_port
    assert pty_path
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    stop = threading.Event()

    def bridge() -> None:
        conn, _ = server.accept()
        fd = os.open(pty_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        conn.settimeout(0.01)
        try:
            while not stop.is_set():
                try:
                    data = conn.recv(4096)
                    if not data:
                        return
                    os.write(fd, data)
                except TimeoutError:
                    pass
                try:
                    out = os.read(fd, 4096)
                    conn.sendall(out)
                except BlockingIOError:
                    pass
        finally:
            os.close(fd)
            conn.close()

    t = threading.Thread(target=bridge, daemon=True)
    t.start()
    try:
        with ConsoleClient(f"socket://127.0.0.1:{port}", timeout_s=EVENT_S) as con:
            con.ping()
            assert con.get("rs_ohm") == pytest.approx(1.93, rel=1e-6)
    finally:
        stop.set()
        t.join(2.0)
        server.close()


# -- the command line ------------------------------------------------------------------


def rig_cli(*args: str, stdin: str | None = None, timeout: float = RUN_S
            ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rig", *args], input=stdin,
                          capture_output=True, text=True, timeout=timeout, check=False)


# `rig console`'s reply time-out (2 s unless told) made a ceiling a loaded machine cannot reach
REPLY = ("--timeout", f"{EVENT_S:g}")


def test_cli_scripted_commands(bench: BenchSession) -> None:
    port = str(bench.endpoints.console_port)
    done = rig_cli("console", "--port", port, *REPLY, "--command", "ping", "--command",
                   "get rs_ohm")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["OK", "OK 1.93"]
    done = rig_cli("console", "--port", port, *REPLY, "--command", "spin", "--command", "ping")
    assert done.returncode == 1 and done.stdout.startswith("ERR 1 ")
    assert "OK" not in done.stdout.splitlines()  # stopped at the first ERR
    done = rig_cli("console", "--port", port, *REPLY, "--keep-going", stdin="spin\n\nhelp\n")
    lines = done.stdout.splitlines()
    assert done.returncode == 1 and lines[0].startswith("ERR 1 ")
    assert lines[-1] == f"OK {len(grammar().commands)}" and lines[1].startswith("- help")


def test_cli_port_errors(tmp_path: Path) -> None:
    done = rig_cli("console", "--port", str(tmp_path / "nothing"), "--command", "ping")
    assert done.returncode == 3 and "cannot open" in done.stderr


def test_cli_interactive_on_a_terminal(bench: BenchSession) -> None:
    """stdin a terminal: prompt, line editing (readline), replies, Ctrl-D ends."""
    import select

    port = str(bench.endpoints.console_port)
    master, slave = os.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "rig", "console", "--port", port, *REPLY],
                            stdin=slave, stdout=slave, stderr=slave, close_fds=True)
    os.close(slave)
    seen = b""

    def read_until(token: bytes, timeout: float = EVENT_S) -> None:
        """Reads until token appears in what arrives from now on."""
        nonlocal seen
        seen = b""
        deadline = time.monotonic() + timeout
        while token not in seen:
            assert time.monotonic() < deadline, seen
            if select.select([master], [], [], 0.1)[0]:
                try:
                    seen += os.read(master, 4096)
                except OSError:
                    break

    try:
        read_until(b"> ")
        os.write(master, b"get rs_ohm\r")
        read_until(b"OK 1.93\r\n> ")
        os.write(master, b"spin\r")
        read_until(b"> ")  # the reply, then the next prompt: readline reads again
        assert b"ERR 1 " in seen
        os.write(master, b"\x04")  # Ctrl-D
        assert proc.wait(EVENT_S) == 1  # an ERR reply was seen
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
