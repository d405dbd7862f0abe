"""Firmware parameters that follow from the bench's hardware, taken from the plant profile.

On a real drive these are known to the firmware's configuration: the ADC scaling of the
current and DC-link channels (docs/interfaces.md, "ADC codes") and the inverter's dead time
(the C2000 programs it itself) and device drop (data sheet), which the flux estimator's
voltage model needs. The rig and the commissioning's virtual bench both set them from the
profile the plant runs, so firmware and plant describe the same hardware.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

# firmware parameter -> (profile key, factor from the profile's SI unit to the parameter's)
FIRMWARE_FROM_PROFILE: dict[str, tuple[str, float]] = {
    "adc_bits": ("adc.bits", 1.0),
    "adc_range_a": ("adc.range_a", 1.0),
    "adc_vdc_range_v": ("adc.vdc_range_v", 1.0),
    "adc_vdc_bits": ("adc.vdc_bits", 1.0),
    "deadtime_us": ("inverter.dead_time_s", 1e6),
    "vdrop_v": ("inverter.device_drop_v", 1.0),
}


def firmware_settings(values: Mapping[str, Any]) -> dict[str, float]:
    """Parameter -> value for the profile fields present in ``values`` (flat section.key)."""
    out: dict[str, float] = {}
    for param, (key, factor) in FIRMWARE_FROM_PROFILE.items():
        if key in values:
            v = values[key]
            out[param] = v if factor == 1.0 else round(float(v) * factor, 9)
    return out
