"""The virtual bench of a bench description: plant_rt, fw_host and the Modbus load bench as
child processes (rig.supervisor), in lockstep or real time.

fw_host gets its console on a pseudo-terminal linked at ``<run>/console.pty`` and a parameter
store ``<run>/params.txt`` (SAVE/LOAD); the ADC scaling of the profile is handed to it as
parameters (as rig.runner does). The load bench server writes its actual port into its ready
file (``modbus.port = 0`` picks a free one).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig import _paths, profiles
from rig.bench_description import BenchDescription
from rig.firmware_from_profile import firmware_settings
from rig.supervisor import Supervisor


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return format(v, ".17g")
    return str(v)


def plant_values(desc: BenchDescription) -> dict[str, Any]:
    """The plant's flat ``section.key`` configuration: profile file plus overrides."""
    assert desc.virtual is not None
    if profiles.profile_file(desc.virtual.profile) is None:
        raise FileNotFoundError(f"virtual.profile: no profile {desc.virtual.profile!r}")
    return profiles.profile_values(desc.virtual.profile, desc.virtual.plant)


def plant_truth(desc: BenchDescription) -> dict[str, float]:
    """What the emulated machine really is (for the report's comparison column): rs, the
    incremental Ld and Lq at zero current, λm, pole pairs, and the cross-saturation as Ldq per
    ampere of q current (the profile gives Ldq at id = 0 and iq = cross_ref_a, where the
    plant's law is linear in iq to 5 %)."""
    v = plant_values(desc)
    return {"rs_ohm": float(v["machine.rs_ohm"]), "ld_h": float(v["magnetics.ld_h"]),
            "lq_h": float(v["magnetics.lq_h"]), "lambda_m_wb": float(v["machine.lambda_m_wb"]),
            "pole_pairs": float(v["machine.pole_pairs"]),
            "xsat_ldq_per_a": float(v["magnetics.ldq_ref_h"]) / float(v["magnetics.cross_ref_a"])}


@dataclass
class Endpoints:
    console_port: str | None
    modbus_port: int | None


class VirtualBench:
    def __init__(self, desc: BenchDescription, run_dir: Path) -> None:
        if desc.virtual is None:
            raise ValueError("not a virtual bench")
        self.desc = desc
        self.dir = run_dir
        self.sup = Supervisor(run_dir / "logs", grace_s=3.0)
        self.transport = ""
        self.channel = ""

    def argv(self, transport: str, channel: str) -> dict[str, list[str]]:
        d, v = self.desc, self.desc.virtual
        assert v is not None
        pacing = "--lockstep" if d.lockstep else "--realtime"
        common = ["--bus", transport, "--channel", channel, pacing]
        out: dict[str, list[str]] = {}
        plant = [str(_paths.binary("plant_rt")), *common, "--config",
                 str(profiles.profile_file(v.profile)),
                 "--ready-file", str(self.dir / "plant.ready"),
                 "--truth-every", str(v.truth_every)]
        for k, val in v.plant.items():
            plant += ["--set", f"{k}={_fmt(val)}"]
        if v.trace:
            plant += ["--trace", str(self.dir / "plant.trace")]
        out["plant_rt"] = plant
        values = plant_values(d)
        fw = [str(_paths.binary("fw_host")), *common, "--ready-file", str(self.dir / "fw.ready"),
              "--pty-link", str(self.dir / "console.pty"), "--params",
              str(self.dir / "params.txt")]
        for param, value in firmware_settings(values).items():
            fw += ["--set", f"{param}={_fmt(value)}"]
        for k, val in v.firmware.items():
            fw += ["--set", f"{k}={_fmt(val)}"]
        if v.trace:
            fw += ["--trace", str(self.dir / "fw.trace")]
        out["fw_host"] = fw
        m = d.modbus
        out["loadbench"] = [sys.executable, "-m", "rig", "loadbench", "serve", "--bus",
                            transport, "--channel", channel, "--host", m.host, "--port",
                            str(m.port), "--watchdog-ms", str(m.watchdog_timeout_ms),
                            "--ready-file", str(self.dir / "loadbench.ready")]
        return out

    def start(self, transport: str, channel: str) -> Endpoints:
        v = self.desc.virtual
        assert v is not None
        self.transport, self.channel = transport, channel
        self.dir.mkdir(parents=True, exist_ok=True)
        store = self.dir / "params.txt"
        if not store.exists():
            store.write_text("# parameter store of the virtual bench (fw_host --params)\n")
        env = {"HIL_BUS": transport, "HIL_CHANNEL": channel}
        ready = {"plant_rt": "plant.ready", "fw_host": "fw.ready",
                 "loadbench": "loadbench.ready"}
        argv = self.argv(transport, channel)
        for name in ("plant_rt", "fw_host", "loadbench"):
            if name in v.programs:
                self.sup.start(name, argv[name], ready_file=self.dir / ready[name], env=env)
        self.sup.wait_ready(v.ready_timeout_s)
        console = str(self.dir / "console.pty") if "fw_host" in v.programs else None
        port = None
        if "loadbench" in v.programs:
            port = int(json.loads((self.dir / "loadbench.ready").read_text())["port"])
        return Endpoints(console, port)

    def check(self) -> None:
        self.sup.check()

    def stop(self) -> dict[str, Any]:
        return {name: {"exit": rep.returncode, "clean": rep.clean}
                for name, rep in self.sup.stop().items()}

    def stop_program(self, name: str) -> None:
        self.sup.stop([name])
