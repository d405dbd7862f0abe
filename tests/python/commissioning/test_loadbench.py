"""The load bench over Modbus: the register map, the virtual bench's server (a real process on
a real bus) and the rig's client. Exception codes are the Modbus specification's (Modbus
Application Protocol V1.1b3, section 7): 01 illegal function, 02 illegal data address,
03 illegal data value, 04 server device failure."""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import can
import pytest
from waits import EVENT_S, ceiling, wait_until

from rig import bus as rigbus
from rig import protocols
from rig.bench.description import ModbusSpec
from rig.commissioning.session import BenchSession
from rig.loadbench.client import LoadBench, LoadBenchError, ModbusExceptionError, register_map

ILLEGAL_FUNCTION, ILLEGAL_DATA_ADDRESS, ILLEGAL_DATA_VALUE, SERVER_DEVICE_FAILURE = 1, 2, 3, 4


# -- the map ---------------------------------------------------------------------------


def test_map_is_contiguous_and_fits_load_cmd() -> None:
    m = register_map()
    load_cmd = protocols.database("bench").get_message_by_name("LOAD_CMD")
    modes = {str(n) for n in (load_cmd.get_signal_by_name("mode").choices or {}).values()}
    assert set(m.holding["mode"].enum_load_cmd.values()) == modes
    for field, sig_name in (("torque_setpoint", "torque"), ("speed_setpoint", "speed"),
                            ("k_speed", "k_speed")):
        f, sig = m.holding[field], load_cmd.get_signal_by_name(sig_name)
        assert f.minimum is not None and f.maximum is not None
        assert sig.minimum <= f.minimum and f.maximum <= sig.maximum, field
    for table in ("holding", "input"):
        first, count = m.span(table)  # type: ignore[arg-type]
        assert first == 0 and count == sum(f.count for f in m.table(table).values())  # type: ignore[arg-type]
    assert m.word_order == "big"


def test_float32_is_ieee_high_word_first() -> None:
    f = register_map().holding["torque_setpoint"]
    raw = struct.pack(">f", -1.25)  # independent encoding: big-endian IEEE 754
    want = [int.from_bytes(raw[:2], "big"), int.from_bytes(raw[2:], "big")]
    assert f.encode(-1.25) == want
    assert f.decode(want) == -1.25


# -- a server on a bus -----------------------------------------------------------------


@dataclass
class Server:
    proc: subprocess.Popen[bytes]
    port: int
    channel: str
    spec: ModbusSpec


def start_server(tmp_path: Path, channel: str, *extra: str) -> Server:
    ready = tmp_path / "lb.ready"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rig", "loadbench", "serve", "--bus", "unixcan", "--channel",
         channel, "--port", "0", "--ready-file", str(ready), *extra],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + EVENT_S
    while not ready.exists():
        if proc.poll() is not None:
            raise AssertionError(proc.stderr.read().decode() if proc.stderr else "exited")
        assert time.monotonic() < deadline, "server not ready"
        time.sleep(0.02)
    port = int(json.loads(ready.read_text())["port"])
    return Server(proc, port, channel, ModbusSpec(port=port, timeout_s=EVENT_S,
                                                  watchdog_timeout_ms=GENEROUS_WATCHDOG_MS))


# The server's watchdog (wall time) far beyond any pause of a loaded machine; the watchdog
# test sets a short one of its own.
GENEROUS_WATCHDOG_MS = min(60000, round(EVENT_S * 1e3))


@pytest.fixture
def server(tmp_path: Path, unix_channel: str) -> Iterator[Server]:
    srv = start_server(tmp_path, unix_channel, "--watchdog-ms", str(GENEROUS_WATCHDOG_MS))
    yield srv
    srv.proc.send_signal(signal.SIGTERM)
    assert srv.proc.wait(EVENT_S) == 0


@pytest.fixture
def observer(unix_channel: str) -> Iterator[can.BusABC]:
    """A node listening for LOAD_CMD (opened before the commands are sent)."""
    cmd = protocols.database("bench").get_message_by_name("LOAD_CMD")
    bus = rigbus.open_bus("unixcan", unix_channel,
                          can_filters=[{"can_id": cmd.frame_id, "can_mask": 0x7FF}])
    yield bus
    bus.shutdown()


def load_cmds(bus: can.BusABC, wait: float = EVENT_S) -> list[dict[str, float]]:
    """The LOAD_CMD frames received, the first awaited for `wait` s (the server sends them
    before it answers the Modbus request, so the rest are already queued)."""
    msg = protocols.database("bench").get_message_by_name("LOAD_CMD")
    out = []
    while (f := bus.recv(timeout=wait)) is not None:
        out.append({k: float(v) for k, v in msg.decode(f.data, decode_choices=False).items()})
        wait = 0.05
    return out


def code_of(fn: object, *args: object) -> int:
    with pytest.raises(ModbusExceptionError) as e:
        fn(*args)  # type: ignore[operator]
    return e.value.code


def test_exception_codes_and_nothing_changes(server: Server) -> None:
    m = register_map()
    with LoadBench(server.spec) as lb:
        holding = lb.read_table("holding")
        _, n_hold = m.span("holding")
        _, n_in = m.span("input")
        assert code_of(lb.read_registers, "holding", n_hold, 1) == ILLEGAL_DATA_ADDRESS
        assert code_of(lb.read_registers, "holding", 0, n_hold + 1) == ILLEGAL_DATA_ADDRESS
        assert code_of(lb.read_registers, "input", n_in, 2) == ILLEGAL_DATA_ADDRESS
        assert code_of(lb.write_registers, n_hold + 10, [1]) == ILLEGAL_DATA_ADDRESS
        # read-only register, and half of a float32
        assert code_of(lb.write_registers, m.holding["map_version"].address, [7]) == \
            ILLEGAL_DATA_ADDRESS
        t = m.holding["torque_setpoint"]
        assert code_of(lb.write_registers, t.address, t.encode(1.0)[:1]) == \
            ILLEGAL_DATA_ADDRESS
        assert code_of(lb.write_registers, t.address + 1, [0]) == ILLEGAL_DATA_ADDRESS
        # values outside the field's range or enumeration, or not finite
        for name, value in (("torque_setpoint", 20.0), ("speed_setpoint", -5000.0),
                            ("k_speed", -0.1), ("torque_setpoint", math.nan),
                            ("mode", 7), ("watchdog_timeout_ms", 50), ("control", 0x10)):
            f = m.holding[name]
            assert code_of(lb.write_registers, f.address, f.encode(value)) == \
                ILLEGAL_DATA_VALUE, name
        # no coils or discrete inputs on this device
        client = lb._client
        assert client is not None
        assert client.read_coils(0, count=1).exception_code == ILLEGAL_FUNCTION
        assert client.read_discrete_inputs(0, count=1).exception_code == ILLEGAL_FUNCTION
        assert client.write_coil(0, True).exception_code == ILLEGAL_FUNCTION
        assert lb.read_table("holding") == holding


def test_setpoints_become_load_commands(server: Server, observer: can.BusABC) -> None:
    m = register_map()
    load_cmds(observer, 0.2)  # the server's initial OFF
    modes = {str(n): int(v) for v, n in (protocols.database("bench").get_message_by_name(
        "LOAD_CMD").get_signal_by_name("mode").choices or {}).items()}
    with LoadBench(server.spec) as lb:
        lb.torque_mode(1.5, k_speed=0.01)
        got = load_cmds(observer)
        assert got[-1]["mode"] == modes["TORQUE"]
        assert got[-1]["torque"] == pytest.approx(1.5) and got[-1]["k_speed"] == \
            pytest.approx(0.01)
        lb.speed_hold(-250.0)
        last = load_cmds(observer)[-1]
        assert last["mode"] == modes["SPEED_HOLD"] and last["speed"] == pytest.approx(-250.0)
        assert int(lb.read("input", "command_seq")) == int(last["seq"])
        status = lb.measure().status
        assert status["load_active"] and status["speed_hold"] and status["watchdog_armed"]
        lb.off()
        last = load_cmds(observer)[-1]
        assert last["mode"] == modes["OFF"] and last["torque"] == 0.0
        assert int(lb.read("holding", "mode")) == m.mode_value("off")


def test_watchdog_zeroes_the_load(server: Server, observer: can.BusABC) -> None:
    """Refreshed for longer than its time-out, the load stays on; silent, it is zeroed, and
    not before the time-out. The watchdog is wall time: the refreshes (every 50 ms) must
    come within it on a loaded machine, so it is 2 s (scaled like every ceiling)."""
    m = register_map()
    timeout_ms = min(60000, round(ceiling(2.0) * 1e3))
    with LoadBench(replace(server.spec, watchdog_timeout_ms=timeout_ms)) as lb:
        lb.set_watchdog_timeout(timeout_ms)
        assert int(lb.read("holding", "watchdog_timeout_ms")) == timeout_ms
        lb.torque_mode(2.0)
        load_cmds(observer, 0.1)
        refreshed_until = time.monotonic() + 1.5 * timeout_ms / 1e3
        while True:  # refreshed for 1.5 time-outs: stays on
            last_refresh = time.monotonic()
            lb.refresh_watchdog(force=True)
            if last_refresh > refreshed_until:
                break
            time.sleep(0.05)
        assert int(lb.read("holding", "mode")) == m.mode_value("torque")
        assert int(lb.read("input", "watchdog_echo")) == int(lb.read("holding", "watchdog"))
        # silent from here (reads do not refresh it): zeroed, awaited with a ceiling
        wait_until(lambda: int(lb.read("holding", "mode")) == m.mode_value("off"),
                   "the watchdog zeroing the load", EVENT_S + timeout_ms / 1e3, poll_s=0.05)
        assert time.monotonic() - last_refresh >= timeout_ms / 1e3  # not before its time
        h = lb.read_table("holding")
        assert h["mode"] == m.mode_value("off") and h["torque_setpoint"] == 0.0
        assert lb.faults() == ["watchdog"]
        assert int(lb.read("input", "watchdog_expiries")) == 1
        assert lb.measure().status["fault"]
        last = load_cmds(observer)[-1]
        assert last["torque"] == 0.0 and last["mode"] == 2  # OFF on the wire
        f = m.holding["mode"]
        assert code_of(lb.write_registers, f.address, f.encode(1)) == SERVER_DEVICE_FAILURE
        lb.reset_faults()
        lb.torque_mode(0.5)
        assert int(lb.read("holding", "mode")) == m.mode_value("torque")
        lb.off()


def test_measurements_follow_the_plant(module_bench: BenchSession) -> None:
    """Speed hold over Modbus: the very next lockstep grant runs at that speed (the server
    sends LOAD_CMD before it answers), and the input registers show the plant's speed. The
    server reads BENCH_TRUTH beside the lockstep (a listener, not a lockstep node), so its
    registers may lag the clock on a loaded machine: they are awaited, with a ceiling."""
    s = module_bench
    lb = s.load
    assert lb is not None
    seen: list[tuple[int, float]] = []
    rpm_per_rad_s = 60.0 / (2.0 * math.pi)
    remove = s.link.on("BENCH_TRUTH",
                       lambda v: seen.append((int(v["period"]), float(v["omega_m"]))))
    try:
        start = s.clock.now()
        lb.speed_hold(600.0)
        s.clock.advance(0.01)
        first = [w for p, w in seen if p * 1e-4 >= start - 1e-9]
        assert first and first[0] * rpm_per_rad_s == pytest.approx(600.0, rel=1e-6)
        wait_until(lambda: lb.measure().speed_rpm == pytest.approx(600.0, rel=1e-4),
                   "the load bench's registers showing 600 r/min", poll_s=0.05)
        m = lb.measure()
        assert m.status["measurement_valid"] and m.sample_counter > 0
        lb.set_speed(0.0)
        s.clock.advance(0.01)
        wait_until(lambda: lb.measure().speed_rpm == pytest.approx(0.0, abs=1e-6),
                   "the load bench's registers showing 0 r/min", poll_s=0.05)
    finally:
        remove()
        lb.off()


# -- dead peers ------------------------------------------------------------------------


def test_closed_port_fails_at_once() -> None:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()  # nobody listens there now
    t0 = time.monotonic()
    with pytest.raises(LoadBenchError, match="cannot connect"):
        LoadBench(ModbusSpec(port=port, timeout_s=EVENT_S)).open()
    # at once: refused, not left to the time-out (half of it: a margin for any machine)
    assert time.monotonic() - t0 < EVENT_S / 2


def test_silent_tcp_peer_times_out() -> None:
    server = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []
    t = threading.Thread(target=lambda: held.append(server.accept()[0]), daemon=True)
    t.start()
    try:
        t0 = time.monotonic()
        with pytest.raises(LoadBenchError, match=r"no valid answer within 0.5 s"):
            LoadBench(ModbusSpec(port=server.getsockname()[1], timeout_s=0.5)).open()
        assert 0.5 <= time.monotonic() - t0 < EVENT_S  # the time-out waited, nothing hangs
    finally:
        for c in held:
            c.close()
        server.close()


def test_silent_serial_peer_times_out() -> None:
    master, slave = os.openpty()
    try:
        # no parity: a pseudo-terminal refuses parity together with pyserial's
        # inter-byte time-out (termios EINVAL), as the next check shows
        spec = ModbusSpec(kind="rtu", device=os.ttyname(slave), baudrate=19200, parity="N",
                          timeout_s=0.5)
        t0 = time.monotonic()
        with pytest.raises(LoadBenchError, match=r"modbus rtu .* no valid answer within 0.5 s"):
            LoadBench(spec).open()
        assert 0.5 <= time.monotonic() - t0 < EVENT_S  # the time-out waited, nothing hangs
        with pytest.raises(LoadBenchError, match=r"cannot connect: .*Invalid argument"):
            LoadBench(replace(spec, parity="E")).open()
    finally:
        os.close(master)
        os.close(slave)
    with pytest.raises(LoadBenchError, match=r"cannot connect: .*No such file"):
        LoadBench(ModbusSpec(kind="rtu", device="/dev/does-not-exist-ttyX")).open()


def test_drive_left_disabled_when_the_load_bench_hangs(make_desc: object,
                                                        tmp_path: Path) -> None:
    """The load bench stops answering while the drive runs: the next Modbus access (the
    watchdog refresh while bench time passes) fails after the time-out, long before the bench
    time asked for has passed, and the safe stop leaves the drive disabled. The session's
    Modbus time-out is generous until the load bench is stopped (a loaded machine must not
    fail the set-up), then 0.5 s."""
    desc = make_desc()  # type: ignore[operator]
    s = BenchSession(desc, tmp_path / "run")
    s.start()
    assert s.virtual is not None
    lb_pid = s.virtual.sup.children["loadbench"].pid
    try:
        _, lb = s.require()
        lb.speed_hold(0.0)
        s.drive.set_limits(4.0, 3300.0, 3000.0)
        s.drive.enable(ctrl_mode="current", fw_mode="id_zero", iq_ref=0.5)
        assert s.drive.state == "RUN"
        # the client's time-out 0.5 s and its refreshes every 0.1 s of wall time (the
        # server's own watchdog stays as the session set it: it is stopped anyway)
        lb.close()
        lb.spec = replace(lb.spec, timeout_s=0.5, watchdog_timeout_ms=400)
        lb.open()
        os.kill(lb_pid, signal.SIGSTOP)
        t0, bench_t0 = time.monotonic(), s.clock.now()
        with pytest.raises(LoadBenchError, match=r"no valid answer within 0.5 s"):
            s.clock.advance(20.0)
        assert time.monotonic() - t0 >= 0.5
        # noticed at the next refresh, not when the 20 s of bench time asked for had passed
        assert s.clock.now() - bench_t0 < 20.0
        notes = s.safe_stop()
        assert any("load bench: zeroing FAILED" in n for n in notes), notes
        assert s.drive.state == "IDLE", (notes, s.clock.period, s.clock.progress)
        assert s.console is not None and s.console.status()["enable"] == "0"
        assert notes[-1].startswith("drive state afterwards: DRIVE_STATUS IDLE"), notes
    finally:
        os.kill(lb_pid, signal.SIGCONT)
        s.close()


# -- the command line ------------------------------------------------------------------


def test_cli_serve_binds_loopback_only() -> None:
    done = subprocess.run([sys.executable, "-m", "rig", "loadbench", "serve", "--host",
                           "0.0.0.0", "--bus", "unixcan", "--channel", "never"],
                          capture_output=True, text=True, timeout=30, check=False)
    assert done.returncode == 2 and "127.0.0.1 only" in done.stderr


def test_cli_read(server: Server, tmp_path: Path) -> None:
    bench = tmp_path / "b.toml"
    bench.write_text('[console]\nport = "/dev/null"\n[modbus]\nport = 1\n')
    done = subprocess.run([sys.executable, "-m", "rig", "loadbench", "read", "--bench",
                           str(bench), "--port", str(server.port)],
                          capture_output=True, text=True, timeout=30, check=False)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["holding"]["map_version"] == register_map().version
    assert set(out["input"]) == set(register_map().input)
