"""The kernel's report (``physics.kernel_report``): what ``build_kernel`` records agrees with the
kernel it describes and with the display's spectra, and ``explain`` says what the fields hold.

Expected values come from the kernel, the spectra or another build, never from the report itself:
the nodes are the kernel's, the nodes left out carry no spectral weight, the counts add up, the
energy held is what the window of a full-field build holds.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from vrcorrect.physics.kernel import STEPS_NM, KernelOptions, build_kernel
from vrcorrect.physics.kernel_report import (PSF_GRID_FITS, PSF_GRID_TOO_LARGE, PSF_OPTION, STEP_FINEST, STEP_FORCED,
                                             STEP_WITHIN_TOLERANCE, explain)
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.physics.perception import INTEGRATION_GRID_NM, normalised_weights
from vrcorrect.physics.sampling import crop_center
from vrcorrect.specs.display import get_display
from vrcorrect.specs.prescription import EyeRx

SMALL_GRID = 1000       # below the 675-1323 the sample eye's wave PSFs need on quest2: the short end is geometric


def eye(s=0.0, c=0.0, a=0.0, pupil=4.0, **kw) -> EyeRx:
    return EyeRx(sphere_D=s, cylinder_D=c, axis_deg=a, pupil_diameter_mm=pupil, **kw)


@pytest.fixture(scope="module")
def quest2():
    return get_display("quest2")


@pytest.fixture(scope="module")
def low(quest2):
    """quest2 seen at 5 pixels per degree: small PSFs, quick kernels."""
    return dataclasses.replace(quest2, pixels_per_degree=5.0)


@pytest.fixture(scope="module")
def mixed(quest2):
    """The bundled sample's right eye on quest2 with a wave-optics grid limit that some nodes exceed."""
    return build_kernel(eye(-3.0, -1.5, 20.0), quest2, KernelOptions(optics=OpticsOptions(max_grid=SMALL_GRID)))


def run_bounds(text: str) -> list[tuple[float, float]]:
    """The runs of a wavelength list in words: ``"500 nm, 520-540 nm"`` -> ``[(500, 500), (520, 540)]``."""
    return [(float(a), float(b or a)) for a, b in re.findall(r"(\d+)(?:-(\d+))? nm", text)]


def named_nodes(text: str, nodes) -> set[float]:
    """The nodes that the runs in ``text`` cover."""
    return {n for n in nodes if any(lo <= n <= hi for lo, hi in run_bounds(text))}


def spectral_weight(display, lam: float, step: int) -> float:
    """The display's spectral weight (all cones and primaries) under the hat of width ``step`` at ``lam``."""
    w = normalised_weights(display.primaries).sum(axis=(0, 1))
    hat = np.clip(1.0 - np.abs(INTEGRATION_GRID_NM - lam) / step, 0.0, None)
    return float((w * hat).sum())


def test_the_nodes_and_psfs_are_the_kernels_and_the_counts_add_up(mixed):
    r, w = mixed.report, mixed.report.wavelength
    assert not r.identity and w is not None
    assert w.nodes_nm == mixed.node_wavelengths_nm and w.step_nm == mixed.wavelength_step_nm
    assert tuple(p.wavelength_nm for p in r.psfs) == w.nodes_nm
    wave = [p for p in r.psfs if p.model == "wave"]
    geometric = [p for p in r.psfs if p.model == "geometric"]
    assert wave and geometric, "the fixture should mix both models"
    assert len(wave) + len(geometric) == len(r.psfs) == len(w.nodes_nm)
    assert w.psfs_computed >= len(w.nodes_nm)
    assert r.kernel_size_px == mixed.size and r.computed_field_px >= mixed.size
    assert r.kernel_size_px % 2 == 1 and r.computed_field_px % 2 == 1
    # each node's model, and why, from its own sampling and the grid limit
    for p in wave:
        assert p.sampling.model == "wave" and p.reason == PSF_GRID_FITS and 0 < p.sampling.grid <= SMALL_GRID
    for p in geometric:
        assert p.sampling.model == "geometric" and p.reason == PSF_GRID_TOO_LARGE
        assert p.sampling.wave_grid_needed > SMALL_GRID and p.sampling.grid == 0
    assert w.max_fft_grid >= max(p.sampling.grid for p in wave)
    assert r.geometric_wavelengths_nm == [p.wavelength_nm for p in geometric]
    assert r.geometric_error_estimate == max(p.sampling.model_error_estimate for p in geometric)
    # the words say the same counts
    text = "\n".join(explain(r))
    assert f"({len(w.nodes_nm)} PSFs over {w.nodes_nm[0]:.0f}-{w.nodes_nm[-1]:.0f} nm" in text
    assert f"({len(geometric)} of {len(r.psfs)} PSFs; " in text
    said = re.search(r"PSF model: geometric optics at (.*?) \(", text).group(1)
    assert named_nodes(said, w.nodes_nm) == {p.wavelength_nm for p in geometric}, said
    said = re.search(r"\(wave optics at (.*?)\)", text).group(1)
    assert named_nodes(said, w.nodes_nm) == {p.wavelength_nm for p in wave}, said


def test_nodes_left_out_have_no_spectral_weight_and_the_rest_do(mixed, quest2):
    w = mixed.report.wavelength
    grid = np.arange(w.nodes_nm[0], w.nodes_nm[-1] + 0.5, w.step_nm)
    assert sorted(w.nodes_nm + w.left_out_nm) == list(grid)           # together: the step's whole grid
    assert not set(w.nodes_nm) & set(w.left_out_nm)
    assert w.left_out_nm, "quest2's spectra have a gap in the 740-760 nm range at a 10 nm step"
    total = normalised_weights(quest2.primaries).sum()
    for lam in w.left_out_nm:
        assert spectral_weight(quest2, lam, w.step_nm) <= 1e-12 * total, lam
    for lam in w.nodes_nm:
        assert spectral_weight(quest2, lam, w.step_nm) > 1e-12 * total, lam
    text = "\n".join(explain(mixed.report))
    said = re.search(r", none at (.*?): no spectral weight there", text).group(1)
    assert [lam for lo, hi in run_bounds(said) for lam in np.arange(lo, hi + 0.5, w.step_nm)] == list(w.left_out_nm)


def test_the_energy_held_is_what_the_window_holds_of_a_full_field_build(quest2):
    e = eye(-3.0, -1.5, 20.0)
    options = KernelOptions(wavelength_step_nm=40)
    k = build_kernel(e, quest2, options)
    full = build_kernel(e, quest2, dataclasses.replace(options, energy_fraction=1.0))
    cones = full.kernel.sum(axis=1)
    held = (crop_center(cones, k.size).sum(axis=(1, 2)) / cones.sum(axis=(1, 2))).min()
    assert k.report.energy_held == pytest.approx(held, abs=1e-9)
    assert k.report.energy_fraction <= k.report.energy_held <= 1.0 + 1e-12
    assert full.report.energy_held == pytest.approx(1.0, abs=1e-12)
    assert full.report.computed_field_px == k.report.computed_field_px


def test_the_step_and_its_reason_follow_the_estimates(quest2, low):
    chosen = build_kernel(eye(-3.0), quest2).report.wavelength
    assert chosen.reason == STEP_WITHIN_TOLERANCE
    steps = [t.step_nm for t in chosen.trials]
    assert steps == list(STEPS_NM[1:len(steps) + 1]) and steps[-1] == chosen.step_nm   # halving from 40 nm
    assert chosen.trials[-1].error_estimate <= chosen.tolerance
    assert all(t.error_estimate > chosen.tolerance for t in chosen.trials[:-1])
    assert chosen.error_estimate == chosen.trials[-1].error_estimate

    forced = build_kernel(eye(-3.0), low, KernelOptions(wavelength_step_nm=20)).report
    assert forced.wavelength.reason == STEP_FORCED and forced.wavelength.step_nm == 20
    assert forced.wavelength.trials == () and forced.wavelength.error_estimate is None
    assert explain(forced)[4].endswith("; 20 nm forced by option")

    # no step is good enough for a tolerance this small: 1 nm, the reference itself
    strict = KernelOptions(wavelength_tolerance=1e-9, optics=OpticsOptions(psf_model="geometric"))
    finest = build_kernel(eye(-3.0), low, strict).report
    w = finest.wavelength
    assert w.reason == STEP_FINEST and w.step_nm == 1
    assert [t.step_nm for t in w.trials] == [40, 20, 10, 5]
    assert all(t.error_estimate > w.tolerance for t in w.trials)
    assert explain(finest)[4].endswith("; 1 nm is the reference itself")
    assert {p.reason for p in finest.psfs} == {PSF_OPTION}
    assert "psf_model option 'geometric'" in explain(finest)[-1]


def test_identity_path_report(low):
    inf = KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf))
    k = build_kernel(eye(0.0, pupil=2.0), low, inf)
    r = k.report
    assert k.identity and r.identity and r.focus.in_focus
    assert r.wavelength is None and r.psfs == () and r.kernel_size_px == k.size == 1
    assert r.computed_field_px is None and r.energy_held == 1.0
    lines = explain(r)
    assert len(lines) == 4 and lines[-1].startswith("identity path: the eye is in focus")

    off = build_kernel(eye(0.0, pupil=2.0), low, dataclasses.replace(inf, identity_path=False, wavelength_step_nm=80))
    assert not off.report.identity and off.report.focus.in_focus and not off.report.identity_path
    assert explain(off.report)[3] == "identity path disabled by option"

    blurred = build_kernel(eye(-2.0, pupil=2.0), low, dataclasses.replace(inf, wavelength_step_nm=80)).report
    assert not blurred.identity and not blurred.focus.in_focus
    assert blurred.focus.worst_meridian_D > blurred.focus.depth_of_focus_D
    assert explain(blurred)[3] == "convolution needed: the eye is out of focus at this display"


def test_viewing_and_accommodation(low):
    """A +1 D eye with 3 D of accommodation at quest2's 1.3 m: it accommodates 1 + 1/1.3 D."""
    e = eye(1.0, accommodation_D=3.0)
    k = build_kernel(e, low, KernelOptions(wavelength_step_nm=80))
    v, f = k.report.viewing, k.report.focus
    assert v.distance_m == low.distance_m and v.vergence_D == pytest.approx(1.0 / low.distance_m)
    assert v.accommodation_used_D == pytest.approx(1.0 + 1.0 / low.distance_m) and v.accommodation_D == 3.0
    assert f.residual.M_D == pytest.approx(0.0, abs=1e-12) and f.residual == k.state.residual
    assert f.reference_wavelength_nm == k.reference_wavelength_nm == 555.0
    assert explain(k.report)[0] == (f"viewing distance {low.distance_m:.2f} m -> vergence {1 / low.distance_m:.2f} D; "
                                    f"accommodation used {1 + 1 / low.distance_m:.2f} of 3.00 D")


def test_explain_words_a_report_changed_by_hand(mixed):
    """explain reads the report alone: change a field and the words follow."""
    r = mixed.report
    w = dataclasses.replace(r.wavelength, left_out_nm=(500.0, 520.0, 530.0, 540.0), psfs_computed=len(r.psfs))
    changed = dataclasses.replace(r, viewing=dataclasses.replace(r.viewing, distance_m=math.inf, vergence_D=0.0),
                                  wavelength=w)
    lines = explain(changed)
    assert lines[0].startswith("viewing distance infinity -> vergence 0.00 D;")
    assert ", none at 500 nm, 520-540 nm: no spectral weight there)" in lines[4]   # no "computed while choosing"
    assert r.wavelength.psfs_computed > len(r.psfs)        # a coarser step's node beyond the kernel's last
    assert f"; {r.wavelength.psfs_computed} PSFs computed while choosing the step)" in explain(r)[4]
    assert lines[1:4] == explain(r)[1:4] and lines[5:] == explain(r)[5:]
