"""The plant's fidelity profiles (``plant_rt/profiles/*.toml``) as the rig reads them: the
file of a profile and its flat ``section.key`` values with a run's overrides.

Scenario runs, the scenario checks and the commissioning's virtual bench all take the
plant's configuration from here, so the firmware's hardware parameters
(``rig.bench.configuration``) and the capture's pole pairs come from the file the plant
itself loads.
"""

from __future__ import annotations

import copy
import functools
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rig import _paths
from rig.data import capture


def profile_file(profile: str) -> Path | None:
    """The file of a profile given by name (``paper``) or as a ``.toml`` path; None when
    there is no such file."""
    given = Path(profile)
    if given.suffix == ".toml" and given.is_file():
        return given
    try:
        path = _paths.data_dir("profiles") / f"{profile}.toml"
    except FileNotFoundError:
        return None
    return path if path.is_file() else None


def flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested TOML tables as one level of dotted keys."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def profile_values(profile: str, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The flat ``section.key`` values of a profile with the overrides on top (only the
    overrides when the profile file is not there or not TOML: the plant reports that)."""
    path = profile_file(profile)
    try:
        flat = _flat(path.read_text()) if path is not None else {}
    except (OSError, tomllib.TOMLDecodeError):
        flat = {}
    return {**copy.deepcopy(flat), **(overrides or {})}


@functools.lru_cache(maxsize=16)
def _flat(text: str) -> dict[str, Any]:
    """A profile file's text parsed and flattened, once per text (every run reads its
    profile twice; a worker runs many: ~10 ms of CPU each)."""
    return flatten(tomllib.loads(text))


def pole_pairs(values: Mapping[str, Any]) -> int:
    """The machine's pole pairs in a profile's values (the capture's default without)."""
    for key in ("machine.pole_pairs", "motor.pole_pairs", "pole_pairs"):
        if key in values:
            return int(values[key])
    for key in ("machine.poles", "motor.poles", "poles"):
        if key in values:
            return int(values[key]) // 2
    return capture.DEFAULT_POLE_PAIRS
