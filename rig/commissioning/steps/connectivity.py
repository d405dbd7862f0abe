"""Step ``connectivity``: CAN (heartbeat, status, a parameter read), console (ping, version)
and Modbus (register map version, measurements, watchdog), and the bench clock."""

from __future__ import annotations

from rig.commissioning.results import StepResult
from rig.commissioning.session import BenchSession

TITLE = "Connectivity: CAN, console, load bench, bench clock"
HEARTBEAT_WAIT_S = 1.5  # HEARTBEAT is sent every 100 ms


def run(s: BenchSession, r: StepResult) -> None:
    link = s.link
    hb = link.wait_for("HEARTBEAT", lambda v: True, HEARTBEAT_WAIT_S, "HEARTBEAT")
    hb2 = link.wait_for("HEARTBEAT", lambda v: int(v["alive"]) != int(hb["alive"]),
                        HEARTBEAT_WAIT_S, "a second HEARTBEAT with a new alive counter")
    r.check("CAN heartbeat", True,
            f"{link.where}: node {int(hb2['node'])}, alive {int(hb['alive'])} → "
            f"{int(hb2['alive'])}, uptime {float(hb2['uptime']):.1f} s, ISR overruns "
            f"{int(hb2['isr_overruns'])}")
    link.wait_for("DRIVE_STATUS", lambda v: True, HEARTBEAT_WAIT_S, "DRIVE_STATUS")
    r.check("drive state", s.drive.state != "FAULT",
            f"{s.drive.state}" + (f", {s.drive.fault_text()}" if s.drive.state == "FAULT"
                                  else ""))
    fw_version = s.params.get("fw_version")
    r.check("CAN parameter access", True, f"PARAM_REQ read fw_version = {fw_version:g}")

    con = s.open_console()
    con.ping()
    ver = con.version()
    proto = int(ver.get("console", "-1"))
    r.check("console", proto == con.grammar.version,
            f"{con.port}: ping OK; version {' '.join(f'{k}={v}' for k, v in ver.items())} "
            f"(the rig speaks console protocol {con.grammar.version})")

    lb = s.open_load()
    m = lb.measure()
    lb.refresh_watchdog(force=True)
    echo = int(lb.read("input", "watchdog_echo"))
    r.check("load bench", echo == int(lb.read("holding", "watchdog")),
            f"{lb.endpoint}: map version {lb.map.version}, speed {m.speed_rpm:.1f} r/min, "
            f"shaft torque {m.shaft_torque:.3f} N·m, faults "
            f"{[k for k, v in m.faults.items() if v] or 'none'}, watchdog echo {echo}")

    t0 = s.clock.now()
    s.clock.advance(0.01)
    r.check("bench clock", s.clock.now() > t0,
            f"{s.clock.mode}: advanced {1e3 * (s.clock.now() - t0):.1f} ms of bench time")
