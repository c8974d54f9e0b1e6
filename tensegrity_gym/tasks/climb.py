"""The climbing task (``TensegrityClimb-v0``): the slope as the physics sees it, written once for
NumPy arrays and torch tensors. SI units, angles in degrees.

A plane of slope ``alpha`` is simulated in its own frame: x uphill, y across the slope, z along
the plane's normal. There the ground is the level plane z = 0 (the rolling task's ground contact,
unchanged) and gravity is tilted: ``g' = |g| (-sin alpha, 0, -cos alpha)``. This is the same
physics as a sloped plane in the world frame, rotated: contact forces, friction and the motion
along the plane are exact, and no terrain code runs for a slope. Positions, velocities and
progress are reported in the plane frame (uphill distance along x).
"""
from __future__ import annotations

import numpy as np

from .xp import namespace

__all__ = ["plane_gravity", "gravity_direction"]


def plane_gravity(slope_deg, g: float = 9.81):
    """(..., 3) gravity in the frame of a plane of slope ``slope_deg`` (...) degrees, uphill +x,
    m/s^2, for gravitational acceleration ``g`` (m/s^2)."""
    xp = namespace(slope_deg)
    a = slope_deg * (np.pi / 180.0)
    return xp.stack([-g * xp.sin(a), 0.0 * a, -g * xp.cos(a)], axis=-1)


def gravity_direction(gravity):
    """(..., 3) unit vector of ``gravity`` (..., 3) (what an accelerometer at rest would read,
    negated): the slope as a state observation."""
    xp = namespace(gravity)
    return gravity / xp.norm(gravity, keepdims=True)
