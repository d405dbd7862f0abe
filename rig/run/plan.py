"""A scenario as commands per PWM period and the lockstep grants that deliver them.

Grants last at most ``grant_max_s`` (100 ms) of simulated time and end exactly at every
profile breakpoint, so commands take effect on an exact period. Speed ramps are the
firmware's own ramp: at a segment start the rig sets ``speed_ref`` to the segment's target
and the acceleration limit to the segment's slope (a step uses the DBC maximum of
``accel_max``); the expected reference (``speed_ref_rpm`` in the capture) is the same rate
limiter evaluated here. Torque ramps of the load are 1 ms steps. Faults on the plant start
(and end) with a FAULT_CMD before the grant of their first period; faults on the rig's own
frames act in ``rig.link.frame_faults``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from rig.data import capture
from rig.link import frame_faults
from rig.link.bench_commands import LoadSetting
from rig.link.drive_master import DriveCommand, DriveLimits, accel_max, accel_on_wire
from rig.scenario import Scenario, faults

TS = capture.TS


@dataclass(frozen=True)
class DriveChange:
    """What the scenario changes in the drive's command and limits at a period."""

    enable: int | None = None
    speed_ref: float | None = None
    accel: float | None = None

    def apply(self, cmd: DriveCommand, limits: DriveLimits) -> tuple[DriveCommand, DriveLimits]:
        if self.enable is not None:
            cmd = replace(cmd, enable=self.enable)
        if self.speed_ref is not None:
            cmd = replace(cmd, speed_ref=self.speed_ref)
        if self.accel is not None:
            limits = replace(limits, accel=self.accel)
        return cmd, limits


def initial_drive(sc: Scenario) -> tuple[DriveCommand, DriveLimits]:
    """The drive command and limits before the scenario's first event."""
    return (DriveCommand(ctrl_mode=sc.ctrl_mode, fw_mode=sc.fw_mode, iq_ref=sc.iq_ref),
            DriveLimits(i_max=sc.i_max, speed_max=sc.speed_max,
                        accel=accel_on_wire(accel_max())))


@dataclass
class Plan:
    """Commands per period and the grant boundaries of a scenario."""

    n_periods: int
    drive_events: dict[int, list[DriveChange]]
    load_events: dict[int, LoadSetting]
    boundaries: list[int]
    grant_max: int
    # FAULT_CMD signals to send before the grant that starts on a period (plant-side faults)
    fault_cmds: dict[int, list[dict[str, float | int]]] = field(default_factory=dict)
    # the faults on the rig's own frames (rig.link.frame_faults)
    link_windows: list[frame_faults.Window] = field(default_factory=list)
    # the drive's command and limits before the scenario's first event
    initial_cmd: DriveCommand = field(default_factory=DriveCommand)
    initial_limits: DriveLimits = field(default_factory=DriveLimits)

    @classmethod
    def build(cls, sc: Scenario) -> Plan:
        n = round(sc.duration / TS)
        cmd0, limits0 = initial_drive(sc)
        step = accel_max()
        drive: dict[int, list[DriveChange]] = {}

        def at(t: float) -> int:
            return min(max(round(t / TS), 0), n)

        def on(t: float, change: DriveChange) -> None:
            drive.setdefault(at(t), []).append(change)

        on(sc.enable_at, DriveChange(enable=1))
        for cmd in sc.speed_commands(step):
            acc = accel_on_wire(min(cmd.accel, step))
            if acc <= 0:
                acc = accel_on_wire(step)
            on(cmd.t, DriveChange(speed_ref=cmd.target, accel=acc))
        loads: dict[int, LoadSetting] = {}
        for lc in sc.load_commands():
            loads[at(lc.t)] = LoadSetting(lc.mode, lc.torque, lc.speed, lc.k_speed)
        fault_cmds: dict[int, list[dict[str, float | int]]] = {}
        slot = 0
        for f in sc.faults:
            if not f.on_plant:
                continue
            start, end = f.periods(n)
            fault_cmds.setdefault(start, []).append(f.fault_cmd(slot))
            if end < n:
                fault_cmds.setdefault(end, []).append(faults.Fault.clear_cmd(slot))
            slot += 1
        link_windows = frame_faults.windows(sc.faults, n)
        bps = {at(t) for t in sc.breakpoints(step)} | set(drive) | set(loads) | set(fault_cmds)
        for w in link_windows:
            bps |= {w.start, w.end}
        plan = cls(n, drive, loads, [], max(1, round(sc.grant_max_s / TS)), fault_cmds,
                   link_windows, cmd0, limits0)
        while True:
            # a frame the rig holds back arrives exactly before its due period: make every
            # due period a grant start (due periods of those starts too, up to a fixed point)
            plan.boundaries = [*sorted(p for p in bps if 0 < p < n), n]
            due = frame_faults.due_periods(link_windows, (g[0] for g in plan.grants()), n)
            if due <= bps:
                return plan
            bps |= due

    def grants(self) -> list[tuple[int, int]]:
        """(start, run_until) pairs covering [0, n)."""
        out: list[tuple[int, int]] = []
        p = 0
        for b in self.boundaries:
            while p < b:
                q = min(b, p + self.grant_max)
                out.append((p, q))
                p = q
        return out
