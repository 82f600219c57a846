"""Physics of the eye's optics: Zernike, refraction, chromatic aberration, PSF.

Every expected value here comes from optics, not from running the code:
Zernike orthonormality, the Airy pattern, geometric blur discs, the
optometric sign conventions of docs/architecture.md ('Physics conventions').
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from vrcorrect.plumbing.errors import ModelLimitError, ValidationError
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.physics.psf import psf_pixels
from vrcorrect.physics.refraction import (chromatic_refraction_D, depth_of_focus_D, lca_defocus_D, meridian_power_D,
                                          refractive_state, wavefront_um)
from vrcorrect.physics.sampling import crop_center, energy_size
from vrcorrect.physics.zernike import (osa_index, osa_nm, power_vector_to_zernike_um, wavefront_from_zernike_um,
                                       zernike, zernike_um_to_power_vector)
from vrcorrect.specs.prescription import EyeRx, PowerVector


def eye(s=0.0, c=0.0, a=0.0, pupil=4.0, **kw) -> EyeRx:
    return EyeRx(sphere_D=s, cylinder_D=c, axis_deg=a, pupil_diameter_mm=pupil, **kw)


def moments(psf: np.ndarray) -> tuple[float, float, float, float, float]:
    """Centroid (row, col) and second moments in display axes: x to the right, y up.

    Returns (row_centroid_offset, col_centroid_offset, var_x, var_y, cov_xy).
    """
    n = psf.shape[0]
    c = n // 2
    rows, cols = np.mgrid[:n, :n]
    x = cols - c
    y = c - rows
    total = psf.sum()
    mx, my = (psf * x).sum() / total, (psf * y).sum() / total
    vx = (psf * (x - mx) ** 2).sum() / total
    vy = (psf * (y - my) ** 2).sum() / total
    cxy = (psf * (x - mx) * (y - my)).sum() / total
    return -my, mx, vx, vy, cxy


# ---------------------------------------------------------------- Zernike

def test_osa_index_round_trip_and_known_values():
    assert osa_index(0, 0) == 0
    assert osa_index(2, -2) == 3 and osa_index(2, 0) == 4 and osa_index(2, 2) == 5
    assert osa_index(3, -1) == 7 and osa_index(4, 0) == 12
    for j in range(66):
        n, m = osa_nm(j)
        assert osa_index(n, m) == j


def test_zernike_orthonormal_over_unit_disc():
    # Gauss-Legendre in r (exact for polynomials), uniform in theta (exact for trig of low order).
    nr, nt = 40, 64
    xr, wr = np.polynomial.legendre.leggauss(nr)
    r = (xr + 1) / 2
    wr = wr / 2
    theta = np.arange(nt) * 2 * np.pi / nt
    R, T = np.meshgrid(r, theta, indexing="ij")
    W = (wr * r)[:, None] * np.full(nt, 2 * np.pi / nt)[None, :] / np.pi   # mean over the disc
    js = range(28)
    Z = np.array([zernike(*osa_nm(j), R, T) for j in js])
    gram = np.einsum("iab,jab,ab->ij", Z, Z, W)
    np.testing.assert_allclose(gram, np.eye(len(js)), atol=1e-10)


def test_zernike_known_forms():
    rho = np.array([0.0, 0.5, 1.0])
    theta = np.array([0.3, 0.3, 0.3])
    np.testing.assert_allclose(zernike(2, 0, rho, theta), math.sqrt(3) * (2 * rho ** 2 - 1))
    np.testing.assert_allclose(zernike(2, 2, rho, theta), math.sqrt(6) * rho ** 2 * np.cos(2 * theta))
    np.testing.assert_allclose(zernike(2, -2, rho, theta), math.sqrt(6) * rho ** 2 * np.sin(2 * theta))


@settings(max_examples=60, deadline=None)
@given(M=st.floats(-20, 20), J0=st.floats(-5, 5), J45=st.floats(-5, 5), r=st.floats(0.5, 4.5))
def test_power_vector_zernike_round_trip(M, J0, J45, r):
    pv = PowerVector(M, J0, J45)
    c = power_vector_to_zernike_um(pv, r)
    # docs/architecture.md's formulas ('Physics conventions'), typed here from the spec
    assert c[(2, 0)] == pytest.approx(-M * r * r / (4 * math.sqrt(3)), abs=1e-12)
    assert c[(2, 2)] == pytest.approx(-J0 * r * r / (2 * math.sqrt(6)), abs=1e-12)
    assert c[(2, -2)] == pytest.approx(-J45 * r * r / (2 * math.sqrt(6)), abs=1e-12)
    back = zernike_um_to_power_vector(c, r)
    assert back.M_D == pytest.approx(M, abs=1e-9)
    assert back.J0_D == pytest.approx(J0, abs=1e-9)
    assert back.J45_D == pytest.approx(J45, abs=1e-9)


@settings(max_examples=30, deadline=None)
@given(s=st.floats(-10, 10), c=st.floats(-6, 0), a=st.floats(0, 180), pupil=st.floats(1, 9))
def test_rx_zernike_wavefront_equals_direct_wavefront(s, c, a, pupil):
    """Rx -> Zernike -> wavefront agrees with the closed-form power-vector wavefront (up to piston)."""
    e = eye(s, c, a, pupil)
    pv = e.power_vector()
    r = pupil / 2
    x, y = np.meshgrid(np.linspace(-r, r, 21), np.linspace(-r, r, 21))
    inside = x ** 2 + y ** 2 <= r * r
    direct = wavefront_um(e, pv, x, y)
    via = wavefront_from_zernike_um(power_vector_to_zernike_um(pv, r), r, x, y)
    d = (direct - via)[inside]
    assert np.ptp(d) < 1e-9 * max(1.0, np.abs(direct).max())


def test_meridian_of_cylinder_power_follows_axis():
    """Minus cylinder: no power error along the axis, full cylinder at 90 deg to it."""
    for axis in (0.0, 30.0, 90.0, 135.0):
        pv = eye(-1.0, -2.0, axis).power_vector()
        assert meridian_power_D(pv, axis) == pytest.approx(-1.0, abs=1e-12)
        assert meridian_power_D(pv, axis + 90) == pytest.approx(-3.0, abs=1e-12)


# ---------------------------------------------------------------- refraction

def test_viewing_distance_and_accommodation():
    # A -2 D myope at 0.5 m is in focus.
    st_ = refractive_state(eye(-2.0), 0.5)
    assert st_.residual.M_D == pytest.approx(0.0, abs=1e-12)
    # An emmetrope at 0.5 m needs +2 D: with 1 D of accommodation, 1 D remains.
    st_ = refractive_state(eye(0.0, accommodation_D=1.0), 0.5)
    assert st_.residual.M_D == pytest.approx(1.0) and st_.accommodation_used_D == pytest.approx(1.0)
    # Accommodation never removes negative R (myopia at infinity).
    st_ = refractive_state(eye(-3.0, accommodation_D=5.0), math.inf)
    assert st_.residual.M_D == pytest.approx(-3.0) and st_.accommodation_used_D == 0.0


def test_an_accommodative_lag_leaves_its_share_of_the_demand_as_hyperopic_defocus():
    # An emmetrope at 0.6 m is asked for 1/0.6 = 1.667 D; a lag of 0.75 D at 40 cm (2.5 D) is 0.3 of
    # the demand: it accommodates 1.167 D and is left +0.5 D from focus (the display behind the retina).
    st_ = refractive_state(eye(0.0, accommodation_D=5.0, accommodative_lag_D=0.75), 0.6)
    assert st_.accommodation_used_D == pytest.approx(7.0 / 6.0) and st_.residual.M_D == pytest.approx(0.5)
    # A -1 D myope there is asked for 0.667 D and lags 0.2 D; at 1.3 m (a headset) the emmetrope lags 0.23 D.
    assert refractive_state(eye(-1.0, accommodation_D=5.0, accommodative_lag_D=0.75), 0.6).residual.M_D == \
        pytest.approx(0.2)
    assert refractive_state(eye(0.0, accommodation_D=5.0, accommodative_lag_D=0.75), 1.3).residual.M_D == \
        pytest.approx(0.3 / 1.3)
    # No lag where the eye need not accommodate: a -3 D myope at 0.6 m, or any eye at optical infinity.
    assert refractive_state(eye(-3.0, accommodation_D=5.0, accommodative_lag_D=2.0), 0.6).residual.M_D == \
        pytest.approx(-3.0 + 1.0 / 0.6)
    assert refractive_state(eye(0.0, accommodation_D=5.0, accommodative_lag_D=2.0), math.inf).residual.M_D == 0.0
    # An eye at the end of its amplitude uses all of it, lag or not (a presbyope's 1 D at 0.6 m: +0.667 D left).
    for lag in (0.0, 0.5):
        st_ = refractive_state(eye(0.0, accommodation_D=1.0, accommodative_lag_D=lag), 0.6)
        assert st_.accommodation_used_D == 1.0 and st_.residual.M_D == pytest.approx(2.0 / 3.0)
    # The extremes of the field: 2 D of lag is 0.8 of the demand, and 0 D is the eye without lag.
    assert refractive_state(eye(0.0, accommodation_D=15.0, accommodative_lag_D=2.0), 0.4).residual.M_D == \
        pytest.approx(2.0)
    assert refractive_state(eye(0.0, accommodation_D=15.0, accommodative_lag_D=0.0), 0.4).residual.M_D == 0.0


def test_lca_sign_and_magnitude():
    """Thibos 1992: ~1.2 D between 450 and 650 nm; blue is focused in front (more myopic)."""
    diff = chromatic_refraction_D(650.0) - chromatic_refraction_D(450.0)
    assert 1.1 < diff < 1.35
    assert lca_defocus_D(450.0, 555.0) < 0 < lca_defocus_D(650.0, 555.0)
    assert lca_defocus_D(555.0, 555.0) == 0.0


def test_lca_in_psf_hyperopic_eye_sees_blue_sharper():
    """Blue focused in front of the retina: a +0.75 D (hyperopic) eye is nearly in focus for
    blue and more blurred for red; a -0.75 D (myopic) eye the other way round."""
    ppd = 30.0
    opt = OpticsOptions()
    for sphere, sharper in ((0.75, 450.0), (-0.75, 650.0)):
        e = eye(sphere)
        st_ = refractive_state(e, math.inf)
        var = {}
        for lam in (450.0, 650.0):
            p = psf_pixels(e, st_.at_wavelength(lam, opt), lam, ppd, opt).values
            _, _, vx, vy, _ = moments(crop_center(p, 41))
            var[lam] = vx + vy
        blurrier = 650.0 if sharper == 450.0 else 450.0
        assert var[sharper] < 0.7 * var[blurrier]


# ---------------------------------------------------------------- PSF

def test_psf_sums_to_one_and_is_finite():
    for e in (eye(), eye(-3, -1, 20), eye(2, -0.5, 170, pupil=6)):
        p = psf_pixels(e, e.power_vector(), 550.0, 20.0).values
        assert p.shape[0] % 2 == 1 and p.shape[0] == p.shape[1]
        assert np.all(np.isfinite(p)) and np.all(p >= 0)
        assert p.sum() == pytest.approx(1.0, abs=1e-12)


def test_defocus_psf_centred_and_rotation_invariant():
    e = eye(-2.0)
    p = psf_pixels(e, e.power_vector(), 550.0, 25.0).values
    dr, dc, vx, vy, cxy = moments(p)
    assert abs(dr) < 1e-9 and abs(dc) < 1e-9
    c = p.shape[0] // 2
    assert p[c, c] >= 0.0
    np.testing.assert_allclose(np.rot90(p), p, atol=1e-12 * p.max() + 1e-15)
    assert vx == pytest.approx(vy, rel=1e-9) and abs(cxy) < 1e-9 * vx


def test_no_aberration_at_coarse_pixels_is_a_delta():
    e = eye(0.0, pupil=4.0)
    p = psf_pixels(e, e.power_vector(), 550.0, 5.0).values
    c = p.shape[0] // 2
    assert p[c, c] > 0.97
    assert p[c, c] == p.max()


def test_airy_pattern_first_zero():
    """Unaberrated 1 mm pupil sampled finely: the first dark ring is at 1.22 lambda/D."""
    lam_nm, pupil_mm, ppd = 550.0, 1.0, 500.0
    e = eye(0.0, pupil=pupil_mm)
    p = psf_pixels(e, e.power_vector(), lam_nm, ppd).values
    c = p.shape[0] // 2
    expected_px = math.degrees(1.22 * lam_nm * 1e-9 / (pupil_mm * 1e-3)) * ppd   # ~19.2 px
    # radial profile along the row through the centre, in both directions
    profile = 0.5 * (p[c, c:] + p[c, c::-1])
    lo, hi = int(expected_px * 0.6), int(expected_px * 1.4)
    first_min = lo + int(np.argmin(profile[lo:hi]))
    assert abs(first_min - expected_px) <= 1.0
    assert profile[first_min] < 1e-3 * profile[0]


def test_large_defocus_blur_disc_radius():
    """Geometric optics: blur-disc radius = pupil radius x |defocus| (radians)."""
    ppd, pupil, M = 20.0, 4.0, -8.0
    e = eye(M, pupil=pupil)
    p = psf_pixels(e, e.power_vector(), 550.0, ppd).values
    _, _, vx, vy, _ = moments(p)
    pixel_var = 1.0 / 12.0                        # a pixel's own (box) variance per axis
    radius_px = math.sqrt(2.0 * (vx + vy - 2 * pixel_var))   # uniform disc: <r^2> = a^2 / 2
    expected = math.degrees(pupil / 2 * 1e-3 * abs(M)) * ppd
    assert radius_px == pytest.approx(expected, rel=0.10)


def test_cylinder_axis_orientation_optometric_convention():
    """Minus cylinder -2.00 x 180 (with-the-rule): the vertical meridian is 2 D myopic, so a
    point is smeared vertically; x 90 smears horizontally.  Axes are TABO/ISO 8429 as the
    examiner sees the eye; the subject sees the display mirrored, so x 45 (myopic meridian at
    135 deg, the examiner's upper-left to lower-right) smears along the subject's lower-left to
    upper-right diagonal ('/', positive covariance with x right and y up), and x 135 along '\\'.
    """
    ppd = 20.0
    res = {}
    for axis in (180.0, 90.0, 45.0, 135.0):
        e = eye(0.0, -2.0, axis)
        p = psf_pixels(e, e.power_vector(), 555.0, ppd).values
        res[axis] = moments(p)[2:]
    vx, vy, _ = res[180.0]
    assert vy > 5 * vx                           # vertical smear
    vx, vy, _ = res[90.0]
    assert vx > 5 * vy                           # horizontal smear
    vx, vy, cxy = res[45.0]
    assert cxy > 0.8 * math.sqrt(vx * vy)         # along '/'
    vx, vy, cxy = res[135.0]
    assert cxy < -0.8 * math.sqrt(vx * vy)        # along '\'


@settings(max_examples=12, deadline=None)
@given(s=st.floats(-4, 4), c=st.floats(-3, -0.25), a=st.floats(0, 179))
def test_plus_and_minus_cylinder_forms_give_the_same_psf(s, c, a):
    minus = eye(s, c, a)
    plus = minus.transposed()
    assert plus.cylinder_D > 0
    p1 = psf_pixels(minus, minus.power_vector(), 550.0, 15.0).values
    p2 = psf_pixels(plus, plus.power_vector(), 550.0, 15.0).values
    assert p1.shape == p2.shape
    np.testing.assert_allclose(p1, p2, atol=1e-10)


@pytest.mark.parametrize("case", [("defocused", -3.0, 18.9), ("in focus, 120 ppd", 0.0, 120.0),
                                  ("slight defocus, 45 ppd", -0.25, 45.0)])
def test_results_change_less_than_one_percent_when_sampling_doubles(case):
    _, sphere, ppd = case
    e = eye(sphere)
    base = OpticsOptions()
    finer = OpticsOptions(pupil_padding=2 * base.pupil_padding, oversample=3,
                          min_pupil_samples=2 * base.min_pupil_samples)
    for lam in (450.0, 600.0):
        a = psf_pixels(e, e.power_vector(), lam, ppd, base).values
        b = psf_pixels(e, e.power_vector(), lam, ppd, finer).values
        size = max(a.shape[0], b.shape[0])
        change = np.abs(crop_center(a, size) - crop_center(b, size)).sum()
        assert change < 0.01, f"{lam} nm: L1 change {change:.4f}"


def test_steep_wavefront_refines_pupil_sampling():
    """Coma (OSA j=7) is not in the analytic slope estimate's closed form: the phase check
    still holds, with refinement if needed."""
    from vrcorrect.specs.prescription import HigherOrder

    e = eye(0.0, pupil=6.0, higher_order=HigherOrder(6.0, ((7, 2.0),)))
    p = psf_pixels(e, e.power_vector(), 500.0, 20.0)
    assert p.sampling.max_phase_step_rad < math.pi / 2
    assert np.isfinite(p.values).all() and p.values.sum() == pytest.approx(1.0)
    # coma is odd: the PSF is not centrosymmetric
    assert not np.allclose(p.values, p.values[::-1, ::-1], atol=1e-4)


def test_energy_size_and_crop():
    a = np.zeros((9, 9))
    a[4, 4] = 0.99
    a[4, 6] = 0.01
    assert energy_size(a, 0.98) == 1
    assert energy_size(a, 0.995) == 5
    assert crop_center(a, 5).sum() == pytest.approx(1.0)


def test_depth_of_focus_scales_with_pupil_and_pixels():
    assert depth_of_focus_D(2.0, 20.0) == pytest.approx(2 * depth_of_focus_D(4.0, 20.0))
    # below 60 ppd the pixel sets the limit: coarser pixels -> deeper focus
    assert depth_of_focus_D(4.0, 10.0) == pytest.approx(2 * depth_of_focus_D(4.0, 20.0))
    # above 60 ppd the eye's 1 arcmin acuity sets it
    assert depth_of_focus_D(4.0, 120.0) == pytest.approx(depth_of_focus_D(4.0, 60.0))


@pytest.mark.parametrize("kw", [dict(s=20.0), dict(s=-20.0), dict(c=-8.0, a=30.0), dict(s=-3.0, pupil=1.0),
                                dict(s=-3.0, pupil=8.0)])
def test_extreme_eyes_give_finite_psfs(kw):
    e = eye(**kw)
    p = psf_pixels(e, e.power_vector(), 450.0, 18.9).values
    assert np.isfinite(p).all() and p.min() >= 0 and p.sum() == pytest.approx(1.0)


@pytest.mark.parametrize("ppd", [5.0, 120.0])
def test_extreme_pixel_densities(ppd):
    e = eye(-3.0)
    p = psf_pixels(e, e.power_vector(), 550.0, ppd).values
    assert np.isfinite(p).all() and p.sum() == pytest.approx(1.0)
    expected_radius_px = math.degrees(2e-3 * 3.0) * ppd
    assert p.shape[0] >= 2 * expected_radius_px   # the field holds the blur disc


def test_too_steep_for_wave_optics_switches_to_geometric_optics():
    """-20 D over an 8 mm pupil at 120 ppd needs a pupil grid far beyond the limit: the wave
    model alone refuses it clearly; the default (auto) models it with geometric optics, where the
    blur is many times the diffraction blur (tests/test_optics_geometric.py checks the model)."""
    e = eye(-20.0, pupil=8.0)
    with pytest.raises(ModelLimitError, match="pupil_diameter_mm"):
        psf_pixels(e, e.power_vector(), 400.0, 120.0, OpticsOptions(psf_model="wave"))
    psf = psf_pixels(e, e.power_vector(), 400.0, 120.0)
    assert psf.sampling.model == "geometric" and psf.sampling.model_error_estimate < 0.05
    assert abs(float(psf.values.sum()) - 1.0) < 1e-9 and np.all(np.isfinite(psf.values))


def test_bad_arguments_are_named():
    e = eye()
    with pytest.raises(ValidationError, match="wavelength_nm"):
        psf_pixels(e, e.power_vector(), 100.0, 20.0)
    with pytest.raises(ValidationError, match="pixels_per_degree"):
        psf_pixels(e, e.power_vector(), 550.0, 0.0)
    with pytest.raises(ValidationError, match="oversample"):
        OpticsOptions(oversample=2)
