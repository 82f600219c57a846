"""The visibility scale of the guard (``vrcorrect.vision.visibility``): its contrast sensitivity against
colour-science's full Barten (1999) model, and what the scale weighs more: the same light on a dark
ground, a grating near the eye's best frequency, anything on a brighter display."""

from __future__ import annotations

import numpy as np
import pytest

from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.specs.display import get_display
from vrcorrect.vision.visibility import ViewingLight, barten_csf, visibility_error

SIZE = 64
WHITE = np.array([0.6, 0.4, 0.3])                         # white's cone light (any positive triple)
DESKTOP = ViewingLight(peak_cd_m2=200.0, floor_cd_m2=0.5, pixels_per_degree=45.0)


def _ground(level: float) -> np.ndarray:
    return np.broadcast_to(level * WHITE, (SIZE, SIZE, 3)).astype(np.float64).copy()


def _grating(period_px: float, amplitude: float) -> np.ndarray:
    """A vertical grating of light, ``amplitude`` of white's, in the L and M cones (a luminance grating)."""
    x = np.arange(SIZE)
    wave = amplitude * np.sin(2 * np.pi * x / period_px)[None, :] * np.ones((SIZE, 1))
    out = np.zeros((SIZE, SIZE, 3))
    out[..., 0], out[..., 1] = wave * WHITE[0], wave * WHITE[1]
    return out


@pytest.mark.parametrize("luminance", [10.0, 100.0])
def test_the_sensitivity_follows_bartens_full_model(luminance):
    """The simplified formula against colour-science's full Barten (1999) model (retinal illuminance of a
    3 mm pupil, a 10 degree field): the same peak frequency, and within 25 % from 0.5 to 16 cycles per
    degree (2 % at 100 cd/m^2 up to 12)."""
    from colour.contrast import contrast_sensitivity_function_Barten1999, retinal_illuminance_Barten1999

    u = np.array([0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0])
    full = contrast_sensitivity_function_Barten1999(u, E=retinal_illuminance_Barten1999(luminance, 3.0), X_0=10)
    ours = barten_csf(u, luminance, 10.0)
    assert u[np.argmax(ours)] == u[np.argmax(full)]
    assert np.all(np.abs(ours / full - 1.0) < 0.25)
    if luminance == 100.0:
        assert np.all(np.abs(ours[:-1] / full[:-1] - 1.0) < 0.02)


def test_sensitivity_falls_in_the_dark_and_at_fine_detail():
    assert barten_csf(4.0, 1.0, 10.0) < barten_csf(4.0, 10.0, 10.0) < barten_csf(4.0, 100.0, 10.0)
    assert barten_csf(30.0, 100.0, 10.0) < 0.1 * barten_csf(3.0, 100.0, 10.0)
    assert np.all(np.isfinite(barten_csf(np.array([0.0, 60.0]), np.array([0.0, 1e4]), 10.0)))   # the floors


def test_a_picture_seen_as_it_should_be_has_no_visible_error():
    for level in (0.0, 0.3, 1.0):
        assert visibility_error(_ground(level), _ground(level), WHITE, DESKTOP) == 0.0


def test_the_same_light_weighs_more_on_a_dark_ground():
    wave = _grating(15.0, 0.02)                              # 3 cycles per degree at 45 pixels per degree
    dark = visibility_error(_ground(0.05) + wave, _ground(0.05), WHITE, DESKTOP)
    bright = visibility_error(_ground(0.8) + wave, _ground(0.8), WHITE, DESKTOP)
    assert dark > 20.0 * bright > 0.0


def test_a_grating_near_the_best_frequency_weighs_more_than_fine_detail_of_the_same_contrast():
    """Coarsely: octave bands that overlap share a grating between them, so 3 cycles per degree weighs
    about 1.8 x 18 cycles per degree, where the squared sensitivities differ 25-fold (the module's
    docstring says so)."""
    ground = _ground(0.5)
    best = visibility_error(ground + _grating(15.0, 0.05), ground, WHITE, DESKTOP)    # 3 cycles per degree
    fine = visibility_error(ground + _grating(2.5, 0.05), ground, WHITE, DESKTOP)     # 18 cycles per degree
    assert best > 1.5 * fine > 0.0


def test_the_error_is_quadratic_in_the_seen_image():
    """The guard reads it off three points: the goal alone sets the adaptation."""
    rng = np.random.default_rng(1)
    goal = _ground(0.4) + 0.1 * rng.random((SIZE, SIZE, 3))
    seen = goal + _grating(7.0, 0.05) + 0.05 * rng.random((SIZE, SIZE, 3))
    f = [visibility_error(goal + b * (seen - goal), goal, WHITE, DESKTOP) for b in (0.5, 1.0)]
    assert f[0] == pytest.approx(0.25 * f[1], rel=1e-9)


def test_a_display_profile_gives_its_light_and_bad_viewing_or_shapes_are_refused():
    desktop = get_display("desktop")
    light = ViewingLight.of(desktop)
    assert light.peak_cd_m2 == desktop.photometry.peak_luminance_cd_m2
    assert light.floor_cd_m2 == pytest.approx(desktop.photometry.black_cd_m2 + desktop.photometry.reflected_cd_m2)
    assert light.pixels_per_degree == desktop.pixels_per_degree
    with pytest.raises(ValidationError, match="viewing.peak_cd_m2"):
        ViewingLight(peak_cd_m2=float("nan"), floor_cd_m2=0.5, pixels_per_degree=45.0)
    with pytest.raises(ValidationError, match="viewing.floor_cd_m2"):
        ViewingLight(peak_cd_m2=100.0, floor_cd_m2=0.0, pixels_per_degree=45.0)
    with pytest.raises(ValidationError, match="seen_lms.shape"):
        visibility_error(_ground(0.5)[:, :10], _ground(0.5), WHITE, DESKTOP)
    with pytest.raises(ValidationError, match="white"):
        visibility_error(_ground(0.5), _ground(0.5), np.array([1.0, 0.0, 1.0]), DESKTOP)
