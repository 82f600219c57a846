"""The GPU projected-gradient (FISTA) correction on a real headless GL context (Mesa llvmpipe in CI)
against its CPU twin, ``vrcorrect.solvers.fista.projected_gradient``: one iteration, k iterations,
the warm start from frame to frame and its cold starts, the guard, flat fields on every GPU method,
and the GPU timers' guard against a saturated query."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import count_gl_objects

from vrcorrect.specs.display import decode, encode
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.specs.prescription import EyeRx, Prescription
from vrcorrect.runtime import gl as G
from vrcorrect.runtime.corrector import Corrector
from vrcorrect.runtime.shell.render import render_frame
from vrcorrect.solvers import make_problem, objective, solve
from vrcorrect.solvers.fista import projected_gradient

SIZE = 64
# The case: a desktop monitor at its default distance, -2.00/-1.00x120, 4 mm pupil.
EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
RX = Prescription(right=EYE, left=EYE)
FLAT_SRGB = ((235, 235, 235), (200, 240, 220), (180, 40, 40), (20, 30, 90))   # grey, mint, red, dark blue


@pytest.fixture(scope="module")
def photo():
    return np.round(bundled_images(SIZE)[0][1] * 255).astype(np.uint8)          # astronaut


@pytest.fixture
def fista(gl):
    c = Corrector(gl, RX, "desktop", "right", filter="fista", iterations_per_frame=4)
    yield c
    c.release()


class Frames:
    """One source texture and a framebuffer of its size: ``frame()`` runs ``apply`` once."""

    def __init__(self, ctx, corrector: Corrector, image_u8: np.ndarray):
        self.ctx, self.c, self.image = ctx, corrector, image_u8
        self.size = (image_u8.shape[1], image_u8.shape[0])
        self.src = G.upload_texture(ctx, image_u8)
        self.tex, self.fbo = G.render_target(ctx, width=self.size[0], height=self.size[1])

    def frame(self) -> np.ndarray:
        self.c.apply(self.src, self.fbo)
        return G.read_framebuffer(self.fbo)

    def problem(self):
        m = self.c.model
        return make_problem(decode("srgb", self.image.astype(np.float32) / 255), m.kernel, m.reference)

    def release(self) -> None:
        G.release(self.fbo, self.tex, self.src)


def to_u8(linear: np.ndarray) -> np.ndarray:
    return np.round(np.clip(encode("srgb", linear), 0, 1) * 255).astype(np.uint8)


def test_one_gl_iteration_equals_one_cpu_step(gl, fista, photo):
    """Cold start, one iteration: the GPU's solution is the CPU's projected-gradient step to float
    precision (the same exact linear convolution with black outside, step 1/||K||^2, clamp)."""
    fista.iterations_per_frame = 1
    f = Frames(gl, fista, photo)
    try:
        f.frame()
        p = f.problem()
        cpu = projected_gradient(p, 1)
        gpu = fista.solution(f.size)
        moved = np.abs(cpu - p.target).max()
        assert moved > 0.05                                        # the step did something
        assert np.abs(gpu - cpu).max() <= 1e-5
    finally:
        f.release()


def test_k_iterations_and_frames_continue_like_one_long_run(gl, fista, photo):
    """k = 4 in one frame is the CPU's 4 steps within 2/255 (as displayed); on a still source the
    next frames continue FISTA where it stopped, momentum included: 3 frames of 2 iterations are
    the CPU's 6 steps, which is also 3 CPU calls of 2 steps passing the state on."""
    f = Frames(gl, fista, photo)
    try:
        p = f.problem()
        f.frame()
        assert np.abs(to_u8(fista.solution(f.size)).astype(int) - to_u8(projected_gradient(p, 4))).max() <= 2
        fista.reset()
        fista.iterations_per_frame = 2
        for _ in range(3):
            f.frame()
        six = projected_gradient(p, 6)
        state = None
        for _ in range(3):
            x, state = projected_gradient(p, 2, state=state, return_state=True)
        np.testing.assert_array_equal(x, six)
        assert np.abs(fista.solution(f.size) - six).max() <= 1e-4
        assert np.abs(to_u8(fista.solution(f.size)).astype(int) - to_u8(six)).max() <= 2
    finally:
        f.release()


def test_warm_start_converges_over_frames_and_never_loses(gl, fista, photo):
    """A still photograph at k = 4: the frame's objective (the GPU's own, after the guard) falls on
    every frame, is below uncorrected from the first, and after 10 frames is within 5 % of the
    CPU's converged ``fast``; the displayed 8-bit frame says the same."""
    f = Frames(gl, fista, photo)
    try:
        p = f.problem()
        none, best = objective(p.target, p), solve(p, "fast").objective
        fractions = []
        for _ in range(10):
            shown = f.frame()
            fractions.append(fista.last_objective_fraction(f.size))
        assert fractions[0] < 0.95
        assert all(b < a for a, b in zip(fractions, fractions[1:])), fractions
        assert fractions[-1] * none <= 1.05 * best
        seen = objective(decode("srgb", shown.astype(np.float32) / 255), p)
        assert seen <= 1.05 * best
        assert abs(seen / none - fractions[-1]) < 0.01             # the GPU's figure is the CPU's
    finally:
        f.release()


def test_cold_start_after_reset_adjust_and_resize(gl, fista, photo):
    """After warm frames, ``reset()``, a prescription change and a size change each start again
    from the target: the next frame equals the CPU's k steps from the target for the eye then."""
    f = Frames(gl, fista, photo)
    small = Frames(gl, fista, photo[8:40, 4:52])
    try:
        def assert_cold(frames: Frames) -> None:
            frames.frame()
            cpu = projected_gradient(frames.problem(), fista.iterations_per_frame)
            assert np.abs(fista.solution(frames.size) - cpu).max() <= 1e-4

        for _ in range(2):
            f.frame()
        assert np.abs(fista.solution(f.size) - projected_gradient(f.problem(), 4)).max() > 1e-2   # warm
        fista.reset()
        assert_cold(f)
        f.frame()
        fista.adjust(sphere_D=-0.5)
        assert fista.eye_rx.sphere_D == -2.5
        assert_cold(f)
        f.frame()
        assert_cold(small)                                        # another size: cold
        assert_cold(f)                                            # and back: cold again
    finally:
        small.release()
        f.release()


def test_no_gpu_allocations_per_frame(gl, fista, photo):
    f = Frames(gl, fista, photo)
    try:
        f.frame()
        with count_gl_objects(gl) as made:
            for k in (4, 1, 0):
                fista.iterations_per_frame = k
                f.frame()
        assert made == []
    finally:
        f.release()


def test_zero_iterations_is_no_correction(gl, fista, photo):
    """k = 0 from a cold start leaves the target: the guard blends nothing in, the frame is the
    input (sRGB round trip)."""
    fista.iterations_per_frame = 0
    f = Frames(gl, fista, photo)
    try:
        assert np.abs(f.frame().astype(int) - photo).max() <= 1
    finally:
        f.release()


@pytest.mark.parametrize("filter_", ["fft", "separable", "fista"])
def test_flat_fields_come_back_unchanged_on_the_gpu(gl, filter_):
    """No colour cast: flat fields of in-gamut colours (the issue's 235 grey through ``render``,
    then the others through the same ``Corrector``, one cold frame each) are unchanged away from
    the border, for each GPU method (the inverse is regularised toward the target).  Near the
    border the objective's black surround asks for a brighter edge; projected gradient spreads
    that inward by about two kernel widths per frame of four iterations."""
    size = 128
    grey = np.full((size, size, 3), 235, np.uint8)
    out, info = render_frame(grey, RX, "desktop", ctx=gl, filter=filter_)
    m = 2 * info["kernel_size"] if filter_ == "fista" else 0
    inner = (slice(m, size - m), slice(m, size - m))
    assert np.abs(out[inner].astype(int) - 235).max() <= 1
    c = Corrector(gl, RX, "desktop", "right", filter=filter_)
    try:
        for rgb in FLAT_SRGB[1:]:
            f = Frames(gl, c, np.zeros((size, size, 3), np.uint8) + np.array(rgb, np.uint8))
            c.reset()
            try:
                assert np.abs(f.frame()[inner].astype(int) - f.image[inner]).max() <= 1, rgb
            finally:
                f.release()
    finally:
        c.release()


@pytest.mark.parametrize("rgb", FLAT_SRGB)
def test_flat_fields_come_back_unchanged_on_the_cpu(rgb):
    """The CPU wiener, with designed filters and with the exact inverse, keeps a flat field away
    from the border (the old toward-zero inverse turned a 235 grey into (220, 238, 234) mint)."""
    from vrcorrect.specs.display import get_display
    from vrcorrect.physics.kernel import build_kernel, build_reference_kernel

    d = get_display("desktop")
    k, ref = build_kernel(EYE, d), build_reference_kernel(EYE, d)
    size, margin = 96, k.size
    target = np.full((size, size, 3), decode("srgb", np.array(rgb, np.float64) / 255), np.float32)
    for reference in (ref, None):
        p = make_problem(target, k, reference)
        for design in (True, False):
            out = to_u8(solve(p, "wiener", design=design).image)
            assert np.abs(out[margin:-margin, margin:-margin].astype(int) - np.array(rgb)).max() == 0


def test_options_are_checked(gl):
    for bad in (-1, 1.5, True, 10_000):
        with pytest.raises(ValidationError, match="iterations_per_frame"):
            Corrector(gl, RX, "desktop", "right", filter="fista", iterations_per_frame=bad)
    with pytest.raises(ValidationError, match="fista"):
        Corrector(gl, RX, "desktop", "right", filter="wavelet")


def test_cpu_twin_start_and_state_are_checked():
    from vrcorrect.specs.display import get_display
    from vrcorrect.physics.kernel import build_kernel

    p = make_problem(decode("srgb", bundled_images(24)[0][1]), build_kernel(EYE, get_display("desktop")))
    x, state = projected_gradient(p, 2, return_state=True)
    assert state.momentum > 1 and state.x.shape == (3, 24, 24)
    from_start = projected_gradient(p, 3, start=x)                      # momentum restarted: not 5 steps
    assert objective(from_start, p) < objective(x, p)
    with pytest.raises(ValidationError, match="start"):
        projected_gradient(p, 1, start=x, state=state)
    with pytest.raises(ValidationError, match="start"):
        projected_gradient(p, 1, start=x[:10])
    small = make_problem(p.target[:20], p.kernel)
    with pytest.raises(ValidationError, match="state"):
        projected_gradient(small, 1, state=state)
    np.testing.assert_array_equal(projected_gradient(p, 0, start=x), x)


# --------------------------------------------------------------------------
# GPU timers
# --------------------------------------------------------------------------


def test_a_saturated_or_invalid_timer_query_is_never_a_time():
    """moderngl reads GL_TIME_ELAPSED as 32-bit nanoseconds: 4.29 s or more comes back as
    2^32 - 1 (shown as "4294.97 ms" before); that, and anything else that is not a time, is None."""
    assert G.timer_query_ms(1_500_000) == pytest.approx(1.5)
    assert G.timer_query_ms(0) == 0.0
    assert G.timer_query_ms(2 ** 32 - 2) == pytest.approx(4294.967294)
    for bad in (2 ** 32 - 1, 2 ** 32, 2 ** 40, -1, None, float("nan"), math.inf, "x", True):
        assert G.timer_query_ms(bad) is None, bad
    assert G.format_ms(None) == "-" and G.format_ms(None, "n/a") == "n/a" and G.format_ms(1.234) == "1.23"


def test_stage_times_drop_a_saturated_query(gl):
    from vrcorrect.runtime.shell.timing import StageTimes

    class FakeQuery:
        def __init__(self, elapsed):
            self.elapsed = elapsed

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

    times = StageTimes(gl, ("correct left", "correct right", "present"))
    times.queries = {"correct left": FakeQuery(2 ** 32 - 1), "correct right": FakeQuery(2_000_000)}
    for name in ("correct left", "correct right", "present"):
        with times.stage(name):
            pass
    out = times.collect()
    assert out["correct left"][0] is None and out["correct right"][0] == pytest.approx(2.0)
    assert out["present"][0] is None


# --------------------------------------------------------------------------
# vrcorrect render --filter fista --frames N
# --------------------------------------------------------------------------


def test_render_frames_warm_start_like_one_long_run(gl, photo):
    """``render_frame(..., frames=3)`` with k = 2 is 6 CPU steps, guarded: the GPU's objective
    fraction of the last frame is the CPU twin's; more frames, lower objective."""
    from vrcorrect.solvers.realtime import FistaFrames

    _, one = render_frame(photo, RX, "desktop", ctx=gl, filter="fista", iterations_per_frame=2)
    out, info = render_frame(photo, RX, "desktop", ctx=gl, filter="fista", iterations_per_frame=2, frames=3)
    assert info["frames"] == 3 and info["iterations_per_frame"] == 2
    c = Corrector(gl, RX, "desktop", "right", filter="fista")
    try:
        p = make_problem(decode("srgb", photo.astype(np.float32) / 255), c.model.kernel, c.model.reference)
    finally:
        c.release()
    twin = FistaFrames(c.model.kernel, c.model.reference, p.target.shape[:2])
    for _ in range(3):
        frame = twin.frame(p.target, 2)
    assert info["objective_fraction"] == pytest.approx(frame.objective / frame.uncorrected, abs=2e-3)
    assert info["objective_fraction"] < one["objective_fraction"] < 1.0
    seen = objective(decode("srgb", out.astype(np.float32) / 255), p)
    assert seen / objective(p.target, p) == pytest.approx(info["objective_fraction"], abs=0.01)


def test_render_command_fista_frames_and_its_errors(tmp_path, photo, capsys):
    import json

    from PIL import Image

    from vrcorrect.apps.cli import main

    src = tmp_path / "in.png"
    Image.fromarray(photo).save(src)
    rx = tmp_path / "rx.json"
    rx.write_text(json.dumps({"schema": "vrcorrect.prescription/1",
                              **{e: {"sphere_D": -2.0, "cylinder_D": -1.0, "axis_deg": 120, "pupil_diameter_mm": 4.0}
                                 for e in ("right", "left")}}))
    out = tmp_path / "out.png"
    assert main(["render", str(src), "-o", str(out), "--rx", str(rx), "--display", "desktop", "--filter", "fista",
                 "--frames", "2", "--iterations-per-frame", "3"]) == 0
    printed = capsys.readouterr().out
    assert "3 iteration(s) per frame, 2 frame(s) warm-started" in printed and "of uncorrected" in printed
    assert np.asarray(Image.open(out)).shape == photo.shape
    missing = str(tmp_path / "missing.png")                       # options are checked before the input
    for args, words in ((["--filter", "fista", "--iterations-per-frame", "65"], "--iterations-per-frame"),
                        (["--filter", "fista", "--iterations-per-frame", "x"], "--iterations-per-frame"),
                        (["--filter", "fft", "--iterations-per-frame", "4"], "only with --filter admm or fista"),
                        (["--filter", "fista", "--frames", "0"], "--frames"),
                        (["--frames", "many"], "--frames")):
        assert main(["render", missing, "-o", str(tmp_path / "o.png"), *args]) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("vrcorrect: error:") and words in err, err
    assert not (tmp_path / "o.png").exists()


def test_admm_is_the_default_gpu_method_everywhere_and_fista_stays_selectable():
    """ADMM over frames is what a user gets without asking: the Corrector's default (2 iterations a
    frame), and the default ``--filter`` of render, mirror, overlay and xr; projected gradient
    (fista, 4 a frame by default) and ``wiener``'s one-pass inverse (fft, separable) stay
    selectable; render runs a settled view (10 frames) by default."""
    from vrcorrect.apps.cli import build_parser
    from vrcorrect.runtime.corrector import CorrectorOptions

    assert CorrectorOptions().filter == "admm" and CorrectorOptions().iterations_per_frame == 2
    assert CorrectorOptions(filter="fista").iterations_per_frame == 4
    assert CorrectorOptions(filter="fista", iterations_per_frame=3).iterations_per_frame == 3
    parser = build_parser()
    for command in (["render", "in.png", "-o", "out.png"], ["mirror"], ["overlay", "--source", "screen"], ["xr"]):
        args = parser.parse_args(command)
        assert args.filter == "admm", command
        assert parser.parse_args([*command, "--filter", "fista"]).filter == "fista"
        assert parser.parse_args([*command, "--filter", "fft"]).filter == "fft"
        assert parser.parse_args([*command, "--filter", "separable"]).filter == "separable"
