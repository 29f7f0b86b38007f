"""The report's statistics: mean +- std as the paper reports it, the interquartile mean, and a
bootstrap confidence interval over training seeds (which the paper does not give).

- `mean_std`: mean and population std (ddof 0, as `d2a eval` reports over humans).
- `iqm`: the interquartile mean, `scipy.stats.trim_mean(x, 0.25)` (the mean of the middle 50 %,
  robust to one diverging run; Agarwal et al., NeurIPS 2021, "Deep RL at the edge of the
  statistical precipice").
- `bootstrap_ci`: the 95 % percentile bootstrap interval of the mean over *training seeds*
  (`scipy.stats.bootstrap`, `BOOTSTRAP_RESAMPLES` resamples, a fixed seed, so the same values give
  the same interval). A seed is the independent unit: humans within one seed share its assistant.
  Below `MIN_SEEDS` seeds no interval is given: `ci_text` then says "n/a (k seeds)".
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence

import numpy as np
from scipy import stats

MIN_SEEDS = 3
CONFIDENCE = 0.95
BOOTSTRAP_RESAMPLES = 9999
BOOTSTRAP_SEED = 20240917
BOOTSTRAP_METHOD = "percentile"
"""Percentile, not BCa: with 3-5 seeds BCa's acceleration estimate is unstable and it fails on
constant data, while the percentile interval is defined for any sample."""

# scipy >= 1.15 names the generator `rng`; older releases call it `random_state`
_RNG_KEYWORD = "rng" if "rng" in inspect.signature(stats.bootstrap).parameters else "random_state"


def finite(values: Sequence[float | None]) -> np.ndarray:
    """The finite values of a sequence (None and NaN dropped) as float64."""
    array = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
    return array[np.isfinite(array)]


def mean_std(values: Sequence[float | None]) -> tuple[float | None, float | None]:
    """Mean and std (ddof 0) of the finite values; (None, None) when there are none."""
    x = finite(values)
    if not len(x):
        return None, None
    return float(np.mean(x)), float(np.std(x))


def iqm(values: Sequence[float | None]) -> float | None:
    """Interquartile mean: `scipy.stats.trim_mean(x, 0.25)` of the finite values."""
    x = finite(values)
    return float(stats.trim_mean(x, 0.25)) if len(x) else None


def bootstrap_ci(per_seed: Sequence[float | None], seed: int = BOOTSTRAP_SEED,
                 confidence: float = CONFIDENCE, resamples: int = BOOTSTRAP_RESAMPLES) -> tuple[float, float] | None:
    """The bootstrap confidence interval of the mean of one value per training seed, or None
    with fewer than `MIN_SEEDS` finite values."""
    x = finite(per_seed)
    if len(x) < MIN_SEEDS:
        return None
    result = stats.bootstrap((x,), np.mean, n_resamples=resamples, confidence_level=confidence,
                             method=BOOTSTRAP_METHOD, **{_RNG_KEYWORD: np.random.default_rng(seed)})
    low, high = result.confidence_interval
    return float(low), float(high)


def ci_text(ci: tuple[float, float] | None, seeds: int, decimals: int) -> str:
    """'[low, high]', or 'n/a (k seeds)' when the interval was not computed."""
    if ci is None:
        return f"n/a ({seeds} seed{'s' if seeds != 1 else ''})"
    return f"[{ci[0]:.{decimals}f}, {ci[1]:.{decimals}f}]"
