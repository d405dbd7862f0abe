"""The statistics the gate's verdicts rest on (rig.regression.stats): Student's t against
printed tables and scipy, and the exact rank-sum test of a shift against a brute-force
count over every split and against scipy's Mann-Whitney test."""

from __future__ import annotations

import itertools
import math
import random

import pytest

from rig.regression import stats

# t(p, df) from a printed table (e.g. any statistics textbook's appendix), 3 decimals
TABLE = [(0.975, 1, 12.706), (0.975, 7, 2.365), (0.995, 7, 3.499), (0.995, 4, 4.604),
         (0.999, 14, 3.787), (0.9995, 14, 4.140), (0.95, 30, 1.697), (0.99, 10, 2.764)]


@pytest.mark.parametrize(("p", "df", "t"), TABLE)
def test_t_quantile_against_a_printed_table(p: float, df: int, t: float) -> None:
    assert stats.t_quantile(p, df) == pytest.approx(t, abs=6e-4)
    assert stats.t_sf(t, df) == pytest.approx(1 - p, rel=2e-3)


@pytest.mark.parametrize("df", [1, 3, 7, 20])
def test_t_sf_against_scipy(df: int) -> None:
    from scipy.stats import t

    for x in (-3.0, -0.5, 0.0, 0.7, 2.0, 5.0, 9.0):
        assert stats.t_sf(x, df) == pytest.approx(float(t.sf(x, df)), rel=1e-7, abs=1e-12)


def _brute(base: list[float], new: list[float], margin: float) -> float:
    moved = [v - margin if math.isfinite(v) else v for v in new]
    pooled = base + moved
    ranks = stats._midranks(pooled)
    obs = sum(ranks[len(base):])
    splits = list(itertools.combinations(range(len(pooled)), len(new)))
    return sum(1 for c in splits if sum(ranks[i] for i in c) >= obs - 1e-9) / len(splits)


@pytest.mark.parametrize("seed", range(40))
def test_shift_p_counts_every_split(seed: int) -> None:
    """Property: the p-value is the share of equally likely splits of the pooled values
    whose new part ranks at least as high, ties sharing their ranks and no number (+inf)
    ranking worst, with the margin taken off the new values first."""
    rng = random.Random(seed)
    n, m = rng.randint(2, 8), rng.randint(1, 8)
    pick = [lambda: rng.gauss(0, 1), lambda: 1.0, lambda: 2.0]
    base = [rng.choice(pick)() for _ in range(n)]
    new = [rng.choice([*pick, lambda: math.inf])() for _ in range(m)]
    margin = rng.choice([0.0, 0.3])
    assert stats.shift_p(base, new, margin) == pytest.approx(_brute(base, new, margin),
                                                             abs=1e-12)


def test_shift_p_equals_scipy_mann_whitney_without_ties() -> None:
    from scipy.stats import mannwhitneyu

    rng = random.Random(7)
    for _ in range(50):
        base = [rng.gauss(0, 1) for _ in range(8)]
        new = [rng.gauss(0.8, 1) for _ in range(8)]
        want = float(mannwhitneyu(new, base, alternative="greater", method="exact").pvalue)
        assert stats.shift_p(base, new) == pytest.approx(want, rel=1e-9)


def test_shift_p_extremes() -> None:
    lo = list(range(8))
    assert stats.shift_p(lo, [x + 100.0 for x in lo]) == pytest.approx(1 / 12870)
    assert stats.smallest_shift_p(8, 8) == pytest.approx(1 / 12870)
    assert stats.shift_p([x + 100.0 for x in lo], lo) == pytest.approx(1.0)
    # a shift inside the margin is no shift: all equal after taking it off
    assert stats.shift_p([1.0] * 8, [1.005] * 8, margin=0.01) > 0.5
    with pytest.raises(ValueError):
        stats.shift_p([], [1.0])
