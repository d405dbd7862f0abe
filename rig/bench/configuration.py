"""What an emulated bench is set to, built in one place for both of them (plant_rt and
fw_host as processes, ``rig.bench.virtual``; the in-process bench, ``rig.bench.sil``): the
plant's profile with its ``--set`` assignments, and the firmware's parameters.

The firmware's parameters come in three layers, later ones winning: first the hardware the
plant's profile fixes, then what the caller asks for (a scenario: the drive as commissioning
left it on the profile's virtual bench, then its own ``[firmware]``; a bench description:
its ``[virtual.firmware]``). On a real drive the hardware parameters are known to the
firmware's configuration: the ADC scaling of the current and DC-link channels
(docs/interfaces.md, "ADC codes") and the inverter's dead time (the C2000 programs it
itself) and device drop (data sheet), which the flux estimator's voltage model needs. Here
they are taken from the profile the plant runs, so firmware and plant describe the same
hardware.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rig.bench import profiles

# firmware parameter -> (profile key, factor from the profile's SI unit to the parameter's)
FIRMWARE_FROM_PROFILE: dict[str, tuple[str, float]] = {
    "adc_bits": ("adc.bits", 1.0),
    "adc_range_a": ("adc.range_a", 1.0),
    "adc_vdc_range_v": ("adc.vdc_range_v", 1.0),
    "adc_vdc_bits": ("adc.vdc_bits", 1.0),
    "deadtime_us": ("inverter.dead_time_s", 1e6),
    "vdrop_v": ("inverter.device_drop_v", 1.0),
}

# the plant's keys of the initial rotor state (set only when not zero)
PLANT_INITIAL = {"theta_e_deg": "initial.theta_e_deg", "speed_rpm": "initial.speed_rpm"}


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


def firmware_settings(values: Mapping[str, Any]) -> dict[str, float]:
    """Parameter -> value for the profile fields present in ``values`` (flat section.key)."""
    out: dict[str, float] = {}
    for param, (key, factor) in FIRMWARE_FROM_PROFILE.items():
        if key in values:
            v = values[key]
            out[param] = v if factor == 1.0 else round(float(v) * factor, 9)
    return out


@dataclass(frozen=True)
class BenchConfiguration:
    """An emulated bench's plant and firmware configuration."""

    profile: str  # a profile name or file
    profile_file: Path | None  # its file (None: not found; plant_rt says why)
    plant_sets: tuple[str, ...] = ()  # plant_rt --set section.key=value
    fw_sets: tuple[str, ...] = ()  # fw_host --set name=value


def configure(profile: str, plant: Mapping[str, Any] | None = None,
              firmware: Mapping[str, Any] | None = None,
              initial: Mapping[str, float] | None = None) -> BenchConfiguration:
    """The bench of ``profile`` with the plant's ``section.key`` overrides, the firmware's
    own parameters over the profile's hardware, and the initial rotor state (the keys of
    ``PLANT_INITIAL``; a zero is the plant's default and is not set)."""
    plant = plant or {}
    plant_sets = settings(plant) + [f"{PLANT_INITIAL[k]}={v!r}"
                                    for k, v in (initial or {}).items() if v]
    values = profiles.profile_values(profile, plant)
    fw_sets = settings(firmware_settings(values)) + settings(firmware or {})
    return BenchConfiguration(profile, profiles.profile_file(profile), tuple(plant_sets),
                              tuple(fw_sets))
