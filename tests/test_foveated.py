"""The foveated frame's CPU twin (:mod:`vrcorrect.solvers.foveated`, issue 45 begun): the full-field
twin on a window around the gaze, the ring held to the target, a blend band, the gaze's motion
warm-started.  The retina is computed here independently of the twins: each cone's image as the
sum over primaries of a direct 2-D convolution (scipy.signal.fftconvolve, "same") of the kernel."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import fftconvolve

from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.solvers.foveated import COLD_WINDOW_ITERATIONS, FoveatedFrames, blend_ramp, fovea_window, foveated_grid
from vrcorrect.solvers.realtime import AdmmFrames, admm_grid
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx

QUEST2 = get_display("quest2")
EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=3.0)
H, W = 96, 128


@pytest.fixture(scope="module")
def kernels():
    return build_kernel(EYE, QUEST2), build_reference_kernel(EYE, QUEST2)


@pytest.fixture(scope="module")
def target():
    codes = bundled_images(128)[0][1][16:16 + H, :W]
    return decode(QUEST2, codes).astype(np.float32)


def _retina(kernel, image_hwc: np.ndarray) -> np.ndarray:
    k = kernel.kernel
    x = np.moveaxis(image_hwc.astype(np.float64), 2, 0)
    return np.stack([sum(fftconvolve(x[j], k[i, j], mode="same") for j in range(3)) for i in range(3)])


def _error(kernels, shown: np.ndarray, target: np.ndarray, rect) -> float:
    """Mean squared LMS error of what the eye sees against the glasses-on view, inside ``rect``."""
    y0, y1, x0, x1 = rect
    d = _retina(kernels[0], shown) - _retina(kernels[1], target)
    return float(np.mean(d[:, y0:y1, x0:x1] ** 2))


def test_a_window_as_large_as_the_view_is_the_full_field_twin(kernels, target):
    """Its cold frame runs COLD_WINDOW_ITERATIONS beyond the frame's (the full-field twin given as
    many), its warm frames the frame's own; a cut starts it cold again."""
    full = AdmmFrames(*kernels, (H, W), cold_iterations=0)
    fov = FoveatedFrames(*kernels, (H, W), radius_px=200)
    assert COLD_WINDOW_ITERATIONS > 0
    for i in range(5):
        cold = i in (0, 3)
        a = full.frame(target, 2 + (COLD_WINDOW_ITERATIONS if cold else 0), cold=cold)
        b = fov.frame(target, 2, gaze_px=(W / 2, H / 2), cold=cold)
        assert b.window.win == (0, H, 0, W) and b.window.sub == (0, H, 0, W)
        np.testing.assert_array_equal(b.shown, a.shown)
        assert b.sub.beta == a.beta
    plain = FoveatedFrames(*kernels, (H, W), radius_px=200, cold_window_iterations=0)
    first = AdmmFrames(*kernels, (H, W), cold_iterations=0).frame(target, 2)
    np.testing.assert_array_equal(plain.frame(target, 2, gaze_px=(W / 2, H / 2)).shown, first.shown)


def test_cold_frames_run_more_iterations_and_converge_sooner(kernels, target):
    """The first frame of the window and of its periphery run their cold iterations: the window's
    error there is lower than with the frame's own alone (the warm frames: the test above)."""
    def window_error(fov):
        f = fov.frame(target, 2, gaze_px=(48, 48))
        y0, y1, x0, x1 = f.window.win
        return _error(kernels, f.shown, target, (y0 + 6, y1 - 6, x0 + 6, x1 - 6)), f

    with_cold = FoveatedFrames(*kernels, (H, W), radius_px=24, band_px=6, periphery="half")
    without = FoveatedFrames(*kernels, (H, W), radius_px=24, band_px=6, periphery="half", cold_window_iterations=0,
                             cold_periphery_iterations=0)
    (e_cold, f_cold), (e_plain, _) = window_error(with_cold), window_error(without)
    assert e_cold < 0.8 * e_plain, (e_cold, e_plain)
    assert with_cold.coarse is not None and f_cold.periphery is not None
    with pytest.raises(ValidationError, match="cold_window_iterations.*0 or more"):
        FoveatedFrames(*kernels, (H, W), radius_px=24, cold_window_iterations=-1)
    with pytest.raises(ValidationError, match="cold_periphery_iterations"):
        FoveatedFrames(*kernels, (H, W), radius_px=24, cold_periphery_iterations=2.5)


def test_outside_the_window_the_view_is_the_target_and_inside_it_is_corrected(kernels, target):
    fov = FoveatedFrames(*kernels, (H, W), radius_px=24, band_px=6)
    full = AdmmFrames(*kernels, (H, W), cold_iterations=0)
    for _ in range(10):
        f = fov.frame(target, 2, gaze_px=(40, 50))
        g = full.frame(target, 2)
    y0, y1, x0, x1 = f.window.win
    assert (y0, y1, x0, x1) == (26, 74, 16, 64)
    outside = np.ones((H, W), bool)
    outside[y0:y1, x0:x1] = False
    np.testing.assert_array_equal(f.shown[outside], target[outside])      # exactly the target
    assert not np.array_equal(f.shown[y0:y1, x0:x1], target[y0:y1, x0:x1])
    assert f.shown.min() >= 0.0 and f.shown.max() <= 1.0
    inner = (y0 + 6, y1 - 6, x0 + 6, x1 - 6)                          # past the blend band
    none = _error(kernels, target, target, inner)
    foveated = _error(kernels, f.shown, target, inner)
    field = _error(kernels, g.shown, target, inner)
    assert foveated < 0.6 * none                                       # the window is corrected
    assert foveated < 1.05 * field                                     # as well as the full field (0.5 % here)
    assert f.sub.objective <= f.sub.uncorrected                        # the guard over the sub-image


def test_the_ring_is_held_to_the_target_so_the_surround_is_what_is_shown(kernels, target):
    """The light from outside the window is modelled as what is shown there: the solution's ring
    (the box's projection) is the target, to half precision."""
    fov = FoveatedFrames(*kernels, (H, W), radius_px=24, band_px=0)
    for _ in range(10):
        f = fov.frame(target, 2, gaze_px=(64, 48))
    twin = fov.twin
    z = twin.proj(twin.q)
    sy0, sy1, sx0, sx1 = f.window.sub
    held = twin.held[:sy1 - sy0, :sx1 - sx0]
    ring = np.moveaxis(target[sy0:sy1, sx0:sx1], 2, 0)[:, held]
    np.testing.assert_allclose(z[:, :sy1 - sy0, :sx1 - sx0][:, held], ring, atol=2e-3)   # half precision


def test_the_blend_fades_only_along_edges_inside_the_view():
    w = fovea_window((H, W), (5, 50), 20, ring=9)
    assert w.win == (30, 70, 0, 25) and w.sub == (21, 79, 0, 58)        # the sub-image moved, not shrunk
    ramp = blend_ramp(w, (H, W), 8)
    assert ramp.shape == (40, 25)
    assert np.all(ramp[8:-8, 0] == 1.0)                                 # the view's left border: no fade
    assert ramp[20, -1] < 0.01 and ramp[0, 10] < 0.01                   # interior edges fade to ~0
    assert np.all(np.diff(ramp[20, 15:]) <= 0) and ramp[20, 12] == 1.0
    far = fovea_window((H, W), (-50, 500), 20, ring=9)                  # a gaze off the view is clamped
    assert far.win == (75, 96, 0, 20) and far.sub == (38, 96, 0, 58)


def test_a_moving_gaze_warm_starts_from_the_reprojected_state(kernels, target):
    """After the window moves 6 px, the warm-started frame's window is corrected better than a cold
    start given the same iterations."""
    warm = FoveatedFrames(*kernels, (H, W), radius_px=24, band_px=6)
    for _ in range(10):
        warm.frame(target, 2, gaze_px=(60, 48))
    moved = warm.frame(target, 2, gaze_px=(66, 48))
    cold = FoveatedFrames(*kernels, (H, W), radius_px=24, band_px=6,
                          cold_window_iterations=0).frame(target, 2, gaze_px=(66, 48))
    assert moved.window == cold.window
    y0, y1, x0, x1 = moved.window.win
    inner = (y0 + 6, y1 - 6, x0 + 6, x1 - 6)
    assert _error(kernels, moved.shown, target, inner) < 0.9 * _error(kernels, cold.shown, target, inner)


def test_the_foveated_grid_is_the_windows_not_the_views():
    assert foveated_grid((1920, 1832), 300, 41) == admm_grid(640, 640, 41)
    assert foveated_grid((96, 128), 200, 19) == admm_grid(128, 96, 19)


@pytest.mark.parametrize("radius, band", [(0, None), (float("nan"), None), (10, 11), (10, -1)])
def test_a_bad_window_is_refused_with_its_field(kernels, radius, band):
    with pytest.raises(ValidationError, match="radius_px" if band is None else "band_px"):
        FoveatedFrames(*kernels, (H, W), radius_px=radius, band_px=band)


@pytest.mark.parametrize("periphery", ["half", "quarter"])
def test_a_coarse_periphery_corrects_outside_the_window_and_the_ring_holds_it(kernels, target, periphery):
    """With a half- or quarter-resolution periphery the view outside the window is that correction
    (not the target), which lowers the retinal error there against the target periphery; the
    window's ring is held to it (the light from outside is what is shown there); values stay in
    [0, 1]."""
    plain = FoveatedFrames(*kernels, (H, W), radius_px=20, band_px=5)
    coarse = FoveatedFrames(*kernels, (H, W), radius_px=20, band_px=5, periphery=periphery)
    for _ in range(10):
        a = plain.frame(target, 2, gaze_px=(40, 48))
        b = coarse.frame(target, 2, gaze_px=(40, 48))
    assert a.periphery is None and b.periphery is not None
    y0, y1, x0, x1 = b.window.win
    outside = np.ones((H, W), bool)
    outside[y0:y1, x0:x1] = False
    np.testing.assert_array_equal(b.shown[outside], b.periphery[outside])
    assert np.abs(b.periphery - target).max() > 0.05                     # a correction, not the target
    assert b.shown.min() >= 0.0 and b.shown.max() <= 1.0
    right = (8, H - 8, x1 + 12, W - 8)                                   # the view right of the window
    bound = {"half": 0.8, "quarter": 0.95}[periphery]                     # a 24 x 32 quarter view corrects less
    assert _error(kernels, b.shown, target, right) < bound * _error(kernels, a.shown, target, right)
    twin = coarse.twin
    z = twin.proj(twin.q)
    sy0, sy1, sx0, sx1 = b.window.sub
    held = twin.held[:sy1 - sy0, :sx1 - sx0]
    ring = np.moveaxis(b.periphery[sy0:sy1, sx0:sx1], 2, 0)[:, held]
    np.testing.assert_allclose(z[:, :sy1 - sy0, :sx1 - sx0][:, held], ring, atol=2e-3)


def test_an_unknown_periphery_is_refused(kernels):
    with pytest.raises(ValidationError, match="periphery"):
        FoveatedFrames(*kernels, (H, W), radius_px=20, periphery="blurred")
