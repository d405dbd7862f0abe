"""The emulated bench of a scenario: plant_rt and fw_host (``rig.link.bench``) or the
in-process bench (``rig.sil``) with the same configuration, and the versions a result
records."""

from __future__ import annotations

import hashlib
import platform
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

from rig import __version__, commissioned_drive, profiles, protocols
from rig.link import bench
from rig.run.errors import EnvironmentProblem
from rig.run.options import RunOptions
from rig.scenario import Scenario

# Plant configuration keys of the initial rotor state (set only when not zero).
PLANT_INITIAL = {"theta_e_deg": "initial.theta_e_deg", "speed_rpm": "initial.speed_rpm"}


def plant_sets(sc: Scenario) -> list[str]:
    """The plant's ``section.key=value`` settings over its profile (plant_rt ``--set``)."""
    sets = bench.settings(sc.overrides)
    if sc.start_theta_deg:
        sets.append(f"{PLANT_INITIAL['theta_e_deg']}={sc.start_theta_deg!r}")
    if sc.initial_speed_rpm:
        sets.append(f"{PLANT_INITIAL['speed_rpm']}={sc.initial_speed_rpm!r}")
    return sets


def firmware_sets(sc: Scenario, values: Mapping[str, Any]) -> list[str]:
    """The firmware's ``name=value`` parameters (fw_host ``--set``): the hardware from the
    profile values, then what commissioning identified on the profile's virtual bench
    (``rig.commissioned_drive``), then the scenario's own."""
    try:
        commissioned = commissioned_drive.parameters(sc.profile)
    except commissioned_drive.CommissionedError as exc:
        raise EnvironmentProblem(str(exc)) from exc  # a broken installation: exit 3
    return bench.firmware_sets(values, {**commissioned, **sc.firmware})


def bench_programs(sc: Scenario, opts: RunOptions) -> bench.BenchPrograms:
    """plant_rt and fw_host for a scenario: traces always, paired from period 0 in lockstep
    (the plant's first ADC frame is its start-up period 0, so stray frames on the channel
    cannot become the firmware's first period)."""
    values = profiles.profile_values(sc.profile, sc.overrides)
    return bench.BenchPrograms(
        profile=sc.profile, plant_sets=tuple(plant_sets(sc)),
        fw_sets=tuple(firmware_sets(sc, values)), lockstep=not opts.realtime, trace=True,
        trace_vio=opts.trace_bus,
        paired_from_start=not opts.realtime, extra_plant_args=tuple(opts.extra_plant_args),
        extra_fw_args=tuple(opts.extra_fw_args))


def sha(path: str | Path) -> str:
    """The first 16 hex digits of a file's SHA-256 (``unavailable`` when unreadable)."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return "unavailable"
    return h.hexdigest()[:16]


def commit() -> str | None:
    """The rig's checkout (``git describe --always --dirty``), when it is one."""
    import subprocess

    try:
        done = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), "describe",
                               "--always", "--dirty", "--abbrev=12"], capture_output=True,
                              text=True, timeout=5, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() or None if done.returncode == 0 else None


def versions(plant: str | None = None, fw: str | None = None) -> dict[str, str]:
    out = {"rig": __version__, "python": platform.python_version()}
    checkout = commit()
    if checkout:
        out["rig.commit"] = checkout
    for dist in ("numpy", "cantools", "python-can", "rerun-sdk"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    for db in protocols.DATABASES:
        out[f"dbc.{db}"] = str(protocols.database(db).version)
    if plant:
        out["plant_rt.sha256"] = sha(plant)
    if fw:
        out["fw_host.sha256"] = sha(fw)
    return out
