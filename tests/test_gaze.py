"""Where the eye looks in a view (``vrcorrect.runtime.gaze``): an eye tracker's gaze pose projected
through a view's pose and asymmetric field of view, and the degrees a Corrector takes for it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vrcorrect.runtime.gaze import gaze_deg_of, gaze_in_view, rotate

FOV = (-0.80, 0.70, 0.75, -0.78)           # the test runtime's left eye: left, right, up, down (radians)


def _quat(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    s = math.sin(angle / 2)
    return (*(axis * s), math.cos(angle / 2))


def _looking(x_deg: float, y_deg: float):
    """A gaze orientation whose -Z points along (tan x, tan y, -1), built independently of the code
    under test: the rotation taking -Z to that direction about their common normal."""
    d = np.array([math.tan(math.radians(x_deg)), math.tan(math.radians(y_deg)), -1.0])
    d /= np.linalg.norm(d)
    f = np.array([0.0, 0.0, -1.0])
    axis = np.cross(f, d)
    if np.linalg.norm(axis) < 1e-12:
        return (0.0, 0.0, 0.0, 1.0)
    return _quat(axis, math.acos(float(np.clip(f @ d, -1, 1))))


def test_rotate_matches_the_rotation_matrix_and_its_inverse_undoes_it():
    q = _quat((1, 2, 3), 0.7)
    x, y, z, w = q
    m = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    v = (0.3, -1.2, 0.5)
    assert np.allclose(rotate(q, v), m @ v, atol=1e-12)
    assert np.allclose(rotate(q, rotate(q, v), inverse=True), v, atol=1e-12)


def test_a_gaze_along_the_views_axis_lands_where_the_axis_crosses_an_asymmetric_view():
    u, v = gaze_in_view((0, 0, 0, 1), (0, 0, 0, 1), FOV)
    left, right, up, down = (math.tan(a) for a in FOV)
    assert u == pytest.approx(-left / (right - left)) and v == pytest.approx(up / (up - down))
    assert u > 0.5          # more of this view lies left of its axis: the axis is right of the image centre


@pytest.mark.parametrize("x, y", [(10, 0), (-20, 15), (30, -25)])
def test_the_gaze_lands_at_its_tangents_in_the_view(x, y):
    uv = gaze_in_view(_looking(x, y), (0, 0, 0, 1), FOV)
    left, right, up, down = (math.tan(a) for a in FOV)
    assert uv == pytest.approx(((math.tan(math.radians(x)) - left) / (right - left),
                                (up - math.tan(math.radians(y))) / (up - down)), abs=1e-9)


def test_a_turned_view_sees_the_gaze_turned_the_other_way():
    turn = _quat((0, 1, 0), math.radians(10))             # the view turned 10 degrees left
    straight = gaze_in_view(_looking(0, 0), turn, (-0.5, 0.5, 0.5, -0.5))
    assert straight[0] == pytest.approx(0.5 + 0.5 * math.tan(math.radians(10)) / math.tan(0.5), abs=1e-9)
    assert straight[1] == pytest.approx(0.5, abs=1e-9)


def test_a_gaze_behind_or_beside_the_view_has_no_place():
    assert gaze_in_view(_quat((0, 1, 0), math.pi), (0, 0, 0, 1), FOV) is None
    assert gaze_in_view(_quat((0, 1, 0), math.pi / 2), (0, 0, 0, 1), FOV) is None


def test_gaze_degrees_put_the_window_on_the_named_pixel_and_are_held_within_90():
    ppd = 20.0
    gx, gy = gaze_deg_of((0.75, 0.25), (200, 100), ppd)
    assert (gx, gy) == pytest.approx((50 / ppd, 25 / ppd))          # 50 px right, 25 px up of the centre
    from vrcorrect.runtime.strategies.foveated import gaze_pixels

    assert gaze_pixels((gx, gy), (200, 100), ppd) == pytest.approx((150, 25))
    assert gaze_deg_of((1e6, -1e6), (200, 100), ppd) == (90.0, 90.0)
