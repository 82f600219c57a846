"""The forward model: what the eye sees of an image."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from vrcorrect.specs.display import decode, encode, get_display
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.vision.forward import _convolve_direct, lms_to_display, simulate_lms, what_the_eye_sees
from vrcorrect.physics.kernel import KernelOptions, build_kernel
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.specs.prescription import EyeRx

# Per-dtype tolerances for comparing two computations of the same quantity.
TOL = {np.float32: 1e-5, np.float64: 1e-10}


def eye(s=0.0, c=0.0, a=0.0, pupil=4.0) -> EyeRx:
    return EyeRx(sphere_D=s, cylinder_D=c, axis_deg=a, pupil_diameter_mm=pupil)


@pytest.fixture(scope="module")
def kernel():
    return build_kernel(eye(-2.0, -1.0, 30.0), get_display("quest2"))


@pytest.fixture(scope="module")
def rng():
    return np.random.default_rng(7)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fft_and_direct_paths_agree(kernel, rng, dtype):
    img = rng.random((53, 71, 3)).astype(dtype)
    a, ia = simulate_lms(img, kernel, "fft")
    b, ib = simulate_lms(img, kernel, "direct")
    assert ia.path == "fft" and ib.path == "direct"
    assert a.dtype == dtype and b.dtype == dtype
    np.testing.assert_allclose(a, b, atol=TOL[dtype])


def test_convolution_is_true_convolution_not_correlation():
    """An impulse reproduces the kernel itself, not its mirror image."""
    k = build_kernel(eye(0.0, -2.0, 45.0), get_display("quest2"),
                     KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf)))
    n = 2 * k.size + 1
    img = np.zeros((n, n, 3))
    img[n // 2, n // 2, 1] = 1.0
    for method in ("fft", "direct"):
        out, _ = simulate_lms(img, k, method)
        c, r = n // 2, k.size // 2
        np.testing.assert_allclose(out[c - r:c + r + 1, c - r:c + r + 1, 0], k.kernel[0, 1], atol=1e-12)


def test_grey_image_takes_the_exact_achromatic_shortcut(kernel, rng):
    g = rng.random((40, 50)).astype(np.float64)
    img = np.repeat(g[..., None], 3, axis=2)
    fast, info = simulate_lms(img, kernel, "direct")
    assert info.achromatic and info.convolutions == 3
    full = np.moveaxis(_convolve_direct(np.moveaxis(img, 2, 0).copy(), kernel.kernel), 0, 2)
    np.testing.assert_allclose(fast, full, atol=1e-12)
    # a colour image takes nine convolutions
    img[0, 0, 0] += 0.1
    _, info = simulate_lms(img, kernel, "direct")
    assert not info.achromatic and info.convolutions == 9


def test_identity_kernel_is_a_colour_matrix_only():
    low = get_display("quest2")
    import dataclasses
    low = dataclasses.replace(low, pixels_per_degree=5.0)
    k = build_kernel(eye(0.0, pupil=2.0), low, KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf)))
    img = np.random.default_rng(1).random((8, 9, 3))
    out, info = simulate_lms(img, k)
    assert info.path == "identity" and info.convolutions == 0
    np.testing.assert_allclose(out, img @ k.matrix.T, atol=1e-12)
    np.testing.assert_allclose(lms_to_display(out, k), img, atol=1e-12)


def test_uniform_interior_is_unchanged_and_border_darkens(kernel):
    """Kernel sums equal A: a uniform field keeps its colour away from the border; outside the
    image the panel is black, so the border darkens."""
    img = np.full((80, 80, 3), [0.2, 0.5, 0.8])
    seen, _ = what_the_eye_sees(img, kernel)
    r = kernel.size // 2
    np.testing.assert_allclose(seen[r:-r, r:-r], img[r:-r, r:-r], atol=1e-6)
    assert seen[0, 0].sum() < img[0, 0].sum() * 0.6


def test_black_and_white(kernel):
    black = np.zeros((32, 32, 3), np.float32)
    out, _ = what_the_eye_sees(black, kernel)
    assert np.all(out == 0)
    white = np.ones((64, 64, 3), np.float32)
    out, _ = what_the_eye_sees(white, kernel)
    assert np.isfinite(out).all() and out.max() <= 1.0
    r = kernel.size // 2
    np.testing.assert_allclose(out[r:-r, r:-r], 1.0, atol=1e-5)


def test_nan_and_bad_shapes_are_rejected(kernel):
    img = np.zeros((4, 4, 3))
    img[1, 2, 0] = np.nan
    with pytest.raises(ValidationError, match="NaN"):
        simulate_lms(img, kernel)
    with pytest.raises(ValidationError, match="shape"):
        simulate_lms(np.zeros((4, 4)), kernel)
    with pytest.raises(ValidationError, match="method"):
        simulate_lms(np.zeros((4, 4, 3)), kernel, "magic")


def test_one_pixel_image(kernel):
    img = np.full((1, 1, 3), 0.7)
    for method in ("fft", "direct"):
        out, _ = simulate_lms(img, kernel, method)
        c = kernel.size // 2
        np.testing.assert_allclose(out[0, 0], kernel.kernel[:, :, c, c] @ img[0, 0], atol=1e-12)


@pytest.mark.slow
def test_huge_image(kernel):
    img = np.zeros((4096, 4096, 3), np.float32)
    img[::64, ::64] = 1.0
    out, info = simulate_lms(img, kernel, "fft")
    assert out.shape == img.shape and out.dtype == np.float32
    assert np.isfinite(out).all()
    # light is conserved: impulses 64 px apart, each spread over less than 32 px
    assert kernel.size < 64
    total_in = img[32:-32, 32:-32].sum(axis=(0, 1)) @ kernel.matrix.T
    total_out = out[32:-32, 32:-32].sum(axis=(0, 1))
    np.testing.assert_allclose(total_out, total_in, rtol=1e-3)


@settings(max_examples=25, deadline=None)
@given(img=arrays(np.float64, st.tuples(st.integers(1, 12), st.integers(1, 12), st.just(3)),
                  elements=st.floats(0, 1)),
       scale=st.floats(0, 1))   # the display range: larger values are refused
def test_linearity_and_energy_conservation(kernel, img, scale):
    a, _ = simulate_lms(img, kernel, "direct")
    b, _ = simulate_lms(img * scale, kernel, "direct")
    np.testing.assert_allclose(b, scale * a, atol=1e-9)
    # with enough black padding every photon lands inside: total cone response = A @ total RGB
    r = kernel.size // 2
    padded = np.pad(img, ((r, r), (r, r), (0, 0)))
    out, _ = simulate_lms(padded, kernel, "fft")
    np.testing.assert_allclose(out.sum(axis=(0, 1)), kernel.matrix @ img.sum(axis=(0, 1)), atol=1e-8)
    assert np.all(out >= -1e-9)


def test_blur_grows_with_dioptres():
    """More myopia, less retinal contrast of a fine grating."""
    d = get_display("quest2")
    x = np.arange(96)
    grating = np.repeat(((x // 3) % 2).astype(np.float64)[None, :], 96, axis=0)
    img = np.repeat(grating[..., None], 3, axis=2)
    contrast = []
    for s in (-0.5, -1.0, -2.0, -4.0):
        k = build_kernel(eye(s), d, KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf)))
        seen, _ = what_the_eye_sees(img, k)
        mid = seen[40:56, 30:66, 1]
        contrast.append(mid.max() - mid.min())
    assert all(a > b for a, b in zip(contrast, contrast[1:]))


def test_srgb_round_trip_through_display(kernel):
    d = get_display("quest2")
    codes = np.linspace(0, 1, 256, dtype=np.float32)[None, :, None].repeat(3, axis=2)
    np.testing.assert_allclose(encode(d, decode(d, codes)), codes, atol=1e-6)
