"""The program: flags, exit codes, counters JSON, parameter files at start."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest
from fwhost_support import Peer, StartFw, fw_binary
from waits import EVENT_S

COUNTER_KEYS = {
    "program", "mode", "transport", "isr", "isr_no_data", "repeats", "last_period", "pwm_sent",
    "pwm_invalid", "overruns", "max_latency_us", "rx_rejected", "rejects", "resyncs", "syncs",
    "drive_cmds", "cmds_refused", "limits", "param_reqs", "status_frames", "heartbeats",
    "tlm_frames", "trace_records", "trace_sent", "trace_errors", "console_sessions",
    "console_lines", "console_errors", "console_keepalive_lapses", "console_out_dropped",
    "state", "fault_code", "fault_name", "core_overruns", "tx_frames", "tx_drops", "tx_errors",
    "rx_frames", "rx_overflows", "rx_malformed", "rx_filtered", "non_data_frames",
    "foreign_entries", "peers_beyond_limit", "tx_ids", "rx_ids", "rt",
    # the lossless unixcan node's back-pressure (issue 36.5): zero on SocketCAN
    "tx_stalls", "tx_stall_ms_total", "tx_stall_ms_max", "tx_stall_failures", "rx_pending_max",
    "listener_drops",
}


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(fw_binary()), *args], capture_output=True, text=True,
                          timeout=30)


def test_help_lists_every_flag() -> None:
    r = run("--help")
    assert r.returncode == 0
    for flag in ("--bus", "--channel", "--lockstep", "--realtime", "--trace", "--send-trace",
                 "--ready-file", "--max-periods", "--params", "--config", "--set",
                 "--tlm-div", "--pty-link", "--no-console", "--console-timeout-ms",
                 "--spin-us", "--node", "--rt-priority"):
        assert flag in r.stdout, flag


@pytest.mark.parametrize("args, needle", [
    (["--bogus"], "unknown option --bogus"),
    (["--tlm-div", "x"], "--tlm-div x"),
    (["--max-periods", "-1"], "--max-periods -1"),
    (["--set", "no_such=1"], "field 'no_such': unknown parameter"),
    (["--set", "rs_ohm=1000"], "field 'rs_ohm': value 1000 outside [0.01, 100]"),
    (["--set", "rs_ohm"], "expected 'name = value'"),
    (["--set", "fw_version=2"], "field 'fw_version': read-only"),
    (["--set", "ld_h=0.05"], "field 'ld_h'"),
    (["extra"], "unexpected argument 'extra'"),
])
def test_bad_arguments_exit_2(args: list[str], needle: str) -> None:
    r = run("--no-console", *args)
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr


@pytest.mark.parametrize("text, line, needle", [
    ("rs_ohm = 2\nbogus = 1\n", 2, "field 'bogus': unknown parameter"),
    ("# c\n\nrs_ohm = 200\n", 3, "field 'rs_ohm': value 200 outside [0.01, 100] ohm"),
    ("rs_ohm = 2.0.1\n", 1, "field 'rs_ohm': value '2.0.1' is not a decimal number"),
    ("rs_ohm = 0x10\n", 1, "is not a decimal number"),
    ("rs_ohm 2\n", 1, "expected 'name = value'"),
    ("rs_ohm = 2\nrs_ohm = 3\n", 2, "field 'rs_ohm': set twice (first on line 1)"),
    ("lq_h = 0.04\nld_h = 0.05\n", 2, "field 'ld_h': value 0.05"),
    ("pole_pairs = 2.5\n", 1, "field 'pole_pairs'"),
    ("fw_version = 1\n", 1, "field 'fw_version': read-only"),
    ("x" * 300 + "\n", 1, "longer than 255"),
    ("# c\nrs_ohm = 2\0junk\n", 2, "a NUL byte (not a text file)"),  # issue 23.17: was
    ("rs_ohm = 2\0", 1, "a NUL byte"),                                # "longer than 255"
])
def test_bad_parameter_file_exits_2_naming_line_and_field(
        tmp_path: Path, text: str, line: int, needle: str) -> None:
    f = tmp_path / "p.txt"
    f.write_text(text)
    r = run("--no-console", "--params", str(f))
    assert r.returncode == 2, r.stderr
    assert f"{f}:{line}:" in r.stderr and needle in r.stderr, r.stderr


def test_a_parameter_file_that_never_ends_exits_2(tmp_path: Path) -> None:
    """Issue 23.17: `--params /dev/zero` looped for ever (and a file of endless blank lines
    would): a NUL byte ends it at once, and a file is read up to 1 MiB."""
    r = run("--no-console", "--params", "/dev/zero")
    assert r.returncode == 2 and "/dev/zero:1: a NUL byte" in r.stderr, r.stderr
    f = tmp_path / "blank.txt"
    f.write_text("\n" * (2 << 20))
    r = run("--no-console", "--params", str(f))
    assert r.returncode == 2 and "longer than 1048576 bytes" in r.stderr, r.stderr


def test_missing_parameter_file_exits_2(tmp_path: Path) -> None:
    r = run("--no-console", "--config", str(tmp_path / "none.txt"))
    assert r.returncode == 2 and "none.txt: cannot read" in r.stderr


def test_order_of_constrained_parameters_does_not_matter(start_fw: StartFw, peer: Peer,
                                                         tmp_path: Path) -> None:
    f = tmp_path / "p.txt"
    f.write_text("ld_h = 0.04\nlq_h = 0.05\n")  # ld_h first would be > the default lq_h
    fw = start_fw("--params", str(f), "--set", "soc_on_us=30", "--set", "tmin_us=40")
    from fwhost_support import param_ids

    ids = param_ids()
    assert peer.param(0, ids["ld_h"])["value"] == pytest.approx(0.04)
    assert peer.param(0, ids["soc_on_us"])["value"] == pytest.approx(30.0)
    assert fw.stop() == 0


@pytest.mark.vcan
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_exits_0_with_json_counters(start_fw: StartFw, peer: Peer, sig: int) -> None:
    fw = start_fw()
    peer.run(0, 3)
    assert fw.stop(sig) == 0
    c = fw.counters()
    assert set(c) == COUNTER_KEYS
    assert c["program"] == "fw_host" and c["mode"] == "lockstep" and c["isr"] == 3
    assert c["transport"] in ("unixcan", "socketcan")
    assert set(c["rejects"]) == {"unknown_id", "bad_length", "wrong_frame_type",
                                 "out_of_range", "malformed", "stale_period",
                                 "future_period", "incomplete", "refused"}


def test_max_periods_ends_the_run(start_fw: StartFw, peer: Peer) -> None:
    fw = start_fw("--max-periods", "4", "--realtime", "--rt-priority", "0")
    peer.run(0, 4)
    assert fw.proc.wait(timeout=EVENT_S) == 0
    c = fw.counters()
    assert c["isr"] == 4 and c["mode"] == "realtime" and c["overruns"] >= 0


def test_ready_file_holds_the_pid(start_fw: StartFw, tmp_path: Path) -> None:
    fw = start_fw()
    assert (tmp_path / "fw0.ready").read_text().strip() == str(fw.proc.pid)
    assert fw.stop() == 0


def test_spin_does_not_change_results(start_fw: StartFw, peer: Peer) -> None:
    fw = start_fw("--spin-us", "200")
    pwms = peer.run(0, 20)  # (each PWM awaited with a ceiling: a spin that never ends fails)
    assert [p["period"] for p in pwms] == list(range(1, 21))
    assert fw.stop() == 0


def test_receives_exactly_the_dbc_id_ranges(start_fw: StartFw, peer: Peer) -> None:
    # fw_host's receive filters are drive.dbc's and vio.dbc's ID ranges (HilIdFirst ..
    # HilIdLast), no wider: ids just outside vio.dbc's 0x10-0x2F never reach the program.
    fw = start_fw()
    outside = (0x0F, 0x30, 0x3F, 0x200)
    for ident in outside:
        peer.send_raw(ident, bytes(8), fd=False)
    peer.run(0, 1)  # its PWM comes after fw_host took everything sent before
    assert fw.stop() == 0
    c = fw.counters()
    if c["transport"] != "unixcan":
        pytest.skip("SocketCAN filters in the kernel: filtered frames are not counted")
    assert c["rx_filtered"] == len(outside) and c["rx_rejected"] == 0
    assert not {str(i) for i in outside} & set(c["rx_ids"]) and str(0x11) in c["rx_ids"]
