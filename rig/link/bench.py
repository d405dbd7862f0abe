"""The virtual bench's programs as child processes (``rig.supervisor``): plant_rt, fw_host
and the Modbus load bench on one bus channel, in lockstep or real time.

What to start is a ``BenchPrograms``: from a bench description (``from_description``, the
commissioning's virtual bench) or from a scenario (``rig.run.programs``). The plant's
configuration is its profile file plus ``--set`` assignments; the firmware gets the
hardware the profile fixes (ADC scaling, dead time: ``rig.firmware_from_profile``) before
its own parameters, so firmware and plant describe the same hardware. fw_host's console can
sit on a pseudo-terminal linked at ``<folder>/console.pty`` with a parameter store
``<folder>/params.txt`` (SAVE/LOAD); the load bench server writes its actual port into its
ready file (``modbus.port = 0`` picks a free one).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig import _paths, profiles
from rig.bench_description import BenchDescription, ModbusSpec
from rig.firmware_from_profile import firmware_settings
from rig.supervisor import StopReport, Supervisor

PLANT, FIRMWARE, LOADBENCH = "plant_rt", "fw_host", "loadbench"
READY_FILES = {PLANT: "plant.ready", FIRMWARE: "fw.ready", LOADBENCH: "loadbench.ready"}


def format_value(v: Any) -> str:
    """A setting's value as the programs' ``--set`` takes it (floats exactly)."""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return format(v, ".17g")
    return str(v)


def settings(values: Mapping[str, Any]) -> list[str]:
    """``key=value`` assignments."""
    return [f"{k}={format_value(v)}" for k, v in values.items()]


def firmware_sets(plant_values: Mapping[str, Any], own: Mapping[str, Any]) -> list[str]:
    """fw_host's ``--set``: the hardware from the plant's profile values, then the run's own
    parameters."""
    return settings(firmware_settings(plant_values)) + settings(own)


@dataclass(frozen=True)
class BenchPrograms:
    """What the virtual bench runs and how."""

    profile: str  # a profile name or file (``--config``; ``--profile`` when not found)
    plant_sets: tuple[str, ...] = ()
    fw_sets: tuple[str, ...] = ()
    programs: tuple[str, ...] = (PLANT, FIRMWARE)
    lockstep: bool = True
    trace: bool = False  # plant.trace / fw.trace in the folder
    trace_vio: bool = False  # the plant's trace also holds the VIO frames (--trace-vio)
    truth_every: int | None = None  # BENCH_TRUTH every N periods (None: the plant's default)
    console: bool = False  # fw_host's console on a pty, its parameter store a file
    # fw_host pairs with the plant's period 0 (lockstep from the start: stray frames on the
    # channel cannot become the firmware's first period)
    paired_from_start: bool = False
    modbus: ModbusSpec | None = None  # the load bench server's address
    extra_plant_args: tuple[str, ...] = ()
    extra_fw_args: tuple[str, ...] = ()

    def argv(self, transport: str, channel: str, folder: Path) -> dict[str, list[str]]:
        """Each program's command line."""
        common = ["--bus", transport, "--channel", channel,
                  "--lockstep" if self.lockstep else "--realtime"]
        out: dict[str, list[str]] = {}
        if PLANT in self.programs:
            plant = [str(_paths.binary(PLANT)), *common, *self._trace(folder, "plant.trace"),
                     *(["--trace-vio"] if self.trace and self.trace_vio else []),
                     "--ready-file", str(folder / READY_FILES[PLANT])]
            config = profiles.profile_file(self.profile)
            plant += ["--config", str(config)] if config else ["--profile", self.profile]
            if self.truth_every is not None:
                plant += ["--truth-every", str(self.truth_every)]
            out[PLANT] = plant + _sets(self.plant_sets) + list(self.extra_plant_args)
        if FIRMWARE in self.programs:
            fw = [str(_paths.binary(FIRMWARE)), *common, *self._trace(folder, "fw.trace"),
                  "--ready-file", str(folder / READY_FILES[FIRMWARE])]
            if self.paired_from_start:
                fw += ["--first-period", "0"]
            if self.console:
                fw += ["--pty-link", str(folder / "console.pty"),
                       "--params", str(folder / "params.txt")]
            out[FIRMWARE] = fw + _sets(self.fw_sets) + list(self.extra_fw_args)
        if LOADBENCH in self.programs:
            m = self.modbus or ModbusSpec()
            out[LOADBENCH] = [sys.executable, "-m", "rig", "loadbench", "serve", "--bus",
                              transport, "--channel", channel, "--host", m.host, "--port",
                              str(m.port), "--watchdog-ms", str(m.watchdog_timeout_ms),
                              "--ready-file", str(folder / READY_FILES[LOADBENCH])]
        return out

    def _trace(self, folder: Path, name: str) -> list[str]:
        return ["--trace", str(folder / name)] if self.trace else []


def _sets(assignments: Sequence[str]) -> list[str]:
    return [arg for a in assignments for arg in ("--set", a)]


def from_description(desc: BenchDescription) -> BenchPrograms:
    """The virtual bench of a bench description."""
    v = desc.virtual
    if v is None:
        raise ValueError("not a virtual bench")
    values = profiles.profile_values(v.profile, v.plant)
    return BenchPrograms(
        profile=v.profile, plant_sets=tuple(settings(v.plant)),
        fw_sets=tuple(firmware_sets(values, v.firmware)), programs=tuple(v.programs),
        lockstep=desc.lockstep, trace=v.trace, truth_every=v.truth_every, console=True,
        modbus=desc.modbus)


@dataclass
class Endpoints:
    console_port: str | None
    modbus_port: int | None


class VirtualBench:
    """Starts, watches and stops the programs (logs in ``log_dir``, other files in
    ``folder``)."""

    def __init__(self, programs: BenchPrograms, folder: Path, *, log_dir: Path | None = None,
                 grace_s: float = 3.0) -> None:
        self.programs = programs
        self.dir = Path(folder)
        self.sup = Supervisor(log_dir if log_dir is not None else self.dir, grace_s=grace_s)

    def start(self, transport: str, channel: str, *, ready_timeout_s: float,
              env: Mapping[str, str] | None = None) -> Endpoints:
        """Starts every program and waits until each is ready (``ChildFailed`` otherwise)."""
        p = self.programs
        self.dir.mkdir(parents=True, exist_ok=True)
        store = self.dir / "params.txt"
        if p.console and not store.exists():
            store.write_text("# parameter store of the virtual bench (fw_host --params)\n")
        argv = p.argv(transport, channel, self.dir)
        full_env = {"HIL_BUS": transport, "HIL_CHANNEL": channel, **(env or {})}
        for name in (PLANT, FIRMWARE, LOADBENCH):
            if name in argv:
                self.sup.start(name, argv[name], ready_file=self.dir / READY_FILES[name],
                               env=full_env)
        self.sup.wait_ready(ready_timeout_s)
        console = str(self.dir / "console.pty") if p.console and FIRMWARE in argv else None
        port = None
        if LOADBENCH in argv:
            ready = self.dir / READY_FILES[LOADBENCH]
            port = int(json.loads(ready.read_text())["port"])
        return Endpoints(console, port)

    def check(self) -> None:
        """Raises ``ChildFailed`` when a program has exited."""
        self.sup.check()

    def stop(self, grace_s: float | None = None) -> dict[str, StopReport]:
        return self.sup.stop(grace_s=grace_s)

    def stop_program(self, name: str) -> None:
        self.sup.stop([name])
