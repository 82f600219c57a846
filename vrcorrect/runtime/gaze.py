"""Where the eye looks in a view: an eye tracker's gaze (a pose whose -Z axis points along the gaze,
as ``XR_EXT_eye_gaze_interaction`` gives it) projected through a view's pose and field of view.

* :func:`gaze_in_view`: ``(u, v)``, the gaze's place in the view's image, 0..1 from its left and top
  edges (the same as the layer's ``vrcorrect_gaze.c``), or ``None`` when the gaze points away from
  the view.
* :func:`gaze_deg_of`: that place as the ``gaze_deg`` a :class:`~vrcorrect.runtime.corrector.Corrector`
  takes (degrees from the view's centre at the display's pixels per degree, x right, y up), so that
  the window lands on the pixel the tracker names.

Plain numbers, no OpenXR: both ``vrcorrect xr`` (:mod:`vrcorrect.runtime.shell.xr.gaze`) and the API
layer's engine use it.
"""

from __future__ import annotations

import math
from typing import Sequence

from ..specs.vocabulary import MAX_GAZE_DEG

__all__ = ["rotate", "gaze_in_view", "gaze_deg_of"]


def rotate(q: Sequence[float], v: Sequence[float], inverse: bool = False) -> tuple[float, float, float]:
    """``v`` rotated by the unit quaternion ``q`` = (x, y, z, w), or by its inverse."""
    x, y, z, w = (float(c) for c in q)
    if inverse:
        x, y, z = -x, -y, -z
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return (v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx))


def gaze_in_view(gaze: Sequence[float], view: Sequence[float],
                 fov: tuple[float, float, float, float]) -> tuple[float, float] | None:
    """The gaze's place ``(u, v)`` in a view's image (0..1 from its left and top edges; outside 0..1
    when the gaze is off the view).

    ``gaze`` and ``view``: orientations (x, y, z, w) in one space; ``fov``: the view's
    ``(angle_left, angle_right, angle_up, angle_down)`` in radians, as OpenXR gives them.
    ``None`` when the gaze points sideways or backwards from the view."""
    d = rotate(view, rotate(gaze, (0.0, 0.0, -1.0)), inverse=True)
    if d[2] > -1e-6:
        return None
    tx, ty = d[0] / -d[2], d[1] / -d[2]
    left, right, up, down = (math.tan(a) for a in fov)
    if right - left <= 1e-9 or up - down <= 1e-9:
        return None
    return (tx - left) / (right - left), (up - ty) / (up - down)


def gaze_deg_of(uv: tuple[float, float], size: tuple[int, int], ppd: float) -> tuple[float, float]:
    """``(u, v)`` in a ``(W, H)`` view as degrees from its centre at ``ppd`` pixels a degree (x right,
    y up), each held within +-:data:`~vrcorrect.specs.vocabulary.MAX_GAZE_DEG`."""
    W, H = size
    gaze = ((uv[0] - 0.5) * W / ppd, (0.5 - uv[1]) * H / ppd)
    return tuple(min(max(g, -MAX_GAZE_DEG), MAX_GAZE_DEG) for g in gaze)  # type: ignore[return-value]
