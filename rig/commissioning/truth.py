"""What the virtual bench's machine really is, for the report's comparison column."""

from __future__ import annotations

from rig.bench import profiles
from rig.bench.description import BenchDescription


def plant_truth(desc: BenchDescription) -> dict[str, float]:
    """rs, the incremental Ld and Lq at zero current, λm, pole pairs, and the
    cross-saturation as Ldq per ampere of q current (the profile gives Ldq at id = 0 and
    iq = cross_ref_a, where the plant's law is linear in iq to 5 %)."""
    v = desc.virtual
    assert v is not None
    if profiles.profile_file(v.profile) is None:
        raise FileNotFoundError(f"virtual.profile: no profile {v.profile!r}")
    values = profiles.profile_values(v.profile, v.plant)
    return {"rs_ohm": float(values["machine.rs_ohm"]), "ld_h": float(values["magnetics.ld_h"]),
            "lq_h": float(values["magnetics.lq_h"]),
            "lambda_m_wb": float(values["machine.lambda_m_wb"]),
            "pole_pairs": float(values["machine.pole_pairs"]),
            "xsat_ldq_per_a": float(values["magnetics.ldq_ref_h"])
            / float(values["magnetics.cross_ref_a"])}
