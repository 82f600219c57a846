"""Poses and projections of the headset's views (``vrcorrect xr``): an OpenXR pose as a matrix, the
view matrix that looks from it, and the asymmetric projection of a view's field of view.

Layer 5: numpy; never torch.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ....plumbing.errors import ValidationError

if TYPE_CHECKING:  # pragma: no cover - typing only
    pass

__all__ = ["pose_matrix", "view_matrix", "projection_from_fov"]


def pose_matrix(orientation: Sequence[float], position: Sequence[float]) -> np.ndarray:
    """The 4x4 matrix of a pose: unit quaternion ``(x, y, z, w)`` then translation (m)."""
    x, y, z, w = (float(v) for v in orientation)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n < 1e-6:
        raise ValidationError("pose.orientation", (x, y, z, w), "a non-zero quaternion (x, y, z, w)")
    x, y, z, w = x / n, y / n, z / n, w / n
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [float(v) for v in position]
    return m


def view_matrix(orientation: Sequence[float], position: Sequence[float]) -> np.ndarray:
    """World-to-eye matrix of an eye at a pose (the inverse of :func:`pose_matrix`)."""
    m = pose_matrix(orientation, position)
    inv = np.eye(4)
    inv[:3, :3] = m[:3, :3].T
    inv[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return inv


def projection_from_fov(angle_left: float, angle_right: float, angle_up: float, angle_down: float,
                        near_m: float = 0.05, far_m: float = 60.0) -> np.ndarray:
    """OpenGL projection (clip z in [-1, 1]) of an OpenXR field of view: four angles in radians
    (left and down negative for a view that contains the forward axis); may be asymmetric."""
    angles = (angle_left, angle_right, angle_up, angle_down)
    if not all(math.isfinite(a) and abs(a) < math.pi / 2 for a in angles) or angle_right <= angle_left \
            or angle_up <= angle_down:
        raise ValidationError("fov", angles, "angles in (-pi/2, pi/2) rad with left < right and down < up")
    if not 0 < near_m < far_m:
        raise ValidationError("near_m, far_m", (near_m, far_m), "0 < near_m < far_m")
    left, right = math.tan(angle_left), math.tan(angle_right)
    up, down = math.tan(angle_up), math.tan(angle_down)
    p = np.zeros((4, 4))
    p[0, 0] = 2 / (right - left)
    p[0, 2] = (right + left) / (right - left)
    p[1, 1] = 2 / (up - down)
    p[1, 2] = (up + down) / (up - down)
    p[2, 2] = -(far_m + near_m) / (far_m - near_m)
    p[2, 3] = -2 * far_m * near_m / (far_m - near_m)
    p[3, 2] = -1.0
    return p
