"""Cones, the RGB->LMS matrix, and the eye's colour kernel."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from vrcorrect.specs.display import get_display
from vrcorrect.physics.kernel import KernelOptions, _kernel_norm, build_kernel, hat_weights, monochromatic_psf
from vrcorrect.physics.kernel_report import explain
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.physics.sampling import crop_center
from vrcorrect.physics.perception import (OPPONENT_MATRIX, from_opponent, normalised_weights,
                                  rgb_to_lms_matrix, to_opponent)
from vrcorrect.specs.prescription import EyeRx

INF = KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf))


def eye(s=0.0, c=0.0, a=0.0, pupil=4.0, **kw) -> EyeRx:
    return EyeRx(sphere_D=s, cylinder_D=c, axis_deg=a, pupil_diameter_mm=pupil, **kw)


@pytest.fixture(scope="module")
def quest2():
    return get_display("quest2")


# ---------------------------------------------------------------- perception

@pytest.mark.parametrize("name,dataset", [("desktop", "Apple Studio Display"), ("crt", "Typical CRT Brainard 1997")])
def test_rgb_to_lms_matrix_equals_direct_integration_of_colour_tables(name, dataset):
    import colour

    cmfs = colour.MSDS_CMFS["Stockman & Sharpe 2 Degree Cone Fundamentals"]
    prim = colour.MSDS_DISPLAY_PRIMARIES[dataset]
    grid = np.arange(390.0, 781.0)
    cones = np.stack([np.interp(grid, cmfs.wavelengths, cmfs.values[:, k], left=0, right=0) for k in range(3)])
    spd = np.stack([np.interp(grid, prim.wavelengths, prim.values[:, c], left=0, right=0) for c in range(3)])
    raw = cones @ spd.T                         # A[k, c] = sum_lambda cone_k spd_c
    expected = raw / raw.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(rgb_to_lms_matrix(get_display(name)), expected, rtol=1e-12, atol=1e-15)


def test_white_maps_to_ones_and_matrix_is_sensible():
    A = rgb_to_lms_matrix(get_display("desktop"))
    np.testing.assert_allclose(A @ np.ones(3), np.ones(3), atol=1e-12)
    # L and M cones are driven mostly by red+green, S mostly by blue
    assert A[2, 2] > 0.8 and A[0, 2] < 0.1 and A[0, 0] > A[1, 0]
    assert np.linalg.cond(A) < 100


def test_opponent_channels_follow_schmidt():
    lms = np.array([[0.2, 0.5, 0.9]])
    o = to_opponent(lms)[0]
    assert o[0] == pytest.approx((0.5 + 0.9) - 0.2)     # (M + S) - L, not (M + S) - M
    assert o[1] == pytest.approx((0.2 + 0.9) - 0.5)
    assert o[2] == pytest.approx((0.2 + 0.5 + 0.9) / 3)
    np.testing.assert_allclose(from_opponent(to_opponent(lms)), lms, atol=1e-12)
    assert OPPONENT_MATRIX.shape == (3, 3)


def test_hat_weights_preserve_the_matrix_at_every_step(quest2):
    w = normalised_weights(quest2.primaries)
    for step in (80, 40, 20, 10, 5, 1):
        nodes, W = hat_weights(w, step)
        np.testing.assert_allclose(W.sum(axis=2), w.sum(axis=2), rtol=1e-12)
        assert np.all(np.diff(nodes) == step) or step == 1 or len(nodes) > 1


# ---------------------------------------------------------------- kernel

@pytest.mark.parametrize("rx", [dict(s=-3.0), dict(s=-1.5, c=-1.0, a=30.0), dict(s=2.0, pupil=6.0)])
def test_kernel_spatial_sums_equal_the_matrix(quest2, rx):
    k = build_kernel(eye(**rx), quest2)
    assert k.kernel.shape[:2] == (3, 3) and k.size % 2 == 1
    np.testing.assert_allclose(k.kernel.sum(axis=(2, 3)), k.matrix, atol=1e-12)
    np.testing.assert_allclose(k.matrix, rgb_to_lms_matrix(quest2), atol=1e-12)
    assert np.all(k.kernel >= 0) and np.isfinite(k.kernel).all()


def test_kernel_size_holds_the_stated_energy(quest2):
    e = eye(-3.0)
    full = build_kernel(e, quest2, KernelOptions(energy_fraction=1.0, wavelength_step_nm=10))
    k = build_kernel(e, quest2, KernelOptions(energy_fraction=0.995, wavelength_step_nm=10))
    cones_full = full.kernel.sum(axis=1)
    inside = crop_center(cones_full, k.size).sum(axis=(1, 2)) / cones_full.sum(axis=(1, 2))
    assert np.all(inside >= 0.995 - 1e-12)
    smaller = crop_center(cones_full, k.size - 2).sum(axis=(1, 2)) / cones_full.sum(axis=(1, 2))
    assert np.any(smaller < 0.995)                 # smallest such size
    assert k.size < full.size


def test_kernel_grows_with_dioptres(quest2):
    sizes = [build_kernel(eye(s), quest2, INF).size for s in (-1.0, -2.0, -4.0)]
    assert sizes[0] < sizes[1] < sizes[2]


def test_chosen_wavelength_step_is_within_tolerance_of_1nm(quest2):
    e = eye(-3.0, -1.0, 20.0)
    full = KernelOptions(energy_fraction=1.0)
    chosen = build_kernel(e, quest2, full)
    assert chosen.wavelength_step_nm in (80, 40, 20, 10, 5)      # model only what is needed
    ref = build_kernel(e, quest2, dataclasses.replace(full, wavelength_step_nm=1))
    size = max(chosen.size, ref.size)
    err = _kernel_norm(crop_center(chosen.kernel, size) - crop_center(ref.kernel, size))
    assert err <= full.wavelength_tolerance
    # and a coarser step would not have been good enough
    coarser = build_kernel(e, quest2, dataclasses.replace(full, wavelength_step_nm=chosen.wavelength_step_nm * 2))
    size = max(coarser.size, ref.size)
    assert _kernel_norm(crop_center(coarser.kernel, size) - crop_center(ref.kernel, size)) > full.wavelength_tolerance


def test_identity_path_for_an_eye_in_focus():
    low = dataclasses.replace(get_display("quest2"), pixels_per_degree=5.0)
    k = build_kernel(eye(0.0, pupil=2.0), low, INF)
    assert k.identity and k.size == 1
    np.testing.assert_allclose(k.kernel[:, :, 0, 0], k.matrix)
    assert any("identity path" in d for d in explain(k.report))
    # the same eye with a real refractive error is not in focus
    k2 = build_kernel(eye(-2.0, pupil=2.0), low, INF)
    assert not k2.identity and k2.size > 1
    # and the identity path can be switched off
    k3 = build_kernel(eye(0.0, pupil=2.0), low, dataclasses.replace(INF, identity_path=False))
    assert not k3.identity


def test_lca_off_removes_colour_dependent_blur(quest2):
    """Without chromatic aberration an emmetrope at infinity is nearly sharp for every cone;
    with it the S cone (blue light, focused in front) is blurred."""
    e = eye(0.0)
    on = build_kernel(e, quest2, INF)
    off = build_kernel(e, quest2, dataclasses.replace(INF, optics=OpticsOptions(
        viewing_distance_m=math.inf, chromatic_aberration=False)))
    def centre_fraction(k, cone):
        kk = k.kernel[cone].sum(axis=0)
        c = kk.shape[0] // 2
        return kk[c, c] / kk.sum()
    assert centre_fraction(on, 2) < centre_fraction(off, 2) - 0.1
    assert off.size <= on.size


def test_decisions_are_explained(quest2):
    k = build_kernel(eye(-3.0), quest2)
    text = "\n".join(explain(k.report))
    for phrase in ("viewing distance", "residual refraction", "depth of focus", "wavelength step",
                   "holds 99.50%", "pupil sampling"):
        assert phrase in text


def test_explain_says_the_lag_and_the_residual_it_leaves(quest2):
    geometric = KernelOptions(optics=OpticsOptions(psf_model="geometric"))
    k = build_kernel(eye(0.0, accommodation_D=5.0, accommodative_lag_D=1.0), quest2, geometric)
    text = "\n".join(explain(k.report))
    # 1/1.3 = 0.769 D asked, 0.4 of it (1 D of lag at 2.5 D) left: +0.31 D, 0.46 D focused
    assert "accommodation used 0.46 of 5.00 D (lag 1.00 D at 40 cm)" in text and "M +0.31 D" in text, text
    assert "lag" not in "\n".join(explain(build_kernel(eye(0.0, accommodation_D=5.0), quest2, geometric).report))


def test_explain_counts_the_kernels_psfs_in_every_line(quest2):
    """Issue 26: the step line counted the kernel's PSFs ("20 PSFs"), the PSF-model line every PSF
    computed while the step was chosen, coarser steps' nodes included ("21 of 21")."""
    geometric = KernelOptions(optics=OpticsOptions(psf_model="geometric"))    # quick, and the line has a count
    k = build_kernel(eye(-3.0, -1.5, 20.0), quest2, geometric)
    text = "\n".join(explain(k.report))
    n = len(k.node_wavelengths_nm)
    assert k.report.wavelength.psfs_computed > n                 # the adaptive step computed nodes the kernel skips
    assert int(re.search(r"\((\d+) PSFs over", text).group(1)) == n, text
    model = re.search(r"\((\d+) of (\d+) PSFs", text)
    assert model and int(model.group(1)) == int(model.group(2)) == n, text   # every one of them geometric
    assert str(k.report.wavelength.psfs_computed) in text        # the work done is still told, as such


def test_headset_distance_shifts_the_residual(quest2):
    k = build_kernel(eye(-3.0), quest2)
    assert k.state.residual.M_D == pytest.approx(-3.0 + 1.0 / quest2.distance_m)
    k_inf = build_kernel(eye(-3.0), quest2, INF)
    assert k_inf.state.residual.M_D == pytest.approx(-3.0)


def test_monochromatic_psf_is_cropped_and_normalised(quest2):
    psf, full, state = monochromatic_psf(eye(-2.0), quest2, 550.0)
    assert psf.sum() == pytest.approx(1.0) and psf.shape[0] % 2 == 1
    assert psf.shape[0] <= full.size


@pytest.mark.slow
@pytest.mark.parametrize("rx,ppd", [(dict(s=20.0), None), (dict(s=-20.0), None), (dict(c=-8.0, a=60.0), None),
                                    (dict(s=-3.0, pupil=1.0), None), (dict(s=-3.0, pupil=8.0), None),
                                    (dict(s=-3.0), 5.0), (dict(s=-3.0), 120.0)])
def test_extreme_kernels_are_finite_and_exact_sums(rx, ppd):
    d = get_display("quest2")
    if ppd:
        d = dataclasses.replace(d, pixels_per_degree=ppd)
    k = build_kernel(eye(**rx), d, KernelOptions(wavelength_step_nm=40 if abs(rx.get("s", 0)) >= 20 else None))
    assert np.isfinite(k.kernel).all() and k.kernel.min() >= 0
    np.testing.assert_allclose(k.kernel.sum(axis=(2, 3)), k.matrix, atol=1e-12)
