"""The SCI console on the pseudo-terminal (protocols/console.md), with pyserial as the client."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial  # type: ignore[import-untyped]
from fwhost_support import FAULT_ADC_LOSS, STATE, FwProcess, Peer, StartFw, param_ids
from waits import EVENT_S, RUN_S, ceiling

from rig import protocols

SPEC = json.loads((protocols.path("drive").parent / "console.json").read_text())
P = param_ids()
NUM = r"[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?"


class Console:
    def __init__(self, link: Path) -> None:
        self.port = serial.Serial(str(link), baudrate=115200, timeout=EVENT_S)

    def write(self, raw: bytes) -> None:
        self.port.write(raw)

    def reply(self) -> list[str]:
        """Lines up to and including the final OK / ERR line."""
        lines: list[str] = []
        while True:
            raw = self.port.readline()
            assert raw.endswith(b"\r\n"), f"no complete line (got {raw!r}, before: {lines})"
            text = raw[:-2].decode("ascii")
            lines.append(text)
            if text == "OK" or text.startswith(("OK ", "ERR ")):
                return lines
            assert text.startswith("- "), text

    def cmd(self, line: str, end: bytes = b"\r\n") -> list[str]:
        self.write(line.encode() + end)
        return self.reply()

    def one(self, line: str) -> str:
        lines = self.cmd(line)
        assert len(lines) == 1, lines
        return lines[0]

    def kv(self, line: str) -> dict[str, str]:
        final = self.one(line)
        assert final.startswith("OK "), final
        return dict(w.split("=", 1) for w in final[3:].split(" "))

    def close(self) -> None:
        self.port.close()


@pytest.fixture
def console_fw(start_fw: StartFw, tmp_path: Path) -> Iterator[tuple[FwProcess, Console]]:
    link = tmp_path / "console"
    store = tmp_path / "params.txt"
    store.write_text("rs_ohm = 1.93\n")
    fw = start_fw("--pty-link", str(link), "--params", str(store))
    con = Console(link)
    try:
        yield fw, con
    finally:
        con.close()


def err_code(line: str) -> int:
    m = re.match(r"ERR (\d+) \S", line)
    assert m, line
    return int(m.group(1))


def test_link_points_to_a_pty_and_is_removed_at_exit(start_fw: StartFw, tmp_path: Path) -> None:
    link = tmp_path / "console"
    fw = start_fw("--pty-link", str(link))
    assert link.is_symlink() and str(link.resolve()).startswith("/dev/pts/")
    assert fw.stop() == 0
    assert not link.exists() and not link.is_symlink()


def test_help_version_and_ping(console_fw: tuple[FwProcess, Console]) -> None:
    _, con = console_fw
    lines = con.cmd("help")
    cmds = SPEC["commands"]
    assert lines[-1] == f"OK {len(cmds)}"
    assert len(lines) == len(cmds) + 1
    for line, c in zip(lines, cmds, strict=False):
        assert line.startswith(f"- {c['name']}") and line.endswith(f" : {c['summary']}")
    assert re.fullmatch(r"OK fw_host=\S+ core=\d+ console=1", con.one("version"))
    assert con.one("ping") == "OK"


def test_status_and_counters_fields(console_fw: tuple[FwProcess, Console], peer: Peer) -> None:
    _, con = console_fw
    peer.run(0, 3)
    st = con.kv("status")
    assert list(st)[:7] == ["state", "fault", "fault_name", "enable", "ctrl", "fw", "owner"]
    assert st["state"] == "IDLE" and st["fault"] == "0" and st["fault_name"] == "NONE"
    assert st["owner"] == "none" and st["period"] == "2"
    for key in ("speed_ref", "speed_ramp", "speed", "iq_ref_cmd", "id", "iq", "id_ref",
                "iq_ref", "theta"):
        assert re.fullmatch(NUM, st[key]), (key, st[key])
    for key in ("est_valid", "polarity_ok", "cmd_status", "overruns", "rx_rejected"):
        assert st[key].isdigit(), key
    c = con.kv("counters")
    assert c["isr"] == "3" and c["pwm_sent"] == "3" and c["rx_rejected"] == "0"
    assert set(c) >= {"isr_no_data", "repeats", "overruns", "max_latency_us", "resyncs",
                      "drive_cmds", "cmds_refused", "param_reqs", "console_lines",
                      "console_errors"}


def test_params_lists_the_whole_table(console_fw: tuple[FwProcess, Console]) -> None:
    _, con = console_fw
    lines = con.cmd("params")
    assert lines[-1] == f"OK {len(P)}"
    pat = re.compile(rf"- id=(\d+) name=([a-z0-9_]+) value=({NUM}) unit=(\S+) "
                     rf"min=({NUM}) max=({NUM}) access=(rw|ro)")
    seen = {}
    for line in lines[:-1]:
        m = pat.fullmatch(line)
        assert m, line
        seen[m.group(2)] = int(m.group(1))
    assert seen == P
    assert "- id=1 name=rs_ohm value=1.93 unit=ohm min=0.01 max=100 access=rw" in lines
    assert any(line.startswith("- id=300 name=fw_version value=1 ") and
               line.endswith("access=ro") for line in lines)


def test_get_and_set(console_fw: tuple[FwProcess, Console], peer: Peer) -> None:
    _, con = console_fw
    assert con.one("get rs_ohm") == "OK 1.93"
    assert con.one("set rs_ohm 2.5") == "OK 2.5"
    assert con.one("get   rs_ohm\t") == "OK 2.5"
    assert peer.param(0, P["rs_ohm"])["value"] == pytest.approx(2.5)  # same table as the bus
    assert con.one("set ld_h 1.6e-2") == "OK 0.016"
    bad = {
        "get": 4, "get rs_ohm extra": 4, "set rs_ohm": 4, "get bogus": 6, "set bogus 1": 6,
        "set rs_ohm abc": 5, "set rs_ohm 0x10": 5, "set rs_ohm nan": 5, "set rs_ohm 1e": 5,
        "set rs_ohm 1000": 8, "set ld_h 0.05": 8, "set pole_pairs 2.5": 8,
        "set fw_version 2": 7, "set a b c d e f": 4,
    }
    for line, code in bad.items():
        assert err_code(con.one(line)) == code, line
    assert con.one("get rs_ohm") == "OK 2.5"     # nothing changed
    assert con.one("get ld_h") == "OK 0.016"


def test_drive_commands_act_on_the_core(console_fw: tuple[FwProcess, Console],
                                        peer: Peer) -> None:
    _, con = console_fw
    pwms = peer.run(0, 2)
    assert con.one("mode current") == "OK current"
    assert con.one("fwmode id_zero") == "OK id_zero"
    st = peer.status(lambda v: v["ctrl_mode"] == 1 and v["fw_mode"] == 2)
    assert st["state"] == STATE["IDLE"]
    assert con.one("fwmode conventional") == "OK conventional"
    assert con.one("mode speed") == "OK speed"
    assert con.one("speed 250.5") == "OK 250.5"
    assert con.one("iq -1.25") == "OK -1.25"
    for line, code in {"speed 5000": 8, "speed fast": 5, "iq 50": 8, "mode torque": 5,
                       "fwmode": 4, "enable now": 4}.items():
        assert err_code(con.one(line)) == code, line
    assert con.one("enable") == "OK"
    pwm = peer.step(2, pwms[-1]["n_soc"])
    st = peer.status(lambda v: v["state"] == STATE["POLARITY"])
    assert st["ctrl_mode"] == 0 and st["fw_mode"] == 1
    s = con.kv("status")
    assert s["owner"] == "console" and s["enable"] == "1" and s["speed_ref"] == "250.5"
    assert s["iq_ref_cmd"] == "-1.25"
    assert con.one("disable") == "OK"
    peer.step(3, pwm["n_soc"])
    peer.status(lambda v: v["state"] == STATE["IDLE"])
    # a CAN command takes over (last writer wins)
    peer.command(enable=0, ctrl_mode=1)
    peer.status(lambda v: v["ctrl_mode"] == 1)
    assert con.kv("status")["owner"] == "can"


def test_reset_after_a_fault(console_fw: tuple[FwProcess, Console], peer: Peer) -> None:
    _, con = console_fw
    pwms = peer.run(0, 2)
    peer.step_after_loss(10, pwms[-1]["n_soc"])  # periods 2..9 lost: ADC-loss fault
    peer.status(lambda v: v["state"] == STATE["FAULT"] and v["fault_code"] == FAULT_ADC_LOSS)
    assert err_code(con.one("enable")) == 11
    assert con.one("reset") == "OK"
    pwms = peer.run(11, 2)
    peer.status(lambda v: v["state"] == STATE["IDLE"] and v["fault_code"] == 0)
    assert con.one("enable") == "OK"
    peer.run(13, 1, pwms[-1]["n_soc"])
    peer.status(lambda v: v["state"] == STATE["POLARITY"])


def test_save_and_load(console_fw: tuple[FwProcess, Console], tmp_path: Path) -> None:
    _, con = console_fw
    n_rw = sum(1 for c in con.cmd("params") if c.endswith("access=rw"))
    assert con.one("set pll_bw_hz 77") == "OK 77"
    assert con.one("save") == f"OK {n_rw}"
    assert "pll_bw_hz = 77" in (tmp_path / "params.txt").read_text()
    assert con.one("set pll_bw_hz 99") == "OK 99"
    assert con.one("set rs_ohm 3") == "OK 3"
    assert con.one("load") == "OK 2"
    assert con.one("get pll_bw_hz") == "OK 77"
    (tmp_path / "params.txt").write_text("rs_ohm = 5\nrs_ohm = 6\n")
    line = con.one("load")
    assert err_code(line) == 10 and "params.txt:2" in line
    assert con.one("get rs_ohm") == "OK 1.93"


def test_save_without_parameter_file(start_fw: StartFw, tmp_path: Path) -> None:
    link = tmp_path / "c"
    start_fw("--pty-link", str(link))
    con = Console(link)
    assert err_code(con.one("save")) == 10
    assert err_code(con.one("load")) == 10
    con.close()


def test_bad_lines(console_fw: tuple[FwProcess, Console]) -> None:
    fw, con = console_fw
    assert err_code(con.one("spin")) == 1
    assert err_code(con.one("HELP")) == 1                      # case-sensitive
    assert err_code(con.one("set rs_ohm 7" + " " * 90)) == 3   # too long: discarded whole
    assert con.one("get rs_ohm") == "OK 1.93"
    con.write(b"set rs_ohm 8\x01\r\n")
    assert err_code(con.reply()[0]) == 2
    con.write("set rs_ohm 9\u00e9\n".encode())
    assert err_code(con.reply()[0]) == 2
    assert con.one("get rs_ohm") == "OK 1.93"
    line80 = "get rs_ohm".ljust(80)
    assert con.one(line80) == "OK 1.93"                         # exactly the maximum
    assert err_code(con.one(line80 + " ")) == 3
    # blank lines get no reply; CR, LF and CR LF all end a line
    con.write(b"\r\n  \t \n\r")
    assert con.cmd("ping", b"\r") == ["OK"]
    assert con.cmd("ping", b"\n") == ["OK"]
    assert con.cmd("ping", b"\r\n") == ["OK"]
    con.port.timeout = 0.3
    assert con.port.read(100) == b""                            # no echo, nothing unsolicited
    assert fw.stop() == 0
    c = fw.counters()
    assert c["console_errors"] == 6 and c["console_sessions"] == 1


def test_console_keepalive_and_command_timeout(start_fw: StartFw, peer: Peer,
                                               tmp_path: Path) -> None:
    # The keep-alive is wall time: long enough that the 60 lockstep periods between two
    # console lines fit in it on a loaded machine; the silence is longer than it (a sleep
    # that only needs to last at least that long: a slower machine sleeps longer).
    keepalive_s = ceiling(3.0)
    link = tmp_path / "c"
    fw = start_fw("--pty-link", str(link), "--console-timeout-ms", str(round(keepalive_s * 1e3)),
                  "--set", "cmd_timeout_ms=3")
    con = Console(link)
    pwms = peer.run(0, 2)
    assert con.one("enable") == "OK"
    pwms = peer.run(2, 60, pwms[-1]["n_soc"])    # 6 ms of ISR time > cmd_timeout: refreshed
    assert pwms[-1]["gate_enable"] == 1
    assert con.kv("status")["state"] == "POLARITY"
    time.sleep(keepalive_s + 0.5)                # console silent for longer than the keep-alive
    pwms = peer.run(62, 40, pwms[-1]["n_soc"])
    assert pwms[-1]["gate_enable"] == 0
    s = con.kv("status")
    assert s["state"] == "FAULT" and s["fault_name"] == "CMD_TIMEOUT"
    con.close()
    assert fw.stop() == 0
    assert fw.counters()["console_keepalive_lapses"] == 1


def test_client_hangup_ends_the_console_session(start_fw: StartFw, peer: Peer,
                                                tmp_path: Path) -> None:
    link = tmp_path / "c"
    fw = start_fw("--pty-link", str(link), "--console-timeout-ms", "0",
                  "--set", "cmd_timeout_ms=3")
    con = Console(link)
    pwms = peer.run(0, 2)
    assert con.one("enable") == "OK"
    con.close()
    # the HAL sees the hang-up on its 10 ms probe (wall time), then the command times out
    # within 30 periods: lockstep periods until the gates are off (no keep-alive time-out
    # here, so nothing but the hang-up ends the session)
    period, n_soc = 2, int(pwms[-1]["n_soc"])
    deadline = time.monotonic() + EVENT_S
    while (pwm := peer.step(period, n_soc))["gate_enable"] != 0:
        assert time.monotonic() < deadline, "the hang-up never ended the console session"
        period, n_soc = period + 1, int(pwm["n_soc"])
    peer.status(lambda v: v["state"] == STATE["FAULT"])
    # a new client gets a fresh session
    con = Console(link)
    assert con.kv("status")["fault_name"] == "CMD_TIMEOUT"
    con.close()
    assert fw.stop() == 0
    assert fw.counters()["console_sessions"] == 2


def test_a_flood_of_lines_gets_every_reply(console_fw: tuple[FwProcess, Console]) -> None:
    """Issue 16.9: 20 000 pings from a client that reads slowly at first get 20 000 replies
    (the console stops reading lines while a reply waits: backpressure), none dropped."""
    import threading

    fw, con = console_fw
    n = 20_000
    lines = b"ping\r\n" * n
    writer = threading.Thread(target=con.write, args=(lines,), daemon=True)
    writer.start()
    time.sleep(1.0)  # the client reads nothing for a while: the replies back up
    got = b""
    deadline = time.monotonic() + RUN_S  # a bound for the failing case only
    while got.count(b"\r\n") < n and time.monotonic() < deadline:
        got += con.port.read(max(1, con.port.in_waiting))
    writer.join(timeout=EVENT_S)
    replies = got.split(b"\r\n")[:-1]
    assert len(replies) == n and all(r.startswith(b"OK") for r in replies), len(replies)
    assert fw.stop() == 0
    c = fw.counters()
    assert c["console_out_dropped"] == 0 and c["console_lines"] == n
