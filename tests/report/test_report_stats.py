"""The report's statistics against hand-computed values and a direct scipy call."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from d2a_core.report.stats import (_RNG_KEYWORD, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, bootstrap_ci, ci_text, iqm,
                                   mean_std)


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm([1, 2, 3, 4, 5, 6, 7, 8]) == pytest.approx(4.5)  # drops 1, 2 and 7, 8
    assert iqm([1, 2, 3, 4, 100]) == pytest.approx(3.0)  # drops one at each end: a diverging run does not count
    assert iqm([5.0]) == 5.0
    assert iqm([None, float("nan")]) is None
    assert iqm([1, None, 2, 3, float("nan"), 4, 5, 6, 7, 8]) == pytest.approx(4.5)  # None and NaN are left out


def test_mean_and_std_are_the_population_ones():
    mean, std = mean_std([1, 2, 3, 11, 12, 13, 21, 22, 23])
    assert mean == pytest.approx(12.0)
    assert std == pytest.approx(np.sqrt(606 / 9))  # squared deviations 121+100+81+1+0+1+81+100+121
    assert mean_std([]) == (None, None)


def test_bootstrap_ci_is_scipys_with_the_fixed_seed():
    per_seed = [2.0, 12.0, 22.0, 5.0]
    direct = stats.bootstrap((np.array(per_seed),), np.mean, n_resamples=BOOTSTRAP_RESAMPLES, confidence_level=0.95,
                             method="percentile",
                             **{_RNG_KEYWORD: np.random.default_rng(BOOTSTRAP_SEED)}).confidence_interval
    low, high = bootstrap_ci(per_seed)
    assert (low, high) == pytest.approx((direct.low, direct.high), abs=1e-12)
    assert bootstrap_ci(per_seed) == (low, high)  # the same values give the same interval
    assert low < np.mean(per_seed) < high
    assert min(per_seed) <= low and high <= max(per_seed)  # a percentile interval of means stays in the range


def test_bootstrap_ci_width_follows_the_spread_and_the_number_of_seeds():
    x = np.array([1.0, 4.0, 2.0, 8.0, 5.0])
    low, high = bootstrap_ci(x)
    # same resampling indices: an affine change of the values moves the interval exactly with them
    assert bootstrap_ci(3 * x + 7) == pytest.approx((3 * low + 7, 3 * high + 7))
    # the same spread seen over four times as many seeds: a narrower interval (about half as wide)
    low4, high4 = bootstrap_ci(np.tile(x, 4))
    assert 0.35 < (high4 - low4) / (high - low) < 0.65
    # no spread, no width
    assert bootstrap_ci([3.0, 3.0, 3.0]) == (3.0, 3.0)


def test_fewer_than_three_seeds_give_no_interval():
    assert bootstrap_ci([1.0, 2.0]) is None
    assert bootstrap_ci([1.0, None, float("nan"), 2.0]) is None  # two finite values
    assert ci_text(None, 2, 1) == "n/a (2 seeds)"
    assert ci_text(None, 1, 1) == "n/a (1 seed)"
    assert ci_text((1.234, 5.678), 3, 1) == "[1.2, 5.7]"
