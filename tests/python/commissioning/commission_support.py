"""Helpers of the commissioning tests (imported by name: conftest puts this folder on
sys.path)."""

from __future__ import annotations

import tomllib
from collections.abc import Callable

from rig import _paths
from rig.bench import description as bd

MakeDesc = Callable[..., bd.BenchDescription]


def paper_truth() -> dict[str, float]:
    """The paper profile's machine, read here from the profile file (independent of rig)."""
    return profile_truth("paper")


def profile_truth(profile: str) -> dict[str, float]:
    """A profile's machine, read here from the profile file (independent of rig)."""
    data = tomllib.loads((_paths.data_dir("profiles") / f"{profile}.toml").read_text())
    return {"rs_ohm": data["machine"]["rs_ohm"], "ld_h": data["magnetics"]["ld_h"],
            "lq_h": data["magnetics"]["lq_h"], "lambda_m_wb": data["machine"]["lambda_m_wb"],
            "pole_pairs": data["machine"]["pole_pairs"]}


def cross_saturation_per_ampere(profile: str) -> float:
    """The plant's incremental Ldq per ampere of q current, read from the profile file: the
    profile gives d psi_d / d iq at (id = 0, iq = cross_ref_a)."""
    data = tomllib.loads((_paths.data_dir("profiles") / f"{profile}.toml").read_text())
    m = data["magnetics"]
    return float(m["ldq_ref_h"]) / float(m["cross_ref_a"])
