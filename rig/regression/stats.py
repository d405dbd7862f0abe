"""Small statistics for verdicts over noise seeds: Student's t distribution, the confidence
interval of a mean, and the exact rank-sum test of a shift that confirms a regression.

Written here rather than taken from scipy: scipy is a test dependency only (tens of MB and
~0.3 s of import for three functions), and each function here is held to scipy's in the
tests (tests/python/rig/test_stats.py)."""

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


def t_sf(t: float, df: int) -> float:
    """P(T > t) for Student's t with ``df`` degrees of freedom."""
    return 1.0 - t_cdf(t, df) if t >= 0 else t_cdf(-t, df)


# --------------------------------------------------------------------------------------
# The exact rank-sum test of a shift (Wilcoxon-Mann-Whitney)


def _midranks(xs: Sequence[float]) -> list[float]:
    """Ranks 1..N of ``xs`` with ties sharing the mean of their ranks."""
    order = sorted(range(len(xs)), key=lambda i: xs[i])
    ranks = [0.0] * len(xs)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and xs[order[j + 1]] == xs[order[i]]:
            j += 1
        for k in range(i, j + 1):
            ranks[order[k]] = (i + j) / 2.0 + 1.0
        i = j + 1
    return ranks


@functools.lru_cache(maxsize=4096)
def _subset_sums(doubled: tuple[int, ...], m: int) -> tuple[int, ...]:
    """How many subsets of m of the (doubled, so integer) ranks have each sum: the rank-sum
    statistic's null distribution, counted exactly (cached: without ties it depends on the
    sample sizes only)."""
    import numpy as np

    total = sum(doubled)
    exact = math.comb(len(doubled), m) < 2**62  # int64 holds every count; else Python ints
    ways = np.zeros((m + 1, total + 1), dtype=np.int64 if exact else object)
    ways[0, 0] = 1  # ways[k, s]: subsets of k of the ranks so far whose sum is s
    for r in doubled:
        ways[1:, r:] += ways[:-1, : total + 1 - r].copy()
    return tuple(int(x) for x in ways[m])


def _rank_sum_tail(ranks: Sequence[float], m: int, observed: float) -> float:
    """P(the ranks of m of ``ranks`` drawn at random sum to at least ``observed``), counted
    exactly over every split."""
    counts = _subset_sums(tuple(sorted(round(2 * r) for r in ranks)), m)
    need = math.ceil(2 * observed - 1e-9)
    return sum(counts[need:]) / math.comb(len(ranks), m)


def shift_p(base: Sequence[float], new: Sequence[float], margin: float = 0.0) -> float:
    """The exact one-sided p-value that ``new`` lies higher than ``base`` by more than
    ``margin``: the Wilcoxon-Mann-Whitney rank-sum of ``new - margin`` among all the values,
    against every equally likely split of the pooled values (valid whatever their
    distribution when both samples are draws of the same kind: no normality, ties and
    infinities allowed: +inf is the worst value)."""
    if not base or not new:
        raise ValueError("a shift test needs values on both sides")
    moved = [v - margin if math.isfinite(v) else v for v in new]
    pooled = [*base, *moved]
    ranks = _midranks(pooled)
    return _rank_sum_tail(ranks, len(new), sum(ranks[len(base):]))


def smallest_shift_p(n_base: int, n_new: int) -> float:
    """The smallest p-value :func:`shift_p` can give with these sample sizes (every new value
    beyond every base value)."""
    return 1.0 / math.comb(n_base + n_new, n_new)
