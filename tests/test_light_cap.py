"""The light cap of a robust design (issue 44): a correction may add to each displayed primary at
most the target's own light there plus 2 % of white (``vrcorrect.solvers.problem.light_cap``), in
``fast``, in the real-time ADMM's CPU twin and on the GPU (``LIGHT_CAP`` in ``admm.glsl``); a
single-eye design keeps the box [0, 1]."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vrcorrect.physics.robust import design_eye
from vrcorrect.runtime.strategies.foveated import PERIPHERY_ITERATIONS
from vrcorrect.plumbing.images import prepare_image
from vrcorrect.solvers import solve
from vrcorrect.solvers.problem import LIGHT_CAP_FLOOR, light_cap, make_design_problem
from vrcorrect.solvers.realtime import AdmmFrames
from vrcorrect.specs.display import decode, encode, get_display
from vrcorrect.specs.prescription import EyeRx, Prescription
from vrcorrect.studies.bench.sequences import WORDS, text_page

EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
QUEST2 = get_display("quest2")
W, H = 64, 48
_designs: dict = {}


def design(robust: bool):
    if robust not in _designs:
        _designs[robust] = design_eye(EYE, QUEST2, 3.125, robust=robust)
    return _designs[robust]


def dark_words_u8() -> np.ndarray:
    """Light words on near black, W x H, 8-bit sRGB."""
    page = prepare_image(text_page(W, H, WORDS, font_px=12, ink=(225, 225, 225), paper=(18, 18, 18)), max(W, H), "w")
    return np.ascontiguousarray(np.round(page[:H, :W] * 255).astype(np.uint8))


def linear(image_u8: np.ndarray) -> np.ndarray:
    return decode("srgb", image_u8.astype(np.float32) / 255).astype(np.float32)


def test_the_cap_is_twice_the_light_plus_the_floor_and_never_above_one():
    assert LIGHT_CAP_FLOOR == 0.02
    cap = light_cap(np.array([0.0, 0.01, 0.1, 0.3, 0.49, 0.5, 1.0]))
    assert cap.dtype == np.float32
    assert cap == pytest.approx([0.02, 0.04, 0.22, 0.62, 1.0, 1.0, 1.0], abs=1e-7)


def test_a_robust_design_is_capped_and_a_single_eye_design_is_not():
    t = linear(dark_words_u8())
    assert make_design_problem(t, design(True)).capped
    assert not make_design_problem(t, design(False)).capped


def test_fast_keeps_a_robust_design_under_the_cap_where_the_unit_box_goes_past_it():
    """On light words over near black the unit box's solution lifts the ground past twice its light
    (the halo the cap is for); the capped one stays under the cap everywhere and is still a
    correction (its objective below uncorrected)."""
    t = linear(dark_words_u8())
    problem = make_design_problem(t, design(True))
    capped = solve(problem, "fast")
    unit = solve(replace(problem, capped=False), "fast")
    cap = light_cap(t)
    assert np.max(unit.image - cap) > 0.05
    assert np.max(capped.image - cap) <= 1e-6
    assert capped.settings["box"].startswith("0 to the light cap")
    assert capped.objective < solve(problem, "none").objective


@pytest.mark.parametrize("level", [0, 255])
def test_a_black_and_a_white_frame_stay_finite_under_the_cap(level):
    """Black: the cap is the floor, 0.02, everywhere; white: the cap is 1 (the unit box)."""
    t = linear(np.full((H, W, 3), level, np.uint8))
    problem = make_design_problem(t, design(True))
    x = solve(problem, "fast").image
    twin = AdmmFrames(design(True).kernel, design(True).reference, (H, W), cap=True)
    for _ in range(3):
        frame = twin.frame(t, 2)
    top = 0.02 if level == 0 else 1.0
    for image in (x, frame.solution, frame.shown):
        assert np.all(np.isfinite(image)) and image.min() >= 0.0 and image.max() <= top + 1e-6


def test_the_twin_keeps_under_the_cap_frame_after_frame():
    """The real-time default's CPU twin with the cap (half precision: the cap of the target as stored,
    in float16): the solution and the guarded frame stay under the cap on every frame of words
    scrolling; without it they go past."""
    words = dark_words_u8()
    d = design(True)
    with_cap, without = (AdmmFrames(d.kernel, d.reference, (H, W), cap=c) for c in (True, False))
    over = 0.0
    for f in range(6):
        t = linear(np.roll(words, 2 * f, axis=1))
        cap = light_cap(t.astype(np.float16).astype(np.float32))
        a, b = with_cap.frame(t, 2), without.frame(t, 2)
        assert np.max(a.solution - cap) <= 1e-6 and np.max(a.shown - cap) <= 1e-6, f
        over = max(over, float(np.max(b.solution - cap)))
    assert over > 0.05


def test_the_gpu_shows_a_robust_design_under_the_cap_and_equals_its_twin(gl):
    """A robust Corrector (the commands' and the layer's default; single precision) on light words
    over near black: each frame's solution equals the capped twin's to 1e-5, and what it draws (8-bit
    sRGB) decodes to at most the cap, one code value allowed for rounding."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    words = dark_words_u8()
    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil=3.125, robust=True,
                  precision="single", early_stop=False)
    twin = AdmmFrames(c.model.kernel, c.model.reference, (H, W), precision="single",
                      grid_kernel_size=c.model.grid_kernel_size, cap=True)
    src = G.upload_texture(gl, words)
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        t = linear(words)
        for f in range(4):
            c.apply(src, fbo)
            cpu = twin.frame(t, 2)
            assert np.abs(c.solution((W, H)) - cpu.solution).max() <= 1e-5, f
        shown = G.read_framebuffer(fbo).astype(np.float32)
        top = np.round(np.clip(encode("srgb", light_cap(t)), 0, 1) * 255) + 1
        assert np.all(shown <= top)
        assert np.max(cpu.solution - light_cap(t)) <= 1e-6
    finally:
        c.release()
        G.release(fbo, tex, src)



@pytest.mark.parametrize("periphery", ["target", "quarter"])
def test_a_foveated_robust_frame_keeps_to_the_cap_and_equals_its_twin(gl, periphery):
    """The foveated path (``--fovea``) with a robust design: the view the GPU composes (the window's
    solution, the periphery's correction, the blend) equals the capped twin's to 2e-5 as the gaze
    moves, and stays under the cap everywhere; the twin without the cap goes past it."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.solvers.foveated import FoveatedFrames, fovea_pixels

    w, h, radius = 128, 96, 16
    ppd = QUEST2.pixels_per_degree
    solved, band = fovea_pixels(radius / ppd, ppd)
    page = prepare_image(text_page(w, h, WORDS, font_px=12, ink=(225, 225, 225), paper=(18, 18, 18)), w, "w")
    words = np.ascontiguousarray(np.round(page[:h, :w] * 255).astype(np.uint8))
    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil=3.125, robust=True,
                  precision="single", iterations_per_frame=2, fovea_deg=radius / ppd, fovea_periphery=periphery)
    k, r = c.model.kernel, c.model.reference
    twins = {cap: FoveatedFrames(k, r, (h, w), radius_px=solved, band_px=band, precision="single", periphery=periphery,
                                 periphery_iterations=PERIPHERY_ITERATIONS.get(periphery), cap=cap)
             for cap in (True, False)}
    src = G.upload_texture(gl, words)
    tex, fbo = G.render_target(gl, width=w, height=h)
    t = linear(words)
    cap = light_cap(t)
    over = 0.0
    try:
        for f, gaze in enumerate(((64.5, 48.5), (40.5, 30.5), (100.5, 70.5))):
            c.gaze_deg = ((gaze[0] - w / 2) / ppd, (h / 2 - gaze[1]) / ppd)
            c.apply(src, fbo)
            cpu = twins[True].frame(t, 2, gaze_px=gaze)
            assert np.abs(c.solution((w, h)) - cpu.shown).max() <= 2e-5, f
            assert np.max(cpu.shown - cap) <= 1e-6, f
            over = max(over, float(np.max(twins[False].frame(t, 2, gaze_px=gaze).shown - cap)))
        assert over > 0.02
    finally:
        c.release()
        G.release(fbo, tex, src)
