"""Shape-preserving C1 interpolation of (s, value) knots (PCHIP, Fritsch-Carlson slopes).

Used for the elevation profile and for varying road widths: it never overshoots the knots (no
invented dips between a crest and a flat) and its first derivative, the road grade, is continuous.
Written in numpy so the package needs no scipy. Beyond the first and last knot the value is held
constant (and the derivative is zero there).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _end_slope(h0: float, h1: float, d0: float, d1: float) -> float:
    """One-sided three-point slope at an end knot, limited so the end stays shape preserving."""
    slope = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1)
    if np.sign(slope) != np.sign(d0):
        return 0.0
    if np.sign(d0) != np.sign(d1) and abs(slope) > abs(3.0 * d0):
        return 3.0 * d0
    return float(slope)


def _pchip_slopes(knots_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    h = np.diff(knots_s)
    delta = np.diff(values) / h
    n = len(knots_s)
    slopes = np.zeros(n)
    if n == 2:
        slopes[:] = delta[0]
        return slopes
    # Interior: weighted harmonic mean of the neighbouring secants, zero at local extrema.
    w1 = 2.0 * h[1:] + h[:-1]
    w2 = h[1:] + 2.0 * h[:-1]
    same_sign = delta[:-1] * delta[1:] > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        harmonic = (w1 + w2) / (w1 / delta[:-1] + w2 / delta[1:])
    slopes[1:-1] = np.where(same_sign, harmonic, 0.0)
    slopes[0] = _end_slope(h[0], h[1], delta[0], delta[1])
    slopes[-1] = _end_slope(h[-1], h[-2], delta[-1], delta[-2])
    return slopes


class KnotProfile:
    """A function of s given by knots: PCHIP between knots, held constant outside them.

    Args:
        knots: sequence of (s, value) with strictly increasing s; one knot means a constant.
    """

    def __init__(self, knots: Sequence[tuple[float, float]]) -> None:
        array = np.asarray(knots, dtype=float).reshape(-1, 2)
        if len(array) == 0:
            raise ValueError("a knot profile needs at least one knot")
        if np.any(np.diff(array[:, 0]) <= 0):
            raise ValueError("knot positions must be strictly increasing")
        self._s = array[:, 0]
        self._v = array[:, 1]
        self._m = _pchip_slopes(self._s, self._v) if len(array) > 1 else np.zeros(1)

    @classmethod
    def constant(cls, value: float) -> KnotProfile:
        """A profile that is `value` everywhere."""
        return cls([(0.0, value)])

    def _locate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        clamped = np.clip(s, self._s[0], self._s[-1])
        k = np.clip(np.searchsorted(self._s, clamped, side="right") - 1, 0, len(self._s) - 2)
        h = self._s[k + 1] - self._s[k]
        t = (clamped - self._s[k]) / h
        return k, h, t, clamped

    def value(self, s: np.ndarray | float) -> np.ndarray:
        """Profile value at s (array or scalar; returns an array of the same shape)."""
        s = np.asarray(s, dtype=float)
        if len(self._s) == 1:
            return np.full(s.shape, self._v[0])
        k, h, t, _ = self._locate(s)
        t2, t3 = t * t, t * t * t
        # Cubic Hermite basis on [s_k, s_k+1].
        return (
            (2 * t3 - 3 * t2 + 1) * self._v[k]
            + (t3 - 2 * t2 + t) * h * self._m[k]
            + (-2 * t3 + 3 * t2) * self._v[k + 1]
            + (t3 - t2) * h * self._m[k + 1]
        )

    def derivative(self, s: np.ndarray | float) -> np.ndarray:
        """d(value)/ds at s; zero outside the knot range."""
        s = np.asarray(s, dtype=float)
        if len(self._s) == 1:
            return np.zeros(s.shape)
        k, h, t, clamped = self._locate(s)
        t2 = t * t
        slope = (
            (6 * t2 - 6 * t) / h * self._v[k]
            + (3 * t2 - 4 * t + 1) * self._m[k]
            + (-6 * t2 + 6 * t) / h * self._v[k + 1]
            + (3 * t2 - 2 * t) * self._m[k + 1]
        )
        outside = (s < self._s[0]) | (s > self._s[-1])
        return np.where(outside, 0.0, slope)
