"""Rotation helpers shared by the pybullet world and the episode logs."""

from __future__ import annotations

import math


def euler_to_quaternion(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> tuple[float, float, float, float]:
    """Quaternion ``(x, y, z, w)`` of ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (intrinsic z-y-x, pybullet's convention)."""
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )
