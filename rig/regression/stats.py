"""Small statistics for verdicts over noise seeds: Student's t quantile and the confidence
interval of a mean (numpy and the standard library only; the rig does not need scipy)."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass


def t_cdf(t: float, df: int) -> float:
    """P(T <= t) for Student's t with ``df`` degrees of freedom (Simpson's rule on the
    density from 0 to |t|; 1e-10 accurate for the df and t a CI needs)."""
    if df < 1:
        raise ValueError("df must be at least 1")
    c = math.exp(math.lgamma((df + 1) / 2) - math.lgamma(df / 2)) / math.sqrt(df * math.pi)
    x = abs(t)
    n = 2000
    h = x / n

    def pdf(u: float) -> float:
        return c * (1.0 + u * u / df) ** (-(df + 1) / 2)

    area = pdf(0.0) + pdf(x) + sum((4 if k % 2 else 2) * pdf(k * h) for k in range(1, n))
    half = area * h / 3.0
    return 0.5 + half if t >= 0 else 0.5 - half


@functools.lru_cache(maxsize=256)
def t_quantile(p: float, df: int) -> float:
    """The t with P(T <= t) = p (bisection on :func:`t_cdf`)."""
    if not 0.0 < p < 1.0:
        raise ValueError("p must be in (0, 1)")
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    lo, hi = 0.0, 1.0
    while t_cdf(hi, df) < p:
        hi *= 2.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if t_cdf(mid, df) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class MeanCI:
    mean: float
    sd: float
    n: int
    lo: float
    hi: float
    level: float


def mean_ci(values: Sequence[float], level: float = 0.95) -> MeanCI:
    """The mean of ``values`` and its two-sided ``level`` confidence interval (t-based)."""
    xs = [float(v) for v in values]
    n = len(xs)
    if n < 2:
        raise ValueError("a confidence interval needs at least two values")
    m = sum(xs) / n
    sd = math.sqrt(sum((x - m) ** 2 for x in xs) / (n - 1))
    half = t_quantile(0.5 + level / 2.0, n - 1) * sd / math.sqrt(n)
    return MeanCI(m, sd, n, m - half, m + half, level)
