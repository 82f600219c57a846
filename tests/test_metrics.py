"""Image quality metrics: PSNR, SSIM, FLIP, the LMS objective and evaluate_seen."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.ndimage
import skimage.data

from vrcorrect.specs.display import decode, get_display
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.physics.kernel import KernelOptions, build_kernel
from vrcorrect.vision.metrics import ImageMetrics, evaluate_seen, flip, lms_objective, psnr, ssim
from vrcorrect.vision.vdp import foveated_jod, jod
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.specs.prescription import EyeRx

AT_INFINITY = KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf))


@pytest.fixture(scope="module")
def astronaut_srgb() -> np.ndarray:
    """A 96x96 crop of skimage's astronaut (face and suit: edges and flat areas), sRGB in [0, 1]."""
    return skimage.data.astronaut()[100:196, 180:276].astype(np.float64) / 255.0


@pytest.fixture(scope="module")
def rng():
    return np.random.default_rng(2023)


def blurred(img: np.ndarray, sigma: float) -> np.ndarray:
    return scipy.ndimage.gaussian_filter(img, sigma=(sigma, sigma, 0), mode="nearest")


def call_without_exit(fn, *args, **kwargs):
    """Call ``fn``; a SystemExit (what flip_evaluator does on bad input) fails the test."""
    try:
        return fn(*args, **kwargs)
    except SystemExit as exc:  # pragma: no cover - the failure being guarded against
        pytest.fail(f"SystemExit({exc.code}) escaped from {fn.__name__}")


# --------------------------------------------------------------------------
# PSNR
# --------------------------------------------------------------------------


def test_psnr_of_identical_images_is_inf(astronaut_srgb):
    assert psnr(astronaut_srgb, astronaut_srgb.copy()) == math.inf


@pytest.mark.parametrize("offset, data_range", [(0.05, 1.0), (0.01, 1.0), (0.1, 2.0)])
def test_psnr_of_constant_offset_is_closed_form(rng, offset, data_range):
    a = rng.uniform(0.2, 0.8, size=(17, 23, 3))
    expected = 10.0 * math.log10(data_range**2 / offset**2)
    assert psnr(a, a + offset, data_range=data_range) == pytest.approx(expected, rel=1e-9)


# --------------------------------------------------------------------------
# SSIM
# --------------------------------------------------------------------------


def test_ssim_of_identical_images_is_one(astronaut_srgb):
    assert ssim(astronaut_srgb, astronaut_srgb.copy()) == pytest.approx(1.0, abs=1e-12)


def test_ssim_decreases_with_noise(astronaut_srgb, rng):
    noise = rng.standard_normal(astronaut_srgb.shape)
    scores = [ssim(astronaut_srgb, astronaut_srgb + s * noise) for s in (0.01, 0.05, 0.2)]
    assert 1.0 > scores[0] > scores[1] > scores[2]


@pytest.mark.parametrize("side", [3, 4, 5, 6])
def test_ssim_small_images_use_a_window_that_fits(rng, side):
    a = rng.random((side, side + 2, 3))
    assert ssim(a, a.copy()) == 1.0
    noisy = ssim(a, np.clip(a + 0.3 * rng.standard_normal(a.shape), 0, 1))
    assert -1.0 <= noisy < 0.99


def test_ssim_below_three_pixels_is_global_formula():
    a = np.full((1, 1, 3), 0.2)
    b = np.full((1, 1, 3), 0.4)
    c1 = (0.01 * 1.0) ** 2
    # A single pixel has no variance: the contrast-structure term is C2/C2 = 1.
    expected = (2 * 0.2 * 0.4 + c1) / (0.2**2 + 0.4**2 + c1)
    assert ssim(a, b) == pytest.approx(expected, rel=1e-12)
    assert ssim(a, a.copy()) == 1.0
    two = np.array([[[0.0, 0.0, 0.0]], [[1.0, 1.0, 1.0]]])   # 2x1, contrast reversed
    assert ssim(two, two[::-1]) < 0.0


# --------------------------------------------------------------------------
# FLIP
# --------------------------------------------------------------------------


def test_flip_of_identical_images_is_zero(astronaut_srgb):
    mean, fmap = flip(astronaut_srgb, astronaut_srgb.copy(), 20.0)
    assert mean == 0.0
    assert fmap.shape == astronaut_srgb.shape[:2] and not fmap.any()


def test_flip_increases_with_blur(astronaut_srgb):
    means = [flip(astronaut_srgb, blurred(astronaut_srgb, s), 20.0)[0] for s in (0.7, 1.5, 3.0)]
    assert 0.0 < means[0] < means[1] < means[2]


def test_flip_map_is_per_pixel_and_mean_is_its_mean(astronaut_srgb):
    test = blurred(astronaut_srgb, 2.0)
    mean, fmap = flip(astronaut_srgb, test, 20.0)
    assert fmap.shape == (96, 96) and fmap.dtype == np.float32
    assert float(fmap.mean()) == pytest.approx(mean, rel=1e-5)
    assert fmap.min() >= 0.0 and fmap.max() <= 1.0
    # Error concentrates on edges: the flattest 8x8 block scores below the image's mean.
    grad = np.abs(np.diff(astronaut_srgb, axis=0))[:, :-1].sum(2) + np.abs(np.diff(astronaut_srgb, axis=1))[:-1].sum(2)
    blocks = grad[:88, :88].reshape(11, 8, 11, 8).sum((1, 3))
    i, j = np.unravel_index(np.argmin(blocks), blocks.shape)
    assert fmap[8 * i:8 * i + 8, 8 * j:8 * j + 8].mean() < mean


def test_flip_passes_pixels_per_degree_through(astronaut_srgb):
    test = blurred(astronaut_srgb, 1.5)
    low, _ = flip(astronaut_srgb, test, 10.0)
    high, _ = flip(astronaut_srgb, test, 120.0)
    # Seen from farther away (more pixels per degree) the same blur is less visible.
    assert high < low
    assert abs(high - low) > 0.01


@pytest.mark.parametrize("shape", [(1, 1, 3), (2, 3, 3), (5, 4, 3)])
def test_flip_accepts_tiny_images(rng, shape):
    a = rng.random(shape)
    mean, fmap = flip(a, np.clip(a + 0.2, 0, 1), 20.0)
    assert 0.0 < mean <= 1.0 and fmap.shape == shape[:2]
    assert flip(a, a.copy(), 20.0)[0] == 0.0


def test_flip_accepts_float32_noncontiguous_and_integer_inputs(astronaut_srgb):
    test = blurred(astronaut_srgb, 1.0)
    ref_mean, _ = flip(astronaut_srgb, test, 20.0)
    f32 = flip(astronaut_srgb.astype(np.float32)[:, ::-1][:, ::-1], test.astype(np.float32), 20.0)[0]
    assert f32 == pytest.approx(ref_mean, rel=1e-5)
    ones = np.ones((4, 4, 3), dtype=np.uint8)
    assert flip(ones, ones, 20.0)[0] == 0.0


def test_flip_clips_tiny_excursions(astronaut_srgb):
    test = blurred(astronaut_srgb, 1.0)
    nudged = test.copy()
    nudged[0, 0] = 1.0 + 5e-7
    nudged[1, 1] = -5e-7
    clean = test.copy()
    clean[0, 0] = 1.0
    clean[1, 1] = 0.0
    assert flip(astronaut_srgb, nudged, 20.0)[0] == pytest.approx(flip(astronaut_srgb, clean, 20.0)[0], rel=1e-6)


def _bad_flip_cases():
    rng = np.random.default_rng(1)
    good = rng.random((8, 8, 3))
    nan = good.copy()
    nan[3, 3, 1] = np.nan
    inf = good.copy()
    inf[0, 0, 0] = np.inf
    high = good.copy()
    high[2, 2, 2] = 1.01
    low = good.copy()
    low[2, 2, 0] = -0.5
    return [
        ("shape mismatch", good, good[:4], 20.0, "test_srgb.shape"),
        ("2-D grey", good[..., 0], good[..., 0], 20.0, "reference_srgb.shape"),
        ("4 channels", np.dstack([good, good[..., :1]]), np.dstack([good, good[..., :1]]), 20.0,
         "reference_srgb.shape"),
        ("empty", good[:0], good[:0], 20.0, "reference_srgb.shape"),
        ("NaN in test", good, nan, 20.0, "test_srgb"),
        ("inf in reference", inf, good, 20.0, "reference_srgb"),
        ("above 1", good, high, 20.0, "test_srgb"),
        ("below 0", low, good, 20.0, "reference_srgb"),
        ("ppd zero", good, good, 0.0, "pixels_per_degree"),
        ("ppd negative", good, good, -5.0, "pixels_per_degree"),
        ("ppd nan", good, good, float("nan"), "pixels_per_degree"),
        ("ppd inf", good, good, float("inf"), "pixels_per_degree"),
        ("ppd bool", good, good, True, "pixels_per_degree"),
        ("ppd string", good, good, "20", "pixels_per_degree"),
        ("complex", good.astype(complex), good, 20.0, "reference_srgb.dtype"),
    ]


@pytest.mark.parametrize("case", _bad_flip_cases(), ids=lambda c: c[0])
def test_flip_validation_errors_name_the_field_and_never_exit(case):
    _, ref, test, ppd, field = case
    with pytest.raises(ValidationError) as err:
        call_without_exit(flip, ref, test, ppd)
    assert err.value.field == field


@pytest.mark.parametrize("fn", [psnr, ssim, lms_objective])
def test_other_metrics_reject_mismatch_and_nan(fn):
    a = np.zeros((8, 8, 3))
    with pytest.raises(ValidationError) as err:
        fn(a, a[:, :5])
    assert err.value.field.endswith(".shape")
    b = a.copy()
    b[1, 1, 1] = np.nan
    with pytest.raises(ValidationError, match="NaN"):
        fn(a, b)


@pytest.mark.parametrize("fn", [psnr, ssim])
def test_data_range_must_be_positive(fn):
    a = np.zeros((8, 8, 3))
    with pytest.raises(ValidationError) as err:
        fn(a, a, data_range=0.0)
    assert err.value.field == "data_range"


# --------------------------------------------------------------------------
# LMS objective
# --------------------------------------------------------------------------


def test_lms_objective_is_the_mean_squared_error():
    a = np.zeros((2, 2, 3))
    b = np.full((2, 2, 3), 0.5)
    b[1, 0, 2] = 1.0
    # 11 entries differ by 0.5, one by 1.0, over 2*2*3 = 12 entries.
    assert lms_objective(a, b) == pytest.approx((11 * 0.25 + 1.0) / 12, rel=1e-15)
    assert lms_objective(b, b.copy()) == 0.0


def test_lms_objective_accumulates_in_float64(rng):
    a = rng.random((64, 64, 3)).astype(np.float32)
    b = (a + np.float32(1e-4)).astype(np.float32)
    exact = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    assert lms_objective(a, b) == pytest.approx(exact, rel=1e-12)


# --------------------------------------------------------------------------
# evaluate_seen
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sharp_setup():
    display = dataclasses.replace(get_display("quest2"), pixels_per_degree=5.0)
    kernel = build_kernel(EyeRx(sphere_D=0, cylinder_D=0, axis_deg=0, pupil_diameter_mm=2.0), display, AT_INFINITY)
    return kernel, display


@pytest.fixture(scope="module")
def myopic_setup():
    display = get_display("quest2")
    kernel = build_kernel(EyeRx(sphere_D=-3.0, cylinder_D=0, axis_deg=0, pupil_diameter_mm=4.0), display, AT_INFINITY)
    return kernel, display


@pytest.fixture(scope="module")
def astronaut_linear(astronaut_srgb):
    return decode(get_display("quest2"), astronaut_srgb)


def test_evaluate_seen_identity_eye_sees_the_target(sharp_setup, astronaut_linear, astronaut_srgb):
    kernel, display = sharp_setup
    assert kernel.identity
    m, images = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display)
    assert isinstance(m, ImageMetrics)
    assert m.objective == pytest.approx(0.0, abs=1e-12)
    assert m.flip == pytest.approx(0.0, abs=1e-4) and m.flip_lms == pytest.approx(0.0, abs=1e-4)
    assert m.ssim == pytest.approx(1.0, abs=1e-6) and m.ssim_lms == pytest.approx(1.0, abs=1e-6)
    assert m.psnr > 60 and m.psnr_lms > 60
    # Rendering the cone image back to display sRGB recovers the image itself (LMS -> RGB inverts A).
    np.testing.assert_allclose(images["target_srgb"], astronaut_srgb, atol=1e-6)
    assert {"seen_srgb", "target_srgb", "flip_map", "seen_lms", "target_lms"} <= set(images)
    for key in ("seen_srgb", "target_srgb", "seen_lms", "target_lms"):
        assert images[key].shape == (96, 96, 3)
    assert images["flip_map"].shape == (96, 96)


def test_evaluate_seen_myopic_eye_sees_a_blur(myopic_setup, astronaut_linear):
    kernel, display = myopic_setup
    assert not kernel.identity
    m, images = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display)
    assert m.objective > 1e-4
    assert m.flip > 0.05 and m.flip_lms > 0.05
    assert m.ssim < 0.95 and m.psnr < 40
    assert m.objective == pytest.approx(lms_objective(images["seen_lms"], images["target_lms"]))
    # The FLIP map is the one of the sRGB renderings, at the display's pixels per degree.
    mean, fmap = flip(images["target_srgb"], images["seen_srgb"], display.pixels_per_degree)
    assert mean == pytest.approx(m.flip, rel=1e-6)
    np.testing.assert_allclose(images["flip_map"], fmap)
    # The seen image is blurrier than the target: less high-frequency energy in the cones.
    def detail(x):
        return float(np.abs(np.diff(x, axis=1)).mean())
    assert detail(images["seen_lms"]) < 0.8 * detail(images["target_lms"])


def test_evaluate_seen_target_options(myopic_setup, astronaut_linear):
    kernel, display = myopic_setup
    m_ideal, images = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display)
    # The paper's ideal target is A applied per pixel.
    np.testing.assert_allclose(images["target_lms"], astronaut_linear @ kernel.matrix.T, atol=1e-12)
    # An explicit target_lms takes precedence: here, exactly what the eye sees -> zero error.
    m_self, _ = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display, target_lms=images["seen_lms"])
    assert m_self.objective == 0.0 and m_self.flip == 0.0
    # A reference kernel is used for the target: a sharp eye (2 mm pupil, no refractive error) at the same
    # display still has diffraction and chromatic blur, so its view differs from A's ideal, but far less
    # than what the myopic eye sees.
    sharp = build_kernel(EyeRx(sphere_D=0, cylinder_D=0, axis_deg=0, pupil_diameter_mm=2.0), display, AT_INFINITY)
    m_ref, ref_images = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display, reference_kernel=sharp)
    ideal = images["target_lms"]
    off_ideal = lms_objective(ref_images["target_lms"], ideal)
    assert 0.0 < off_ideal < 0.25 * lms_objective(images["seen_lms"], ideal)
    np.testing.assert_allclose(ref_images["seen_lms"], images["seen_lms"])
    assert m_ref.objective != m_ideal.objective
    # The blurred eye as its own reference sees exactly the target.
    m_same, _ = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display, reference_kernel=kernel)
    assert m_same.objective == pytest.approx(0.0, abs=1e-20)


def test_evaluate_seen_validates_inputs(sharp_setup, myopic_setup):
    kernel, display = sharp_setup
    img = np.full((8, 8, 3), 0.5)
    cases = [
        (dict(displayed_linear=img[:4]), "target_linear.shape"),
        (dict(displayed_linear=np.where(img > 0, np.nan, img)), "displayed_linear"),
        (dict(target_linear=img * 3), "target_linear"),
        (dict(target_lms=np.zeros((4, 4, 3))), "target_lms.shape"),
        (dict(display=myopic_setup[1]), "display.pixels_per_degree"),
    ]
    for override, field in cases:
        args = dict(displayed_linear=img, target_linear=img, eye_kernel=kernel, display=display)
        args.update(override)
        with pytest.raises(ValidationError) as err:
            call_without_exit(evaluate_seen, **args)
        assert err.value.field == field, override


# --------------------------------------------------------------------------
# JOD (ColorVideoVDP)
# --------------------------------------------------------------------------


def test_jod_of_identical_images_is_ten(astronaut_srgb):
    for name in ("desktop", "quest2"):
        assert jod(astronaut_srgb, astronaut_srgb.copy(), get_display(name)) == pytest.approx(10.0, abs=1e-4)


def test_jod_falls_monotonically_with_blur(astronaut_srgb):
    """More blur is never judged better, and a strong blur is clearly visible (several JOD)."""
    display = get_display("desktop")
    scores = [jod(astronaut_srgb, blurred(astronaut_srgb, s), display) for s in (0.5, 1.0, 2.0, 4.0)]
    assert all(a > b for a, b in zip(scores, scores[1:])), scores
    assert scores[0] > 9.0 and scores[-1] < 8.0, scores
    assert all(s < 10.0 for s in scores)


def test_jod_depends_on_the_viewing_conditions(astronaut_srgb):
    """The same pixel blur is more visible at fewer pixels per degree (each pixel spans more of the view)."""
    desk = get_display("desktop")
    coarse = dataclasses.replace(desk, pixels_per_degree=15.0)
    test = blurred(astronaut_srgb, 1.0)
    assert jod(astronaut_srgb, test, coarse) < jod(astronaut_srgb, test, desk)
    # A dimmer display in a bright room hides more of the difference than a bright one in the dark.
    dim = dataclasses.replace(desk, photometry=dataclasses.replace(desk.photometry, peak_luminance_cd_m2=20.0,
                                                                    ambient_lux=2000.0))
    bright = dataclasses.replace(desk, photometry=dataclasses.replace(desk.photometry, peak_luminance_cd_m2=400.0,
                                                                       ambient_lux=0.0))
    assert jod(astronaut_srgb, test, dim) > jod(astronaut_srgb, test, bright)


def test_jod_smallest_image(rng):
    a = rng.uniform(0.2, 0.8, size=(2, 2, 3))
    assert jod(a, a, get_display("desktop")) == pytest.approx(10.0, abs=1e-4)


def test_foveated_jod_counts_a_difference_at_the_fixation_more_than_far_from_it():
    """FovVideoVDP (foveated): identical images score 10; an image blurred on its left half scores
    lower for an eye fixating the blur than for one fixating the sharp right half 20 degrees away."""
    big = skimage.data.astronaut()[::2, ::2].astype(np.float64) / 255.0         # 256 x 256
    quest2 = get_display("quest2")                                              # 18.9 px a degree
    assert foveated_jod(big, big.copy(), quest2, (128, 128)) == pytest.approx(10.0, abs=1e-3)
    test = big.copy()
    test[:, :128] = blurred(big, 2.0)[:, :128]
    at_blur = foveated_jod(big, test, quest2, (40, 128))
    away = foveated_jod(big, test, quest2, (215, 128))
    assert at_blur < away < 10.0, (at_blur, away)


@pytest.mark.parametrize("fixation", [(-1, 10), (10, 96), (float("nan"), 3)])
def test_foveated_jod_refuses_a_fixation_outside_the_image(astronaut_srgb, fixation):
    with pytest.raises(ValidationError) as info:
        foveated_jod(astronaut_srgb, astronaut_srgb, get_display("quest2"), fixation)
    assert info.value.field == "fixation_px"


@pytest.mark.parametrize("args, field", [
    (dict(reference_srgb=np.zeros((8, 8)), test_srgb=np.zeros((8, 8))), "reference_srgb.shape"),
    (dict(reference_srgb=np.zeros((1, 8, 3)), test_srgb=np.zeros((1, 8, 3))), "reference_srgb.shape"),
    (dict(reference_srgb=np.zeros((8, 8, 3)), test_srgb=np.zeros((8, 9, 3))), "test_srgb.shape"),
    (dict(reference_srgb=np.full((8, 8, 3), np.nan), test_srgb=np.zeros((8, 8, 3))), "reference_srgb"),
    (dict(reference_srgb=np.zeros((8, 8, 3)), test_srgb=np.full((8, 8, 3), 1.5)), "test_srgb"),
    (dict(reference_srgb=np.zeros((8, 8, 3)), test_srgb=np.zeros((8, 8, 3)), display="desktop"), "display"),
])
def test_jod_rejects_bad_input(args, field):
    args = {"display": get_display("desktop"), **args}
    with pytest.raises(ValidationError) as info:
        call_without_exit(jod, **args)
    assert info.value.field == field


def test_evaluate_seen_scores_jod(myopic_setup, astronaut_linear):
    kernel, display = myopic_setup
    m, _ = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display)
    assert m.jod is not None and m.jod < 9.5          # the myopic eye's blur is visible
    m_self, images = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display, with_jod=False)
    assert m_self.jod is None
    same, _ = evaluate_seen(astronaut_linear, astronaut_linear, kernel, display, target_lms=images["seen_lms"])
    assert same.jod == pytest.approx(10.0, abs=1e-4)
