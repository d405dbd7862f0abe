"""The swept parameters and the points of a sweep.

An axis is ``NAME=SPEC`` on the command line:

- ``NAME`` is a plant profile key ``section.key`` (``machine.rs_ohm``), a firmware parameter
  ``firmware.NAME`` (``protocols/parameters.csv``), one of the short names in ``ALIASES``,
  or ``speed_scale`` / ``load_scale`` (the scenario's speed targets / load torques times the
  value);
- ``SPEC`` is ``LO:HI:N`` (N evenly spaced values, both ends included), ``LO:HI`` (a range:
  random sampling only) or ``V1,V2,...`` (the values given).

``grid`` is the product of every axis's values; ``random(n, seed)`` draws n points, each
axis independently (uniform over a range, uniform over the listed values).
"""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from rig.scenario import SEED_KEY, Scenario

ALIASES: dict[str, str] = {
    "rs": "machine.rs_ohm",
    "ld": "magnetics.ld_h",
    "lq": "magnetics.lq_h",
    "lambda_m": "machine.lambda_m_wb",
    "noise": "sensors.noise_rms_a",
    "dead_time": "inverter.dead_time_s",
    "device_drop": "inverter.device_drop_v",
    "vdc": "inverter.vdc_v",
}
SCALES = ("speed_scale", "load_scale")
# A sweep's points are built in memory and each is a run (about a second in process): more
# than this is refused before anything is built (a 9 M-point grid took 57 s to fail).
MAX_POINTS = 100_000


# the profile's keys end in their SI unit (rs_ohm, ld_h, lambda_m_wb, noise_rms_a, ...)
KEY_UNITS = {"ohm": "Ω", "h": "H", "wb": "Wb", "a": "A", "s": "s", "v": "V", "hz": "Hz",
             "rpm": "r/min", "nm": "N·m", "kgm2": "kg·m²", "per_a2": "1/A²"}


def unit_of(name: str) -> str:
    """The unit of a swept parameter (axis name or key): the profile key's suffix, the
    firmware parameter's unit (protocols/parameters.csv), 'factor' for a scale."""
    key = ALIASES.get(name, name)
    if key in SCALES:
        return "factor"
    if key.startswith("firmware."):
        from rig.drive import params

        try:
            return params.table().lookup(key.removeprefix("firmware.")).unit
        except params.ParamError:
            return ""
    leaf = key.rsplit(".", 1)[-1]
    for suffix, unit in sorted(KEY_UNITS.items(), key=lambda kv: -len(kv[0])):
        if leaf.endswith("_" + suffix):
            return unit
    return ""


class SpecError(ValueError):
    """A sweep axis that cannot be read (the message names it)."""


@dataclass(frozen=True)
class Axis:
    name: str  # as given
    key: str  # plant key, firmware.NAME or a scale
    values: tuple[float, ...] = ()  # grid values (or the listed values)
    low: float | None = None  # a range (random sampling only)
    high: float | None = None

    @property
    def is_range(self) -> bool:
        return not self.values

    def grid(self) -> tuple[float, ...]:
        if self.is_range:
            raise SpecError(f"{self.name}: a range LO:HI has no grid; give LO:HI:N or values")
        return self.values

    def draw(self, rng: random.Random) -> float:
        if self.is_range:
            assert self.low is not None and self.high is not None
            return rng.uniform(self.low, self.high)
        return rng.choice(self.values)


def _number(text: str, axis: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SpecError(f"{axis}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise SpecError(f"{axis}: {text!r} is not a finite number")
    return value


def parse_axis(text: str) -> Axis:
    name, sep, spec = text.partition("=")
    name, spec = name.strip(), spec.strip()
    if not sep or not name or not spec:
        raise SpecError(f"{text!r}: expected NAME=LO:HI:N, NAME=LO:HI or NAME=V1,V2,...")
    key = ALIASES.get(name, name)
    if key not in SCALES and "." not in key:
        raise SpecError(f"{name}: not a profile key (section.key), firmware.NAME, "
                        f"{', '.join(SCALES)} or one of {', '.join(sorted(ALIASES))}")
    if ":" in spec:
        parts = spec.split(":")
        if len(parts) not in (2, 3):
            raise SpecError(f"{name}: {spec!r} is neither LO:HI nor LO:HI:N")
        lo, hi = _number(parts[0], name), _number(parts[1], name)
        if len(parts) == 2:
            return Axis(name, key, low=min(lo, hi), high=max(lo, hi))
        try:
            n = int(parts[2])
        except ValueError:
            raise SpecError(f"{name}: N in {spec!r} is not an integer") from None
        if not 1 <= n <= MAX_POINTS:
            raise SpecError(f"{name}: N must be in 1 .. {MAX_POINTS}, not {n}")
        values = (lo,) if n == 1 else tuple(lo + (hi - lo) * k / (n - 1) for k in range(n))
        return Axis(name, key, values=values)
    return Axis(name, key, values=tuple(_number(v, name) for v in spec.split(",")))


def count(axes: Sequence[Axis], random_n: int = 0) -> int:
    """How many points the grid (or ``random_n`` random draws) has; SpecError above
    ``MAX_POINTS``, found before any point is built."""
    n = random_n if random_n > 0 else math.prod(len(a.grid()) for a in axes)
    if n > MAX_POINTS:
        what = f"--random {random_n}" if random_n > 0 else "the grid (" + " x ".join(
            f"{len(a.values)} {a.name}" for a in axes) + ")"
        raise SpecError(f"{what} has {n:,} points, more than the {MAX_POINTS:,} a sweep takes "
                        "(each is a run): sweep fewer values, or --random N")
    return n


def grid(axes: Sequence[Axis]) -> list[dict[str, float]]:
    count(axes)
    names = [a.name for a in axes]
    return [dict(zip(names, combo, strict=True))
            for combo in itertools.product(*(a.grid() for a in axes))]


def sample(axes: Sequence[Axis], n: int, seed: int) -> list[dict[str, float]]:
    count(axes, n)
    rng = random.Random(seed)
    return [{a.name: a.draw(rng) for a in axes} for _ in range(n)]


def check_axes(sc: Scenario, axes: Sequence[Axis]) -> None:
    """Refuses an axis the scenario would ignore: the noise seed of a scenario decided over
    its own seeds (``[run] seeds``), which each of its runs sets itself."""
    if sc.seeds and any(a.key == SEED_KEY for a in axes):
        raise SpecError(
            f"{SEED_KEY}: {sc.name} is decided over its own seeds "
            f"({', '.join(str(s) for s in sc.seeds)}: [run] seeds in its file), which set "
            "the noise seed of each of its runs, so this axis would change nothing; drop it "
            "(every point runs those seeds, and its summary metric is the worst seed's)")


def apply(sc: Scenario, axes: Sequence[Axis], values: Mapping[str, float],
          label: str) -> Scenario:
    """The scenario with one point's values: plant overrides, firmware parameters, scales."""
    check_axes(sc, axes)
    overrides: dict[str, Any] = dict(sc.overrides)
    firmware: dict[str, Any] = dict(sc.firmware)
    speed, load = sc.speed, sc.load
    for a in axes:
        v = values[a.name]
        if a.key == "speed_scale":
            speed = tuple(replace(seg, to=None if seg.to is None else seg.to * v,
                                  peak=None if seg.peak is None else seg.peak * v)
                          for seg in speed)
            load = tuple(replace(ev, speed=ev.speed * v) for ev in load)
        elif a.key == "load_scale":
            load = tuple(replace(ev, torque=ev.torque * v) for ev in load)
        elif a.key.startswith("firmware."):
            firmware[a.key.removeprefix("firmware.")] = v
        else:
            overrides[a.key] = v
    return replace(sc, name=f"{sc.name}[{label}]", overrides=overrides, firmware=firmware,
                   speed=speed, load=load)

