"""Tyre model: Pacejka's magic formula for pure lateral slip, in friction-coefficient form.

The force an axle produces is ``Fz * magic_formula(alpha)`` with the peak friction ``D`` scaled by
the load (``load_scaled_mu``), so the peak is about ``d_peak_mu * Fz`` near the axle's static load.
The vehicle combines it with the longitudinal force through a friction ellipse (``ellipse_factor``);
its hot loop inlines these formulas for speed, and the functions here are their reference.
"""

from __future__ import annotations

import math

from pydantic import Field

from d2a_core.config.section import Section


class TyreConfig(Section):
    """Magic-formula coefficients of one axle (lateral force per unit normal load)."""


    b_stiffness: float = Field(10.0, gt=0, description="B: stiffness factor (1/rad)")
    c_shape: float = Field(
        1.9, gt=1.0, lt=2.0, description="C: shape factor; below 2 keeps grip when sliding"
    )
    d_peak_mu: float = Field(1.6, gt=0, le=3.0, description="D: peak friction coefficient")
    e_curvature: float = Field(0.9, le=1.0, description="E: curvature factor near and after the peak")
    load_sensitivity: float = Field(
        0.0,
        ge=0,
        lt=1,
        description="drop of the peak friction per unit of relative load above the axle's static load",
    )


def load_scaled_mu(tyre: TyreConfig, fz: float, fz_nominal: float) -> float:
    """Peak friction at load ``fz``: real tyres grip less per newton as the load grows.

    Linear in the load, clamped to at least a tenth of ``d_peak_mu``. Because of it, shifting load
    from one axle to the other loses total grip, and the cornering stiffness grows less than
    proportionally with the load.
    """
    mu = tyre.d_peak_mu * (1.0 - tyre.load_sensitivity * (fz / fz_nominal - 1.0))
    return max(mu, 0.1 * tyre.d_peak_mu)


def magic_formula(alpha: float, b: float, c: float, d: float, e: float) -> float:
    """Lateral friction coefficient at slip angle ``alpha`` (rad); odd in ``alpha``, peak ``d``."""
    b_alpha = b * alpha
    return d * math.sin(c * math.atan(b_alpha - e * (b_alpha - math.atan(b_alpha))))


def lateral_mu(alpha: float, tyre: TyreConfig) -> float:
    """``magic_formula`` with the coefficients of ``tyre``."""
    return magic_formula(alpha, tyre.b_stiffness, tyre.c_shape, tyre.d_peak_mu, tyre.e_curvature)


def peak_slip_angle(tyre: TyreConfig) -> float:
    """Slip angle (rad, positive) where the lateral force peaks, found by a golden-section search."""
    lo, hi = 1e-4, 1.0
    inv_phi = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        a = hi - inv_phi * (hi - lo)
        b = lo + inv_phi * (hi - lo)
        if lateral_mu(a, tyre) < lateral_mu(b, tyre):
            lo = a
        else:
            hi = b
    return 0.5 * (lo + hi)


def ellipse_factor(fx: float, fx_capacity: float) -> float:
    """Share of the lateral capacity left when the tyre already carries ``fx`` (friction ellipse)."""
    if fx_capacity <= 0.0:
        return 0.0
    ratio = fx / fx_capacity
    rest = 1.0 - ratio * ratio
    return math.sqrt(rest) if rest > 0.0 else 0.0
