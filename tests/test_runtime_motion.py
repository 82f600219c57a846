"""The reprojected warm start of ``Corrector(filter="fista")`` on a real headless GL context (Mesa
llvmpipe in CI), and the motion estimate that feeds it (:mod:`vrcorrect.runtime.motion`): a pan
across a photograph with the shift known, against the plain warm start, ``fast`` and the CPU twin;
phase correlation on known shifts and on unrelated images; a scene cut starts cold; a shift of
(0, 0) is the plain warm start."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import count_gl_objects
from PIL import Image

from vrcorrect.specs.display import decode
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.specs.prescription import EyeRx, Prescription
from vrcorrect.runtime import gl as G
from vrcorrect.runtime.corrector import Corrector
from vrcorrect.runtime.motion import CUT_CONFIDENCE, MotionTracker, estimate_shift, motion_for
from vrcorrect.runtime.shell.scene import open_source
from vrcorrect.runtime.shell.sources import FolderSource, start_motion, take_motion
from vrcorrect.runtime.shell.source_spec import SourceSpec
from vrcorrect.solvers import make_problem, objective, solve
from vrcorrect.solvers.fista import FistaState, projected_gradient

SIZE, PAN, FRAMES, K = 96, 2, 10, 4
EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
RX = Prescription(right=EYE, left=EYE)


@pytest.fixture(scope="module")
def images():
    return {name: np.round(im * 255).astype(np.uint8) for name, im in bundled_images(128)}


def pan_windows(photo: np.ndarray, frames: int = FRAMES) -> list[np.ndarray]:
    """``SIZE`` windows moving ``PAN`` px right each frame: the content moves ``PAN`` px left."""
    top = (photo.shape[0] - SIZE) // 2
    return [np.ascontiguousarray(photo[top:top + SIZE, PAN * f:PAN * f + SIZE]) for f in range(frames)]


def fista(gl) -> Corrector:
    return Corrector(gl, RX, "desktop", "right", filter="fista", iterations_per_frame=K)


def run_pan(gl, windows, motion) -> tuple[list[float], list[np.ndarray], Corrector]:
    """Frames of ``windows`` through a fresh corrector, ``motion`` passed from the second on;
    returns the GPU's objective fractions, the solutions after each frame and the corrector."""
    c = fista(gl)
    src = G.upload_texture(gl, windows[0])
    tex, fbo = G.render_target(gl, width=SIZE, height=SIZE)
    fractions, solutions = [], []
    try:
        for f, w in enumerate(windows):
            G.write_texture(src, w)
            c.apply(src, fbo, motion_px=None if f == 0 else motion)
            fractions.append(c.last_objective_fraction((SIZE, SIZE)))
            solutions.append(c.solution((SIZE, SIZE)))
    finally:
        G.release(fbo, tex, src)
    return fractions, solutions, c


def problem_of(c: Corrector, image_u8: np.ndarray):
    m = c.model
    return make_problem(decode("srgb", image_u8.astype(np.float32) / 255), m.kernel, m.reference)


def test_pan_with_the_known_shift_beats_the_plain_warm_start_and_nears_fast(gl, images):
    windows = pan_windows(images["astronaut"])
    plain, _, c1 = run_pan(gl, windows, None)
    moved, _, c2 = run_pan(gl, windows, (-PAN, 0))
    try:
        problems = [problem_of(c1, w) for w in windows]
        none = [objective(p.target, p) for p in problems]
        fast = [solve(p, "fast").objective for p in problems]
    finally:
        c1.release()
        c2.release()
    plain_r = [fr * n / b for fr, n, b in zip(plain, none, fast)]
    moved_r = [fr * n / b for fr, n, b in zip(moved, none, fast)]
    print("objective / fast per frame, plain warm start:", np.round(plain_r, 4).tolist())
    print("objective / fast per frame, reprojected:     ", np.round(moved_r, 4).tolist())
    assert plain[0] == moved[0]                                       # the same cold first frame
    assert all(fr < 1.0 for fr in plain + moved)                      # never worse than uncorrected
    for f in range(4, FRAMES):                                        # from frame 5 on
        assert moved_r[f] < plain_r[f], (f, moved_r, plain_r)
    assert moved_r[-1] <= 1.05, moved_r


def test_gpu_reprojection_equals_the_cpu_twin(gl, images):
    """The shader's reprojection (shift, exposed pixels from the new target, y moved with x, momentum
    kept) is the CPU's: three pan frames on the GPU against ``projected_gradient`` from the state
    moved by the same shift."""
    windows = pan_windows(images["coffee"], 3)
    _, solutions, c = run_pan(gl, windows, (-PAN, 0))
    try:
        problems = [problem_of(c, w) for w in windows]
    finally:
        c.release()
    state = None
    for f, p in enumerate(problems):
        start = None
        if f:
            def move(a):                                              # content PAN px left, exposed: t
                out = np.moveaxis(p.target, 2, 0).astype(np.float32).copy()
                out[:, :, :SIZE - PAN] = a[:, :, PAN:]
                return out
            start = FistaState(x=move(state.x), y=move(state.y), momentum=state.momentum)
        x, state = projected_gradient(p, K, state=start, return_state=True)
        assert np.abs(solutions[f] - x).max() <= 2e-3, f


def test_a_zero_shift_is_the_plain_warm_start(gl, images):
    windows = pan_windows(images["astronaut"], 3)
    a, sa, c1 = run_pan(gl, windows, None)
    b, sb, c2 = run_pan(gl, windows, (0.3, -0.4))                     # rounds to (0, 0)
    c1.release()
    c2.release()
    assert a == b
    for x, y in zip(sa, sb):
        np.testing.assert_array_equal(x, y)


def test_a_shift_allocates_nothing_and_motion_is_checked(gl, images):
    windows = pan_windows(images["astronaut"], 4)
    c = fista(gl)
    src = G.upload_texture(gl, windows[0])
    tex, fbo = G.render_target(gl, width=SIZE, height=SIZE)
    try:
        c.apply(src, fbo)
        with count_gl_objects(gl) as made:
            for w in windows[1:]:
                G.write_texture(src, w)
                c.apply(src, fbo, motion_px=(-PAN, 0))
        assert made == []
        for bad in ((1,), (float("nan"), 0), "left"):
            with pytest.raises(ValidationError):
                c.apply(src, fbo, motion_px=bad)
    finally:
        c.release()
        G.release(fbo, tex, src)


@pytest.mark.parametrize("shift", [(3, -5), (-7, 2), (0, 4), (-1, -1), (0, 0)])
def test_estimate_shift_recovers_known_shifts(images, shift):
    dx, dy = shift
    photo = images["astronaut"]
    prev = photo[20:100, 20:110]
    new = photo[20 - dy:100 - dy, 20 - dx:110 - dx]                    # new(p) = prev(p - d)
    got = estimate_shift(prev, new)
    assert got[:2] == shift
    assert got[2] > 0.5
    assert motion_for(prev, new) == shift


def test_estimate_shift_downsamples_large_frames(images):
    photo = np.round(bundled_images(768)[0][1] * 255).astype(np.uint8)
    prev, new = photo[40:640, 40:700], photo[49:649, 34:694]          # d = (6, -9); 660 px: factor 3
    assert estimate_shift(prev, new)[:2] == (6, -9)


def test_unrelated_images_have_low_confidence(images):
    names = list(images)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            confidence = estimate_shift(images[a], images[b])[2]
            assert confidence < CUT_CONFIDENCE, (a, b, confidence)
            assert motion_for(images[a], images[b]) is None
    assert estimate_shift(np.zeros((8, 8)), np.zeros((8, 8)))[2] == 0.0


def test_tracker_accumulates_and_reports_cuts(images):
    photo = images["astronaut"]
    t = MotionTracker()
    t.new_frame(photo[20:84, 20:84])
    assert t.take() == (0, 0)                                         # the first picture
    t.new_frame(photo[20:84, 22:86])
    t.new_frame(photo[20:84, 24:88])
    assert t.take() == (-4, 0)                                        # two pictures in one frame
    assert t.take() == (0, 0)
    t.new_frame(images["text"][20:84, 20:84])
    assert t.take() == "cut"
    t2 = MotionTracker()
    t2.new_frame(photo[20:84, 20:84])
    t2.new_frame(photo[20:84, 22:86], scale=(2.0, 2.0))               # a picture fitted at twice its size
    assert t2.take() == (-4, 0)


def test_a_folder_pan_reprojects_and_a_cut_starts_cold(gl, images, tmp_path):
    """The mirror's and overlay's wiring: a folder source estimates its pictures' motion before upload,
    ``take_motion`` hands it on, and on an unrelated picture the corrector starts cold (the frame
    equals a fresh corrector's first frame)."""
    windows = pan_windows(images["astronaut"], 2)
    cut = np.ascontiguousarray(images["chelsea"][:SIZE, :SIZE])
    for i, im in enumerate(windows + [cut]):
        Image.fromarray(im).save(tmp_path / f"{i}.png")
    source = FolderSource(gl, SIZE, SIZE, tmp_path, interval_s=1.0)
    c = fista(gl)
    fresh = fista(gl)
    tex, fbo = G.render_target(gl, width=SIZE, height=SIZE)
    try:
        assert start_motion(source, [c])
        assert not start_motion(source, [Corrector(gl, RX, "desktop", "right", filter="fft")])
        seen = []
        for t_s in (0.0, 1.0, 2.0):
            texture = source.render(t_s)[1]
            motion = take_motion(source, [c])
            seen.append(motion)
            c.apply(texture, fbo, motion_px=motion)
        assert seen == [(0, 0), (-PAN, 0), None]
        fresh.apply(source.render(2.0)[1], fbo)
        np.testing.assert_array_equal(c.solution((SIZE, SIZE)), fresh.solution((SIZE, SIZE)))
        demo = open_source(gl, SourceSpec("demo"), SIZE, SIZE)
        try:
            assert not start_motion(demo, [c]) and take_motion(demo, [c]) == (0, 0)
        finally:
            demo.release()
    finally:
        c.release()
        fresh.release()
        source.release()
        G.release(fbo, tex)


# --------------------------------------------------------------------------
# Known motion: a turn of the eye (xr's tracked head)
# --------------------------------------------------------------------------


def _camera_yaw_pitch(yaw_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """World-to-eye matrix of an eye at the origin turned left by ``yaw_deg`` and up by ``pitch_deg``."""
    from vrcorrect.runtime.shell.scene import rotation_x, rotation_y

    return np.linalg.inv(rotation_y(np.radians(yaw_deg)) @ rotation_x(np.radians(pitch_deg)))


def test_view_shift_of_a_turn_is_the_projected_angle():
    """Turning left moves distant content right by f tan(angle) pixels (f: the focal length in
    pixels); looking up moves it down; a symmetric frustum's centre is the image centre."""
    from vrcorrect.runtime.motion import view_shift
    from vrcorrect.runtime.shell.scene import perspective

    width, height, fov_y = 320, 200, 50.0
    p = perspective(fov_y, width / height, 0.05, 60.0)
    f = height / 2 / np.tan(np.radians(fov_y / 2))                 # pixels, vertically and horizontally
    for yaw, pitch in [(1.0, 0.0), (-2.5, 0.0), (0.0, 1.5), (0.0, -3.0)]:
        dx, dy = view_shift(np.eye(4), _camera_yaw_pitch(yaw, pitch), p, (width, height))
        assert dx == round(f * np.tan(np.radians(yaw))), (yaw, dx)
        assert dy == round(f * np.tan(np.radians(pitch))), (pitch, dy)
    assert view_shift(np.eye(4), np.eye(4), p, (width, height)) == (0, 0)
    # the eye's position does not count (distant content): the same turn from elsewhere
    moved = _camera_yaw_pitch(2.0) @ np.array([[1, 0, 0, -0.3], [0, 1, 0, 0.1], [0, 0, 1, 0.2], [0, 0, 0, 1.0]])
    assert view_shift(np.eye(4), moved, p, (width, height)) == view_shift(np.eye(4), _camera_yaw_pitch(2.0), p,
                                                                          (width, height))


def test_view_shift_follows_the_old_centre_in_an_asymmetric_field():
    """A headset's field is wider on the outer side: the old image centre is off the axis, and the
    shift is where that ray lands in the turned view, relative to the centre."""
    from vrcorrect.runtime.motion import view_shift
    from vrcorrect.runtime.shell.xr import projection_from_fov

    p = projection_from_fov(-0.80, 0.70, 0.75, -0.78)
    size = (400, 400)
    yaw = np.radians(3.0)
    dx, dy = view_shift(np.eye(4), _camera_yaw_pitch(3.0), p, size)
    # the centre of the image looks at tan(x) = (tan(right) + tan(left)) / 2 on the image plane
    tl, tr = np.tan(-0.80), np.tan(0.70)
    centre = np.arctan((tl + tr) / 2)
    expected = (np.tan(centre + yaw) - np.tan(centre)) / (tr - tl) * size[0]
    assert abs(dx - expected) <= 0.5 and dy == 0


def test_view_shift_turns_that_lose_the_view_and_bad_matrices():
    from vrcorrect.plumbing.errors import ValidationError
    from vrcorrect.runtime.motion import view_shift
    from vrcorrect.runtime.shell.scene import perspective

    p = perspective(60.0, 1.0, 0.05, 60.0)
    assert view_shift(np.eye(4), _camera_yaw_pitch(120.0), p, (64, 64)) is None     # behind the eye now
    with pytest.raises(ValidationError, match="view_after"):
        view_shift(np.eye(4), np.eye(3), p, (64, 64))
    with pytest.raises(ValidationError, match="projection"):
        view_shift(np.eye(4), np.eye(4), np.full((4, 4), np.nan), (64, 64))
