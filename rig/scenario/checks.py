"""What the rest of the rig accepts of a scenario on a profile: overrides the plant's own
profile loader takes (``rig.bench.plant_schema``), firmware parameters in the ranges of
protocols/parameters.csv, stuck ADC codes the profile's converter can give."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from rig import _paths
from rig.bench import plant_schema, profiles
from rig.drive import params
from rig.scenario import faults
from rig.scenario.positions import Path_, locate
from rig.scenario.schema import Checker, finite, shown


def key_path(section: str, key: str, text: str) -> Path_:
    """Where a flattened key of a table is: a quoted dotted key, or nested tables."""
    quoted: Path_ = (section, key)
    return quoted if locate(text, quoted) is not None else (section, *key.split("."))


def check_overrides(c: Checker, profile: str, overrides: Mapping[str, Any]) -> None:
    """The plant's own loader judges the overrides on the profile (rig.bench.plant_schema)."""
    if not overrides or not plant_schema.available():
        return  # not built: plant_rt reports it at start (exit 2, named field)
    try:
        path = _paths.data_dir("profiles") / f"{profile}.toml"
    except FileNotFoundError:
        return
    for key, why in plant_schema.check(path, overrides).items():
        c.err(key_path("overrides", key, c.text) if key else ("overrides",),
              why if key else f"on profile {profile!r}: {why}")


def check_firmware(c: Checker, firmware: Mapping[str, Any]) -> None:
    """Firmware parameters by name, in the ranges of protocols/parameters.csv."""
    if not firmware:
        return
    table = params.table()
    for key, value in firmware.items():
        where = key_path("firmware", key, c.text)
        try:
            info = table.lookup(key)
        except params.ParamError:
            c.err(where, "unknown parameter (rig param list, protocols/parameters.csv)")
            continue
        number = finite(value)
        if number is None:
            c.err(where, f"must be a finite number, not {shown(value)}")
            continue
        problem = info.problem(number)
        if problem is not None:
            c.err(where, problem)


def check_stuck_codes(c: Checker, profile: str, overrides: Mapping[str, Any],
                      events: Sequence[faults.Fault]) -> None:
    """A stuck converter's code must be one the converter has, on this profile."""
    bits = faults.adc_bits_of(profiles.profile_values(profile, overrides))
    for i, f in enumerate(events):
        if f.kind == "adc_stuck" and f.channel in bits:
            top = (1 << bits[f.channel]) - 1
            if f.value > top:
                c.err(("faults", i, "code"), f"code {f.value:g} is beyond the {f.channel} "
                      f"converter of profile {profile!r} (0 .. {top})")
