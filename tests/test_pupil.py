"""The eye as it is: the viewing pupil from the light (Watson & Yellott), its dynamics, the pupil bank's
entries and switching, the robust design's effective kernel, and the real-time path following the
light on a real headless GL context (Mesa llvmpipe in CI) against its CPU twin."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.physics.pupil import (FORMULA_AGE_RANGE, PUPIL_RANGE_MM, PupilDynamics, check_pupil_mm, field_area_deg2,
                                     pupil_from_light, stanley_davies_mm, unified_pupil_mm)
from vrcorrect.physics.robust import RobustBand, design_eye
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.runtime.pupil_bank import (BANK_PUPILS_MM, BANK_REACH_STEPS, BANK_STEP, HYSTERESIS, PupilFollower,
                                          bank_grid_kernel_size, bank_pupils, bank_reach_mm, nearest_bank_pupil,
                                          relative_luminance_of)
from vrcorrect.solvers import make_problem, objective, solve
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx, HigherOrder, Prescription
from vrcorrect.vision.forward import simulate_lms

EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
QUEST2 = get_display("quest2")
DESKTOP = get_display("desktop")


# ------------------------------------------------------------------ the formula


def test_stanley_davies_core_by_hand():
    """D = 7.75 - 5.75 f / (f + 2), f = (F / 846)^0.41: at F = 846, f = 1 and D = 7.75 - 5.75 / 3; in the
    dark, 7.75 mm; at F = 846 * 2^(1/0.41), f = 2 and D = 7.75 - 5.75 / 2."""
    assert stanley_davies_mm(846.0) == pytest.approx(7.75 - 5.75 / 3.0, abs=1e-12)
    assert stanley_davies_mm(0.0) == pytest.approx(7.75, abs=1e-12)
    assert stanley_davies_mm(846.0 * 2.0 ** (1 / 0.41)) == pytest.approx(7.75 - 5.75 / 2.0, abs=1e-12)


@pytest.mark.parametrize("luminance, expected", [(10.0, 3.4), (50.0, 2.9), (100.0, 2.7)])
def test_a_headset_field_gives_the_pupils_of_the_literature(luminance, expected):
    """A full headset field (about 6000 deg^2) at 10 / 50 / 100 cd/m^2: about 3.4 / 2.9 / 2.7 mm (the
    issue's table, from Watson & Yellott 2012)."""
    d, notes = unified_pupil_mm(luminance, 6000.0)
    assert d == pytest.approx(expected, abs=0.1)
    assert notes == ()


def test_the_pupil_narrows_with_light_and_widens_with_one_eye():
    values = [unified_pupil_mm(lum, 1800.0)[0] for lum in (0.1, 1.0, 10.0, 100.0, 1000.0)]
    assert all(a > b for a, b in zip(values, values[1:]))
    assert unified_pupil_mm(50.0, 1800.0, eyes=1)[0] > unified_pupil_mm(50.0, 1800.0, eyes=2)[0] + 0.2


@pytest.mark.parametrize("age, held", [(10.0, FORMULA_AGE_RANGE[0]), (90.0, FORMULA_AGE_RANGE[1])])
def test_ages_outside_the_fitted_range_are_held_with_a_note(age, held):
    d, notes = unified_pupil_mm(50.0, 6000.0, age_years=age)
    assert d == pytest.approx(unified_pupil_mm(50.0, 6000.0, age_years=held)[0], abs=1e-12)
    assert len(notes) == 1 and f"taken as {held:g}" in notes[0]


def test_age_moves_the_pupil_as_the_formula_says():
    """At the reference age 28.58 the age term is zero; older eyes have smaller pupils, by
    (y - 28.58)(0.02132 - 0.009562 D) mm."""
    base = unified_pupil_mm(20.0, 6000.0)[0]
    assert unified_pupil_mm(20.0, 6000.0, age_years=28.58)[0] == pytest.approx(base, abs=1e-12)
    assert unified_pupil_mm(20.0, 6000.0, age_years=70.0)[0] == pytest.approx(
        base + (70.0 - 28.58) * (0.02132 - 0.009562 * base), abs=1e-12)
    assert unified_pupil_mm(20.0, 6000.0, age_years=70.0)[0] < base


def test_a_black_frame_is_held_at_the_largest_pupil_and_a_white_one_narrows_it():
    black = pupil_from_light(0.0, QUEST2)
    assert black.formula_mm == pytest.approx(7.75)
    assert black.diameter_mm == PUPIL_RANGE_MM[1]
    assert any("held at 7.5" in n for n in black.notes)
    white = pupil_from_light(1.0, DESKTOP)
    assert PUPIL_RANGE_MM[0] < white.diameter_mm < 3.2 and white.notes == ()
    assert pupil_from_light(1.0, QUEST2).diameter_mm < pupil_from_light(0.1, QUEST2).diameter_mm


def test_the_field_is_the_display_and_a_pupil_beyond_measured_terms_is_held():
    assert field_area_deg2(DESKTOP) == pytest.approx((2560 / DESKTOP.pixels_per_degree) *
                                                     (1440 / DESKTOP.pixels_per_degree))
    held = pupil_from_light(0.01, QUEST2, upper_mm=4.5, upper_why="measured")
    assert held.diameter_mm == 4.5 and any("held at 4.5" in n for n in held.notes)


@pytest.mark.parametrize("value", [1.5, 8.0, 7.51, 1.99, float("nan"), "abc", True, None])
def test_a_fixed_pupil_outside_the_range_is_refused(value):
    with pytest.raises(ValidationError) as e:
        check_pupil_mm(value)
    assert "--pupil" in str(e.value) and "2 to 7.5 mm" in str(e.value)


def test_a_fixed_pupil_inside_the_range_is_taken():
    assert check_pupil_mm("2") == 2.0 and check_pupil_mm(7.5) == 7.5


# ------------------------------------------------------------------ dynamics and the bank


def test_the_pupil_constricts_within_half_a_second_and_dilates_over_seconds():
    fast = PupilDynamics()
    fast.update(6.0, 0.0)
    for _ in range(45):                               # 0.5 s at 90 Hz
        d = fast.update(3.0, 1 / 90)
    assert d - 3.0 <= 0.05 * 3.0
    slow = PupilDynamics()
    slow.update(3.0, 0.0)
    for _ in range(90):                               # 1 s
        d = slow.update(6.0, 1 / 90)
    assert 6.0 - d >= 0.4 * 3.0


def test_the_bank_is_a_geometric_ladder_whose_band_lands_on_entries():
    assert bank_pupils() == BANK_PUPILS_MM
    assert BANK_PUPILS_MM[0] == PUPIL_RANGE_MM[0] and BANK_PUPILS_MM[-1] == PUPIL_RANGE_MM[1]
    for a, b in zip(BANK_PUPILS_MM[3:-1], BANK_PUPILS_MM[:-4]):
        assert a / b == pytest.approx(1.25, rel=1e-3)
    assert nearest_bank_pupil(3.1) == pytest.approx(3.125)
    assert nearest_bank_pupil(6.9, upper_mm=5.0) == pytest.approx(4.8828)


def test_closing_a_bank_stops_the_design_in_progress_and_waits_for_its_worker():
    """A design on the worker is stopped at its next kernel once the bank closes, and close() returns
    with the worker ended: no thread is left inside a C extension at the interpreter's exit (which
    aborts the process: 'terminate called without an active exception')."""
    import threading
    import time

    from vrcorrect.runtime.pupil_bank import PupilBank

    started, kernels_done = threading.Event(), []

    def build(pupil_mm, kernels, grids, progress):
        started.set()
        for k in range(1000):                        # a design of many kernels, 10 ms each
            time.sleep(0.01)
            kernels_done.append(k)
            if progress is not None:
                progress(k + 1, 1000)
        return object()

    eye = EyeRx(-2.0, -1.0, 120.0, 4.0)
    bank = PupilBank(eye, get_display("quest2"), None, None, build)
    for p in BANK_PUPILS_MM[:4]:
        bank.request(p)
    assert started.wait(10)
    worker = bank._worker
    assert worker is not None and not worker.daemon
    bank.close()
    assert not worker.is_alive()
    assert len(kernels_done) < 1000                  # stopped part-way, and the queued designs never began
    assert all(bank.get(p) is None for p in BANK_PUPILS_MM[:4])
    assert bank.build_now(BANK_PUPILS_MM[0]) is not None   # the caller's own thread still designs


def test_the_follower_switches_entries_with_hysteresis():
    f = PupilFollower(QUEST2, entry_mm=3.125)
    step = math.log(BANK_STEP)
    mid = 3.125 * math.exp(step / 2)                  # between 3.125 and 3.3663
    f.dynamics.diameter_mm = mid * math.exp(0.5 * HYSTERESIS * step)     # past the midpoint, not by enough
    lum = _luminance_for(f.dynamics.diameter_mm)
    f.dynamics.constrict_s = f.dynamics.dilate_s = 1e-9                  # follow the light at once
    assert f.update(lum, 1.0) == pytest.approx(3.125)
    lum = _luminance_for(mid * math.exp(1.5 * HYSTERESIS * step))
    assert f.update(lum, 1.0) == pytest.approx(3.3663)


def test_the_reach_is_six_entries_above_the_first_design_and_ends_at_the_bank():
    assert BANK_REACH_STEPS == 6
    assert bank_reach_mm(3.125) == pytest.approx(4.8828)            # x1.25^2
    assert bank_reach_mm(2.0) == pytest.approx(3.125)
    assert bank_reach_mm(3.05) == pytest.approx(4.8828)             # 3.05 is nearest the 3.125 entry
    assert bank_reach_mm(6.5748) == pytest.approx(7.5) and bank_reach_mm(7.5) == pytest.approx(7.5)


def test_the_grids_hold_the_reach_and_less_than_the_whole_bank():
    """A robust design at 3.125 mm: grids for its reach (4.88 mm) hold a smaller kernel than grids for
    7.5 mm, and still the reach's own design (built, not extrapolated)."""
    design = design_eye(EYE, QUEST2, 3.125, robust=True)
    reach = bank_grid_kernel_size(design, bank_reach_mm(3.125))
    whole = bank_grid_kernel_size(design)
    assert reach < whole
    top = design_eye(EYE, QUEST2, bank_reach_mm(3.125), robust=True)
    assert top.kernel.size <= reach, (top.kernel.size, reach)


def test_the_follower_stays_within_the_reach_and_says_so():
    """A black frame asks for the 7.5 mm pupil; with the grids' reach at 4.88 mm the entry stops there
    and the notes say the design is the reach's, not the pupil's; within the reach it is unchanged."""
    f = PupilFollower(QUEST2, entry_mm=3.125, reach_mm=bank_reach_mm(3.125))
    f.dynamics.constrict_s = f.dynamics.dilate_s = 1e-9
    assert f.update(0.0, 1.0) == pytest.approx(4.8828)
    assert any("the grids' reach" in n and "7.50 mm" in n for n in f.notes), f.notes
    assert f.held_at_reach
    assert f.update(_luminance_for(3.9063), 1.0) == pytest.approx(3.9063)
    assert not any("reach" in n for n in f.notes)
    assert not f.held_at_reach
    free = PupilFollower(QUEST2, entry_mm=3.125)
    free.dynamics.constrict_s = free.dynamics.dilate_s = 1e-9
    assert free.update(0.0, 1.0) == pytest.approx(7.5)
    assert not free.held_at_reach


def _luminance_for(pupil_mm: float) -> float:
    """The mean relative luminance whose light-adapted pupil on quest2 is ``pupil_mm`` (bisection)."""
    lo, hi = 1e-6, 10.0
    for _ in range(100):
        mid = math.sqrt(lo * hi)
        if pupil_from_light(mid, QUEST2).formula_mm > pupil_mm:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


# ------------------------------------------------------------------ the robust design


@pytest.fixture(scope="module")
def design():
    return design_eye(EYE, QUEST2, 3.0)


def test_the_effective_kernel_keeps_the_white_and_the_band(design):
    """U(0) = R(0) (a flat field in the gamut is shown unchanged), U(0)^T U(0) = A^T A (the floor aside);
    the default band's three members at one pupil a bank step below the estimate (3.0 x 0.928 mm),
    weights summing to 1, the eye as modelled weighted most, a sharper eye (less myopic) above a
    blurrier one; a band of pupils, given, has its nine members, a smaller pupil above a larger."""
    U, R, A = design.kernel.kernel, design.reference.kernel, design.nominal.matrix
    assert np.allclose(U.sum(axis=(2, 3)), R.sum(axis=(2, 3)), atol=1e-12)
    assert np.allclose(U.sum(axis=(2, 3)).T @ U.sum(axis=(2, 3)), A.T @ A, atol=2e-4 * np.linalg.norm(A, 2) ** 2)
    assert len(design.members) == 3 and design.pupil_mm == 3.0
    assert all(m.pupil_mm == pytest.approx(3.0 * 1.25 ** (-1 / 3), abs=1e-4) for m in design.members)
    w = {m.sphere_offset_D: m.weight for m in design.members}
    assert sum(w.values()) == pytest.approx(1.0)
    assert max(w, key=w.get) == 0.0
    assert EYE.sphere_D < 0 and w[0.25] > w[-0.25]
    band = RobustBand((0.8, 1.0, 1.25), (-0.25, 0.0, 0.25), (1.0, 2.0, 1.0), (1.0, 2.0, 1.0))
    wide = design_eye(EYE, QUEST2, 3.0, band=band)
    assert len(wide.members) == 9
    w = {(round(m.pupil_mm, 3), m.sphere_offset_D): m.weight for m in wide.members}
    assert sum(w.values()) == pytest.approx(1.0)
    assert max(w, key=w.get) == (3.0, 0.0)
    assert w[(2.4, 0.0)] > w[(3.75, 0.0)]
    assert max(w.values()) / min(w.values()) <= 20.0


def test_off_is_the_one_eye_as_today():
    one = design_eye(EYE, QUEST2, 3.0, robust=False)
    direct = build_kernel(EYE.with_changes(pupil_diameter_mm=3.0), QUEST2)
    assert not one.robust and np.array_equal(one.kernel.kernel, direct.kernel)
    assert np.array_equal(one.reference.kernel, build_reference_kernel(EYE.with_changes(pupil_diameter_mm=3.0),
                                                                       QUEST2).kernel)


def test_the_effective_form_differs_from_the_expectation_by_a_constant(design):
    """Without the crop, ||U x - R t||^2 and sum_i w_i ||K_i x - K_ref,i t||^2 (every output pixel of
    the linear convolutions) differ by a constant in x (the window and the floor aside): for a
    photograph ``t``, the uncorrected ``x = t`` and the correction ``fast`` finds give the same
    difference to 2 % of the expectation's gain between them."""
    t = decode(QUEST2, bundled_images(48)[0][1]).astype(np.float64)
    x1 = t
    x2 = solve(make_design_problem(t.astype(np.float32), design), "fast").image.astype(np.float64)

    def conv(image, kernel):
        from scipy.signal import fftconvolve

        return np.stack([sum(fftconvolve(image[..., c], kernel[k, c]) for c in range(3)) for k in range(3)], -1)

    def expectation(x):
        total = 0.0
        for m in design.members:
            k, r = design.member_kernels(m)
            a, b = conv(x, k.kernel), conv(t, r.kernel)
            size = max(a.shape[0], b.shape[0])
            total += m.weight * float(((_pad(a, size) - _pad(b, size)) ** 2).sum())
        return total

    def effective(x):
        a, b = conv(x, design.kernel.kernel), conv(t, design.reference.kernel)
        size = max(a.shape[0], b.shape[0])
        return float(((_pad(a, size) - _pad(b, size)) ** 2).sum())

    e1, e2 = expectation(x1), expectation(x2)
    d1, d2 = e1 - effective(x1), e2 - effective(x2)
    assert e2 < e1
    assert abs(d1 - d2) <= 0.02 * abs(e1 - e2)


def _pad(a: np.ndarray, size: int) -> np.ndarray:
    p = (size - a.shape[0]) // 2
    return np.pad(a, ((p, p), (p, p), (0, 0)))


def test_a_robust_problems_objective_is_the_expectation(design):
    img = decode(QUEST2, bundled_images(48)[0][1]).astype(np.float32)
    problem = make_design_problem(img, design)
    x = solve(problem, "fast").image
    by_hand = 0.0
    for m in design.members:
        k, r = design.member_kernels(m)
        d = simulate_lms(x, k)[0].astype(np.float64) - simulate_lms(img, r)[0].astype(np.float64)
        by_hand += m.weight * float(np.mean(d * d))
    assert objective(x, problem) == pytest.approx(by_hand, rel=1e-4)
    assert objective(x, problem) < objective(img, problem)


def test_a_flat_field_is_no_further_from_flat_than_with_the_one_eyes_design(design):
    """No tint from the effective kernels: a flat field in the gamut (160 px) comes back as near to flat
    at its centre (four of the eye's kernel widths from the edge) as the one eye's design brings it (the black
    surround's pull on the edges carries a few code values inward in both: docs/realtime.md), to one
    code value."""
    flat = np.empty((160, 160, 3), np.float32)
    flat[...] = decode("srgb", np.array([200, 240, 220], np.float32) / 255)
    one = design_eye(EYE, QUEST2, 3.0, robust=False)
    m = 4 * design.nominal.size
    inside = (slice(m, 160 - m), slice(m, 160 - m))

    def codes(x):
        from vrcorrect.specs.display import encode

        return np.round(encode("srgb", np.clip(x, 0, 1)) * 255)

    want = codes(flat)[inside]
    robust = np.abs(codes(solve(make_design_problem(flat, design), "fast", tolerance=1e-4).image)[inside] - want)
    single = np.abs(codes(solve(make_problem(flat, one.kernel, one.reference), "fast", tolerance=1e-4).image)[inside]
                    - want)
    assert robust.max() <= single.max() + 1


def test_a_band_pupil_is_held_below_the_measured_higher_order_pupil():
    eye = EYE.with_changes(pupil_diameter_mm=3.0, higher_order=HigherOrder(4.0, {7: 0.05}))
    d = design_eye(eye, QUEST2, 3.6, band=RobustBand((0.8, 1.0, 1.25), (0.0,), None, None))
    assert max(m.pupil_mm for m in d.members) == pytest.approx(4.0)
    assert any("held at 4 mm" in n for n in d.notes)


# ------------------------------------------------------------------ the command line


@pytest.mark.parametrize("value", ["1.5", "8"])
def test_simulate_refuses_pupils_outside_the_range(tmp_path, value):
    from vrcorrect.plumbing.fileio import package_data

    out = tmp_path / "seen.png"
    r = subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli", "simulate", str(package_data("sample.png")), "-o",
                        str(out), "--pupil", value], capture_output=True, text=True)
    assert r.returncode == 2 and "--pupil" in r.stderr and "2 to 7.5 mm" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


# ------------------------------------------------------------------ real time, on GL


W, H = 56, 40


def _frames():
    big = np.round(bundled_images(96)[0][1][:H, :W] * 255).astype(np.uint8)
    return (big * 0.08).astype(np.uint8), big


def test_a_frames_code_values_are_measured_as_its_decoded_light():
    """``codes_luminance``: 8-bit and float code values of one frame measure the same light, the
    alpha left out, floats held in [0, 1]; white is 1 and black 0."""
    from vrcorrect.runtime.pupil_bank import codes_luminance

    rng = np.random.default_rng(3)
    u8 = rng.integers(0, 256, (12, 10, 4), dtype=np.uint8)
    want = relative_luminance_of(decode(QUEST2, u8[..., :3].astype(np.float32) / 255), QUEST2)
    assert codes_luminance(u8, QUEST2) == pytest.approx(want, rel=1e-6)
    assert codes_luminance(u8[..., :3].astype(np.float32) / 255, QUEST2) == pytest.approx(want, rel=1e-6)
    assert codes_luminance(np.full((2, 2, 3), 255, np.uint8), QUEST2) == pytest.approx(1.0, abs=1e-6)
    assert codes_luminance(np.full((2, 2, 3), 1.7, np.float32), QUEST2) == pytest.approx(1.0, abs=1e-6)
    assert codes_luminance(np.zeros((2, 2, 3), np.uint8), QUEST2) == 0.0


def test_the_gpu_measures_the_frames_light_two_frames_late(gl):
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    dark, bright = _frames()
    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=False,
                  precision="single")
    src = G.upload_texture(gl, dark)
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        c.apply(src, fbo)
        assert c._pupil.meter.latest() is None
        G.write_texture(src, bright)
        c.apply(src, fbo)
        want = relative_luminance_of(decode("srgb", dark.astype(np.float32) / 255), QUEST2)
        assert c._pupil.meter.latest() == pytest.approx(want, rel=1e-4)
        c.apply(src, fbo)
        want = relative_luminance_of(decode("srgb", bright.astype(np.float32) / 255), QUEST2)
        assert c._pupil.meter.latest() == pytest.approx(want, rel=1e-4)
        assert "auto:" in c.pupil_status
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_a_black_and_a_white_frame_are_corrected_and_the_pupil_follows(gl):
    """Extremes: a black frame holds the pupil at 7.5 mm (said in the status), a white one narrows it;
    every output is finite (the bank builds off the render thread; nothing here waits for it)."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=False)
    src = G.upload_texture(gl, np.zeros((H, W, 3), np.uint8))
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        for _ in range(4):
            c.apply(src, fbo)
        out = G.read_framebuffer(fbo)
        assert out.max() == 0
        assert c._pupil.follower.estimate.diameter_mm == PUPIL_RANGE_MM[1]
        assert any("held at 7.5" in n for n in c._pupil.follower.notes)
        G.write_texture(src, np.full((H, W, 3), 255, np.uint8))
        for _ in range(4):
            c.apply(src, fbo)
        assert G.read_framebuffer(fbo)[10:-10, 10:-10].min() >= 250
        assert c._pupil.follower.estimate.diameter_mm < 3.0
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_a_dark_scene_is_designed_at_the_reach_and_switched_without_a_cold_start(gl):
    """A bright first frame, then black ones (the pupil following at once, the bank designing on this
    thread as a batch render does): the design climbs to the grids' reach and no further, every switch
    keeps the strategy (its grids and state), and the status reports a pupil above the design."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    _, bright = _frames()
    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=False,
                  first_luminance=relative_luminance_of(decode("srgb", bright.astype(np.float32) / 255), QUEST2))
    c.frame_time_s = 1 / 90
    c._pupil.follower.dynamics.constrict_s = c._pupil.follower.dynamics.dilate_s = 1e-9
    first, strategy = c.model.pupil_mm, c.strategy
    assert c.model.reach_mm == pytest.approx(bank_reach_mm(first)) and c.model.reach_mm > first
    src = G.upload_texture(gl, np.zeros((H, W, 3), np.uint8))
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        for _ in range(8):
            c.apply(src, fbo)
        assert c.model.pupil_mm == pytest.approx(c.model.reach_mm) and c._pupil.switches >= 1
        assert c.strategy is strategy                               # switched, never installed anew
        assert c._pupil.follower.pupil_mm > c.model.reach_mm + 1.0
        assert np.isfinite(c.solution((W, H))).all()
        assert f"design {c.model.reach_mm:.2f} mm (the grids reach no further)" in c.pupil_status, c.pupil_status
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_a_dark_first_frame_keeps_the_grids_of_a_mid_grey_start():
    """A fade from black: the first frame's light asks for the largest pupil, but the first design and
    the grids' reach stop at a mid-grey frame's reach (not 7.5 mm for the whole run); a bright first
    frame keeps its own, smaller, reach."""
    from vrcorrect.runtime.eye_model import CorrectorOptions, auto_reach_mm, initial_pupil_mm

    auto = CorrectorOptions(pupil="auto")
    neutral = initial_pupil_mm(EYE, QUEST2, auto)
    assert neutral == pytest.approx(3.125)
    dark = initial_pupil_mm(EYE, QUEST2, auto, 0.0)
    assert dark == pytest.approx(bank_reach_mm(neutral)) and dark < max(BANK_PUPILS_MM)
    assert auto_reach_mm(EYE, QUEST2, auto, dark) == pytest.approx(bank_reach_mm(neutral))
    bright = initial_pupil_mm(EYE, QUEST2, auto, 1.0)
    assert bright < neutral and auto_reach_mm(EYE, QUEST2, auto, bright) == pytest.approx(bank_reach_mm(bright))
    assert initial_pupil_mm(EYE, QUEST2, CorrectorOptions(pupil="auto", age_years=10.0), 0.0) == pytest.approx(
        bank_reach_mm(initial_pupil_mm(EYE, QUEST2, CorrectorOptions(pupil="auto", age_years=10.0))))


def test_a_corrector_whose_first_frame_is_black_follows_within_the_mid_grey_reach(gl):
    """``render`` of a clip that fades in from black: the first design is held at the reach and the
    status says so from the first measured frame; its grids are those of a mid-grey start."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=False,
                  first_luminance=0.0)
    grey = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=False)
    c.frame_time_s = 1 / 90
    src = G.upload_texture(gl, np.zeros((H, W, 3), np.uint8))
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        assert c.model.pupil_mm == pytest.approx(bank_reach_mm(grey.model.pupil_mm))
        assert c.model.reach_mm == pytest.approx(grey.model.reach_mm)
        assert c.model.grid_kernel_size <= grey.model.grid_kernel_size * 1.02, \
            (c.model.grid_kernel_size, grey.model.grid_kernel_size)
        for _ in range(4):
            c.apply(src, fbo)
        assert "(the grids reach no further)" in c.pupil_status, c.pupil_status
        assert c.model.pupil_mm == pytest.approx(c.model.reach_mm)
    finally:
        c.release()
        grey.release()
        G.release(fbo, tex, src)


def test_the_gpu_equals_its_twin_across_pupil_switches(gl):
    """A dark clip cut to a bright one through the robust real-time default with the pupil from the
    light (single precision, the frame time of 90 Hz): the pupil constricts and the correction
    switches designs (at least twice) without a cold start; every frame the GPU's solution equals the
    CPU twin's, which switches its design at the same frames (``AdmmFrames.set_design``), to 1e-5."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.solvers.realtime import AdmmFrames

    dark, bright = _frames()
    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=True,
                  precision="single", early_stop=False, first_luminance=relative_luminance_of(
                      decode("srgb", dark.astype(np.float32) / 255), QUEST2))
    c.frame_time_s = 1 / 90
    twin = AdmmFrames(c.model.kernel, c.model.reference, (H, W), precision="single",
                      grid_kernel_size=c.model.grid_kernel_size, cap=True)
    src = G.upload_texture(gl, dark)
    tex, fbo = G.render_target(gl, width=W, height=H)
    designs = [c.model.pupil_mm]
    try:
        for f in range(30):
            image = dark if f < 6 else bright
            G.write_texture(src, image)
            before = c.model
            c.apply(src, fbo)
            if c.model is not before:
                twin.set_design(c.model.kernel, c.model.reference)
                designs.append(c.model.pupil_mm)
            cpu = twin.frame(decode("srgb", image.astype(np.float32) / 255).astype(np.float32), 2)
            assert np.abs(c.solution((W, H)) - cpu.solution).max() <= 1e-5, f
        assert len(designs) >= 3 and designs[-1] < designs[0]
        assert c._pupil.switches == len(designs) - 1
    finally:
        c.release()
        G.release(fbo, tex, src)


@pytest.mark.parametrize("options", [{"filter": "fft"}, {"filter": "separable"}, {"filter": "fista"},
                                     {"fovea_deg": 0.8}], ids=["fft", "separable", "fista", "fovea"])
def test_a_switch_that_installs_a_new_strategy_corrects_the_frame_it_happens_in(gl, options):
    """The filters and a fovea with its periphery (the default) have no ``swap_model`` that takes the
    switch: the bank's switch installs a new strategy in the middle of a frame, which releases the old
    one's texture the frame was decoded into; the frame is decoded again and corrected (``apply``) or
    simulated (``simulate``) with the new design, never a released texture (``vrcorrect mirror
    --filter fft`` failed so on its first switch; with ``--fovea`` the new strategy had decoded nothing
    and failed on that)."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    light = np.full((H, W, 3), 230, np.uint8)                # brighter than the mid-grey start: the pupil narrows
    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=False, **options)
    c.frame_time_s = 1 / 30                              # deterministic: each switch's design is made at once
    src = G.upload_texture(gl, light)
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        for run, want, codes in ((c.simulate, 1, 230), (c.apply, 2, 20)):    # narrows, then widens in the dark
            G.write_texture(src, np.full((H, W, 3), codes, np.uint8))
            for _ in range(300):
                strategy = c.strategy
                run(src, fbo)
                if c.strategy is not strategy:
                    break
            assert c._pupil.switches == want and c.model.pupil_mm == c._pupil.current
            assert np.isfinite(G.read_framebuffer(fbo).astype(np.float32)).all()
        c.apply(src, fbo)                                # and the frame after the switch
        assert np.abs(G.read_framebuffer(fbo).astype(np.float32)[..., :3] - 20).mean() < 10
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_priming_switches_to_the_lights_design_at_once_and_a_second_run_takes_it_from_the_cache(gl, tmp_path):
    """The OpenXR layer's priming (``Corrector.follow_light_now``): the frame just corrected is read now,
    not two frames late, and the design for its light is made on the bank's worker and switched to
    before any application frame; kept in the design cache (``keep_pupil_designs``), a second
    Corrector takes it from there instead of designing it again.  A fixed pupil has nothing to follow."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    light = np.full((H, W, 3), 230, np.uint8)            # brighter than the mid-grey frame designed for first
    want = nearest_bank_pupil(pupil_from_light(
        relative_luminance_of(decode("srgb", light.astype(np.float32) / 255), QUEST2), QUEST2).diameter_mm)
    env = {"VRCORRECT_CACHE_DIR": str(tmp_path)}
    src = G.upload_texture(gl, light)
    tex, fbo = G.render_target(gl, width=W, height=H)
    stamps = []
    try:
        for _ in range(2):
            c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="auto", robust=False)
            try:
                c.keep_pupil_designs(env)
                assert c._pupil.current != want              # a mid-grey frame's design to begin with
                c.apply(src, fbo)
                assert c._pupil.meter.latest() is None        # the frames' own reading is two frames late
                assert c.follow_light_now(120.0) == pytest.approx(want)
                assert c._pupil.current == pytest.approx(want) and c.model.pupil_mm == pytest.approx(want)
                model = c.model
                assert c.follow_light_now(120.0) == pytest.approx(want) and c.model is model   # already there
                c.apply(src, fbo)
                assert np.isfinite(G.read_framebuffer(fbo).astype(np.float32)).all()
                kept = sorted((tmp_path / "designs").glob("*.pickle"))
                assert len(kept) == 1, kept
                stamps.append(kept[0].stat().st_mtime_ns)
            finally:
                c.release()
        assert stamps[0] == stamps[1]                         # the second run designed nothing: it read the file
        fixed = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil="rx", robust=False)
        try:
            fixed.apply(src, fbo)
            assert fixed.follow_light_now(1.0) is None
        finally:
            fixed.release()
    finally:
        G.release(fbo, tex, src)
