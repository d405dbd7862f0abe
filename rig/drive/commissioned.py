"""The drive as commissioning left it on the virtual bench of each plant profile.

A real drive runs with the parameters its commissioning identified on its own machine; the
virtual bench of a profile is such a machine. ``rig/commissioned/<profile>.toml`` holds what
``rig commission ... --save-params`` wrote for it (today: the cross-saturation of the harsh
machine, which the slope estimator cannot tell from a rotor angle at low speed), and every
scenario run on that profile sets these parameters on the drive after the hardware ones from
the profile (``rig.bench.configuration``) and before the scenario's own ``[firmware]``.
A profile without a file runs the drive as shipped (``protocols/parameters.csv``).
"""

from __future__ import annotations

import datetime as dt
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path

from rig.drive import params

FOLDER = Path(__file__).resolve().parents[1] / "commissioned"


class CommissionedError(ValueError):
    pass


def file_of(profile: str) -> Path | None:
    """The commissioned-drive file of a profile given by name (None for a profile file path or
    a profile without one)."""
    if not profile or "/" in profile or profile.endswith(".toml"):
        return None
    path = FOLDER / f"{profile}.toml"
    return path if path.is_file() else None


def parameters(profile: str) -> dict[str, float]:
    """The commissioned parameters of a profile's virtual bench ({} when there are none)."""
    path = file_of(profile)
    if path is None:
        return {}
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CommissionedError(f"{path}: {exc}") from exc
    table = data.get("firmware", {})
    if set(data) - {"firmware"} or not isinstance(table, dict):
        raise CommissionedError(f"{path}: only a [firmware] table of parameter = number")
    known = params.table()
    out: dict[str, float] = {}
    for name, value in table.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CommissionedError(f"{path}: firmware.{name}: not a number")
        # the scenario checks' rule (names and ranges of protocols/parameters.csv): a bad
        # value is refused here, not by fw_host halfway into a run
        try:
            problem = known.lookup(name).problem(float(value))
        except params.ParamError as exc:
            problem = str(exc)
        if problem is not None:
            raise CommissionedError(f"{path}: firmware.{name}: {problem}")
        out[name] = float(value)
    return out


HEADER = "# The drive as commissioning left it"  # the first line of a file render() wrote


def is_saved_file(path: Path) -> bool:
    """A file ``--save-params`` wrote (the only kind it replaces)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(HEADER)) == HEADER.encode()
    except OSError:
        return False


def values_to_save(identified: Mapping[str, float], written: Mapping[str, float]
                   ) -> dict[str, float]:
    """What a commissioning run leaves for the drive: every drive parameter a step identified
    (rs, Ld, Lq, λm, Ldq per ampere) and every one a step wrote to the drive, by the names
    and ranges of protocols/parameters.csv (CommissionedError for a value out of range; an
    identified quantity that is no drive parameter is not saved)."""
    known = params.table()
    out: dict[str, float] = {}
    for name, value in {**identified, **written}.items():
        try:
            info = known.lookup(name)
        except params.ParamError:
            continue
        problem = info.problem(float(value))
        if problem is not None:
            raise CommissionedError(problem)
        out[name] = float(value)
    return out


def render(values: Mapping[str, float], profile: str, command: Sequence[str],
           previous: str | None = None) -> str:
    """The file ``--save-params`` writes (with tomlkit): where the values come from, then
    the table. ``previous``: the text of the file it replaces; the comments a reviewer wrote
    in its ``[firmware]`` table (above a parameter, after its value) stay with the parameters
    that are still there."""
    import tomlkit

    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d")
    doc = tomlkit.document()
    for line in (
        f"{HEADER[2:]} on the virtual bench of the {profile} profile",
        f"({when}), written by:",
        f"  {' '.join(command)}",
        "Scenario runs on this profile set these parameters on the drive after the hardware",
        "ones from the profile and before a scenario's own [firmware]",
        "(rig/drive/commissioned.py).",
    ):
        doc.add(tomlkit.comment(line))
    table = tomlkit.table()
    if previous is not None:
        try:
            old = tomlkit.parse(previous).get("firmware")
        except tomlkit.exceptions.ParseError:
            old = None
        if isinstance(old, tomlkit.items.Table):
            table = old
            for name in [k for k in table if k not in values]:
                del table[name]
    for name, value in sorted(values.items()):
        table[name] = float(format(float(value), ".6g"))
    doc.add("firmware", table)
    return tomlkit.dumps(doc)
