"""The virtual bench's programs as child processes (``rig.supervisor``): plant_rt, fw_host
and the Modbus load bench on one bus channel, in lockstep or real time.

What to start is a ``BenchPrograms``: the bench's configuration (``rig.bench.configuration``:
the plant's profile file plus ``--set`` assignments, the firmware's parameters over the
hardware the profile fixes) from a bench description (``from_description``, the
commissioning's virtual bench) or from a scenario (``rig.run.on_bus``), and how the
programs run. fw_host's console can
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

from rig import _paths
from rig.bench.configuration import BenchConfiguration, configure
from rig.bench.description import BenchDescription, ModbusSpec
from rig.supervisor import StopReport, Supervisor

PLANT, FIRMWARE, LOADBENCH = "plant_rt", "fw_host", "loadbench"
READY_FILES = {PLANT: "plant.ready", FIRMWARE: "fw.ready", LOADBENCH: "loadbench.ready"}


@dataclass(frozen=True)
class BenchPrograms:
    """What the virtual bench runs and how."""

    config: BenchConfiguration  # the plant's profile and settings, the firmware's parameters
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
            c = self.config
            plant += (["--config", str(c.profile_file)] if c.profile_file
                      else ["--profile", c.profile])
            if self.truth_every is not None:
                plant += ["--truth-every", str(self.truth_every)]
            out[PLANT] = plant + _sets(self.config.plant_sets) + list(self.extra_plant_args)
        if FIRMWARE in self.programs:
            fw = [str(_paths.binary(FIRMWARE)), *common, *self._trace(folder, "fw.trace"),
                  "--ready-file", str(folder / READY_FILES[FIRMWARE])]
            if self.paired_from_start:
                fw += ["--first-period", "0"]
            if self.console:
                fw += ["--pty-link", str(folder / "console.pty"),
                       "--params", str(folder / "params.txt")]
            out[FIRMWARE] = fw + _sets(self.config.fw_sets) + list(self.extra_fw_args)
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
    return BenchPrograms(
        configure(v.profile, v.plant, v.firmware), programs=tuple(v.programs),
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
