"""Frenet (s, e) coordinates on a uniformly sampled open centreline.

Model: between samples i and i+1 the centreline is the straight chord, and the normal turns
linearly from sample i's normal to sample i+1's, so the normal field is continuous and the normal
lines sweep the road without gaps or overlaps (as long as |e| stays below the radius of
curvature). A point p on the normal line at chord parameter t satisfies
    p = a + t d + lambda (n_a + t dn),    d = b - a, dn = n_b - n_a,
and eliminating lambda gives the quadratic  (d x dn) t^2 + (d x n_a - w x dn) t - w x n_a = 0
with w = p - a (x: the 2-D cross product). Its small root is the exact projection; e is the
distance along the (normalised) normal. `from_frenet` evaluates the same model, so the two are
exact inverses. Before the first and after the last sample the centreline continues straight
along the end headings.

The scalar path (`project`) walks from an index hint: project onto the hinted interval, and if t
falls outside [0, 1] jump by floor(t) intervals and project again. It uses Python lists and the
math module because numpy's per-call overhead would dominate single-point work. A hinted answer
far from the centreline (a stale hint) is re-checked by a global search.
"""

from __future__ import annotations

import math

import numpy as np

from d2a_core.tracks.config import FrenetSearchConfig


class CentrelineFrame:
    """Frenet frame of samples at s_i = i * spacing (i = 0..n-1) with positions and headings."""

    def __init__(
        self, spacing: float, x: np.ndarray, y: np.ndarray, heading: np.ndarray, config: FrenetSearchConfig | None = None
    ) -> None:
        self.config = config or FrenetSearchConfig()
        self.spacing = float(spacing)
        self.inv_spacing = 1.0 / self.spacing
        self.n = len(x)
        self.length = self.spacing * (self.n - 1)
        nx, ny = -np.sin(heading), np.cos(heading)
        dx, dy = np.diff(x), np.diff(y)
        dnx, dny = np.diff(nx), np.diff(ny)
        # Arrays for the vectorised path.
        self._x, self._y, self._nx, self._ny = x, y, nx, ny
        self._dx, self._dy, self._dnx, self._dny = dx, dy, dnx, dny
        self._a2 = dx * dny - dy * dnx
        self._b1 = dx * ny[:-1] - dy * nx[:-1]
        # Lists for the scalar path.
        self._lx, self._ly = x.tolist(), y.tolist()
        self._lnx, self._lny = nx.tolist(), ny.tolist()
        self._ldx, self._ldy = dx.tolist(), dy.tolist()
        self._ldnx, self._ldny = dnx.tolist(), dny.tolist()
        self._la2, self._lb1 = self._a2.tolist(), self._b1.tolist()

    # ----- scalar ---------------------------------------------------------------------------------

    def _interval_t(self, i: int, px: float, py: float) -> float:
        """Chord parameter of the normal line through (px, py) in interval i (may be outside [0, 1])."""
        wx = px - self._lx[i]
        wy = py - self._ly[i]
        dnx = self._ldnx[i]
        dny = self._ldny[i]
        a2 = self._la2[i]
        a1 = self._lb1[i] - (wx * dny - wy * dnx)
        a0 = wy * self._lnx[i] - wx * self._lny[i]
        disc = a1 * a1 - 4.0 * a2 * a0
        root = math.sqrt(disc) if disc > 0.0 else 0.0
        q = -0.5 * (a1 + root) if a1 >= 0.0 else -0.5 * (a1 - root)
        return a0 / q if q != 0.0 else 0.0

    def _interval_e(self, i: int, t: float, px: float, py: float) -> float:
        mx = self._lnx[i] + t * self._ldnx[i]
        my = self._lny[i] + t * self._ldny[i]
        rx = px - self._lx[i] - t * self._ldx[i]
        ry = py - self._ly[i] - t * self._ldy[i]
        return (rx * mx + ry * my) / math.sqrt(mx * mx + my * my)

    def _beyond_end(self, i: int, px: float, py: float, s_base: float) -> tuple[float, float]:
        """(s, e) on the straight continuation through sample i (first or last)."""
        wx = px - self._lx[i]
        wy = py - self._ly[i]
        nx = self._lnx[i]
        ny = self._lny[i]
        return s_base + wx * ny - wy * nx, wx * nx + wy * ny

    def project(self, px: float, py: float, s_hint: float | None = None) -> tuple[float, float]:
        """(s, e) of one point, searching locally from `s_hint` (global nearest sample when None).

        A hinted answer farther than `global_fallback_m` from the centreline (a stale hint, e.g.
        after a reset) is checked against a global search and the closer answer is returned.
        """
        if s_hint is None:
            return self._walk(min(int(self.nearest_index(np.array([px]), np.array([py]))[0]), self.n - 2), px, py)
        i = int(s_hint * self.inv_spacing) if s_hint > 0.0 else 0
        s, e = self._walk(i if i < self.n - 2 else self.n - 2, px, py)
        if e > self.config.global_fallback_m or -e > self.config.global_fallback_m:
            s_global, e_global = self.project(px, py, None)
            if abs(e_global) < abs(e):
                return s_global, e_global
        return s, e

    def _walk(self, i: int, px: float, py: float) -> tuple[float, float]:
        """Walk from interval i to the interval whose normal line passes through the point."""
        last = self.n - 2
        max_jump = self.config.max_jump_samples
        previous_step = 0
        t = 0.0
        for _ in range(self.config.max_iterations):
            t = self._interval_t(i, px, py)
            if t < 0.0:
                if i == 0:
                    return self._beyond_end(0, px, py, 0.0)
                step = max(math.floor(t), -max_jump)
            elif t > 1.0:
                if i == last:
                    return self._beyond_end(last + 1, px, py, self.length)
                step = min(math.floor(t), max_jump)
            else:
                return (i + t) * self.spacing, self._interval_e(i, t, px, py)
            if step == -previous_step and (step == 1 or step == -1):
                break  # oscillating between two intervals: far off the road inside a bend
            previous_step = step
            i += step
            if i < 0:
                i = 0
            elif i > last:
                i = last
        t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t
        return (i + t) * self.spacing, self._interval_e(i, t, px, py)

    def point(self, s: float, e: float) -> tuple[float, float]:
        """World (x, y) of one Frenet point."""
        u = s * self.inv_spacing
        if u < 0.0 or u >= self.n - 1:
            i = 0 if u < 0.0 else self.n - 1
            ds = s if u < 0.0 else s - self.length
            nx = self._lnx[i]
            ny = self._lny[i]
            return self._lx[i] + ds * ny + e * nx, self._ly[i] - ds * nx + e * ny
        i = int(u)
        t = u - i
        mx = self._lnx[i] + t * self._ldnx[i]
        my = self._lny[i] + t * self._ldny[i]
        scale = e / math.sqrt(mx * mx + my * my)
        return self._lx[i] + t * self._ldx[i] + scale * mx, self._ly[i] + t * self._ldy[i] + scale * my

    # ----- vectorised -----------------------------------------------------------------------------

    def nearest_index(self, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """Index of the nearest sample to each point (brute force in blocks)."""
        out = np.empty(len(px), dtype=np.int64)
        block = self.config.nearest_chunk
        for start in range(0, len(px), block):
            qx = px[start : start + block, None]
            qy = py[start : start + block, None]
            d2 = (qx - self._x[None, :]) ** 2 + (qy - self._y[None, :]) ** 2
            out[start : start + block] = np.argmin(d2, axis=1)
        return out

    def _interval_t_array(self, i: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        wx = px - self._x[i]
        wy = py - self._y[i]
        a2 = self._a2[i]
        a1 = self._b1[i] - (wx * self._dny[i] - wy * self._dnx[i])
        a0 = wy * self._nx[i] - wx * self._ny[i]
        root = np.sqrt(np.maximum(a1 * a1 - 4.0 * a2 * a0, 0.0))
        q = np.where(a1 >= 0.0, -0.5 * (a1 + root), -0.5 * (a1 - root))
        safe_q = np.where(q != 0.0, q, 1.0)
        return np.where(q != 0.0, a0 / safe_q, 0.0)

    def project_array(
        self, px: np.ndarray, py: np.ndarray, s_hint: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised `project` for 1-D arrays of points (and optional hints)."""
        px = np.asarray(px, dtype=float).ravel()
        py = np.asarray(py, dtype=float).ravel()
        last = self.n - 2
        if s_hint is None:
            i = np.minimum(self.nearest_index(px, py), last)
        else:
            hint = np.broadcast_to(np.asarray(s_hint, dtype=float), px.shape)
            i = np.clip(np.floor(hint * self.inv_spacing), 0, last).astype(np.int64)
        max_jump = self.config.max_jump_samples
        t = np.zeros_like(px)
        for _ in range(self.config.max_iterations):
            t = self._interval_t_array(i, px, py)
            step = np.clip(np.floor(t), -max_jump, max_jump).astype(np.int64)
            step[(t >= 0.0) & (t <= 1.0)] = 0
            step[((i == 0) & (t < 0.0)) | ((i == last) & (t > 1.0))] = 0
            if not step.any():
                break
            i = np.clip(i + step, 0, last)
        before = (i == 0) & (t < 0.0)
        after = (i == last) & (t > 1.0)
        t = np.where(before | after, t, np.clip(t, 0.0, 1.0))
        mx = self._nx[i] + t * self._dnx[i]
        my = self._ny[i] + t * self._dny[i]
        rx = px - self._x[i] - t * self._dx[i]
        ry = py - self._y[i] - t * self._dy[i]
        s = (i + t) * self.spacing
        e = (rx * mx + ry * my) / np.sqrt(mx * mx + my * my)
        # Straight continuations beyond the ends.
        for mask, k, base in ((before, 0, 0.0), (after, self.n - 1, self.length)):
            if mask.any():
                wx = px[mask] - self._x[k]
                wy = py[mask] - self._y[k]
                s[mask] = base + wx * self._ny[k] - wy * self._nx[k]
                e[mask] = wx * self._nx[k] + wy * self._ny[k]
        # Stale hints: answers far off the centreline are checked against a global search.
        far = np.abs(e) > self.config.global_fallback_m
        if s_hint is not None and far.any():
            s_global, e_global = self.project_array(px[far], py[far], None)
            better = np.abs(e_global) < np.abs(e[far])
            s[np.flatnonzero(far)[better]] = s_global[better]
            e[np.flatnonzero(far)[better]] = e_global[better]
        return s, e

    def point_array(self, s: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised `point` (s and e broadcast together)."""
        s, e = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(e, dtype=float))
        u = s * self.inv_spacing
        i = np.clip(np.floor(u), 0, self.n - 2).astype(np.int64)
        t = u - i
        inside = (u >= 0.0) & (u < self.n - 1)
        t = np.where(inside, t, np.where(u < 0.0, 0.0, 1.0))
        mx = self._nx[i] + t * self._dnx[i]
        my = self._ny[i] + t * self._dny[i]
        scale = e / np.sqrt(mx * mx + my * my)
        x = self._x[i] + t * self._dx[i] + scale * mx
        y = self._y[i] + t * self._dy[i] + scale * my
        # Outside the samples: continue straight along the end heading (t is 0 or 1 there).
        beyond = np.where(u < 0.0, s, np.where(u >= self.n - 1, s - self.length, 0.0))
        end = np.where(u < 0.0, 0, self.n - 1)
        x = x + beyond * self._ny[end]
        y = y - beyond * self._nx[end]
        return x, y
