"""The GPU's foveated frame (``CorrectorOptions(fovea_deg=...)``, issue 45) on a real headless GL
context (Mesa llvmpipe in CI), held to its CPU twin :class:`vrcorrect.solvers.foveated.FoveatedFrames`
frame by frame while the gaze and the content move; the view outside the window shown as it came;
its bad settings refused; its counted bytes against the full field's."""

from __future__ import annotations

import numpy as np
import pytest

from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.runtime import gl as G
from vrcorrect.runtime.corrector import Corrector, CorrectorOptions
from vrcorrect.runtime.dispatch import CostLedger
from vrcorrect.runtime.strategies.foveated import PERIPHERY_ITERATIONS
from vrcorrect.solvers.foveated import COLD_WINDOW_ITERATIONS, FoveatedFrames, fovea_pixels
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx, Prescription

QUEST2 = get_display("quest2")
PPD = QUEST2.pixels_per_degree
EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
RX = Prescription(right=EYE, left=EYE)
W, H = 128, 96
RADIUS = 16                                   # px: the fovea's radius (the window's half-side less its band)
SOLVED, BAND = fovea_pixels(RADIUS / PPD, PPD)  # the window solved: the radius and the band beyond it


@pytest.fixture(scope="module")
def clip():
    """Five 8-bit windows of the astronaut, the content moving (-3, -2) px a frame."""
    big = np.round(bundled_images(160)[0][1] * 255).astype(np.uint8)
    return [np.ascontiguousarray(big[10 + 2 * f:10 + 2 * f + H, 5 + 3 * f:5 + 3 * f + W]) for f in range(5)]


def linear(image_u8: np.ndarray) -> np.ndarray:
    return decode("srgb", image_u8.astype(np.float32) / 255).astype(np.float32)


def gaze_deg(gaze_px):
    """View pixels (x, y down) -> degrees from the view's centre (x right, y up)."""
    return (gaze_px[0] - W / 2) / PPD, (H / 2 - gaze_px[1]) / PPD


# the gaze (pixel centres, so that degrees and back land in the same pixel) and the content's motion
FRAMES = (((64.5, 48.5), None), ((70.5, 44.5), None), ((70.5, 44.5), (-3, -2)), ((20.5, 85.5), (-3, -2)),
          ((122.5, 3.5), None))


@pytest.mark.parametrize("periphery", ["target", "half", "quarter"])
def test_the_gl_foveated_frame_equals_its_cpu_twin_as_the_gaze_and_content_move(gl, clip, periphery):
    """Single precision, 2 iterations a frame: the view the GPU composes (window solved, ring held to
    the periphery, blend band, guard, warm start across the window's and the content's motion, a
    window at the view's corner; the periphery's own frame, pooled, guarded and upsampled) equals the
    twin's to 2e-5, frame by frame."""
    c = Corrector(gl, RX, QUEST2, "right", precision="single", iterations_per_frame=2, fovea_deg=RADIUS / PPD,
                  fovea_periphery=periphery)
    twin = FoveatedFrames(build_kernel(EYE, QUEST2), build_reference_kernel(EYE, QUEST2), (H, W), radius_px=SOLVED,
                          band_px=BAND, precision="single", periphery=periphery,
                          periphery_iterations=PERIPHERY_ITERATIONS.get(periphery))
    src = G.upload_texture(gl, np.zeros((H, W, 3), np.uint8))
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        assert (c.describe()["fovea_radius_px"], c.describe()["fovea_band_px"]) == (SOLVED, BAND) == (20, 4)
        for f, ((gaze, motion), image) in enumerate(zip(FRAMES, clip)):
            G.write_texture(src, image)
            c.gaze_deg = gaze_deg(gaze)
            c.apply(src, fbo, motion_px=motion)
            cpu = twin.frame(linear(image), 2, gaze_px=gaze, shift=motion)
            gpu = c.solution((W, H))
            assert c.describe()["fovea_window"] == list(cpu.window.win), f
            assert np.abs(gpu - cpu.shown).max() <= 2e-5, f
            assert c.last_blend((W, H)) == pytest.approx(cpu.sub.beta, abs=1e-5), f
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_outside_the_window_the_codes_are_the_applications_and_inside_they_change(gl, clip):
    """The default precision (half), the periphery the target: every pixel outside the window is
    shown with the code values it came with; inside the window the picture is corrected."""
    c = Corrector(gl, RX, QUEST2, "right", fovea_deg=RADIUS / PPD, fovea_periphery="target")
    src = G.upload_texture(gl, clip[0])
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        gaze = (40.5, 60.5)
        c.gaze_deg = gaze_deg(gaze)
        for _ in range(3):
            c.apply(src, fbo)
        out = G.read_framebuffer(fbo)
        y0, y1, x0, x1 = c.describe()["fovea_window"]
        assert (y0, y1, x0, x1) == (60 - SOLVED, 60 + SOLVED, 40 - SOLVED, 40 + SOLVED)
        outside = np.ones((H, W), bool)
        outside[y0:y1, x0:x1] = False
        np.testing.assert_array_equal(out[outside], clip[0][outside])
        changed = np.abs(out[y0 + 4:y1 - 4, x0 + 4:x1 - 4].astype(int) - clip[0][y0 + 4:y1 - 4, x0 + 4:x1 - 4])
        assert changed.max() >= 16 and changed.mean() >= 2          # the window is corrected
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_a_foveated_frame_moves_fewer_bytes_than_the_full_field(gl):
    """At 480 x 400 with a 5 degree window (94 px on quest2) and the target outside it, the counted
    bytes of a changing frame fall
    to under 40 % of the full field's (the FFT grid is the sub-image's, 228 px a side against the view's 480 x
    400; the decode and the compose still read and write the whole view)."""
    size = (480, 400)
    rng = np.random.default_rng(3)
    moved = {}
    for fovea in (None, 5.0):
        c = Corrector(gl, RX, QUEST2, "right", fovea_deg=fovea, fovea_periphery="target")
        src = G.upload_texture(gl, (rng.random((size[1], size[0], 3)) * 255).astype(np.uint8))
        tex, fbo = G.render_target(gl, width=size[0], height=size[1])
        try:
            c.gpu.dry_run = True
            c.apply(src, fbo)                                   # the first frame of a size
            ledger = CostLedger()
            c.gpu.ledger = ledger
            c.apply(src, fbo)
            moved[fovea] = ledger.bytes
        finally:
            c.release()
            G.release(fbo, tex, src)
    assert moved[5.0] < 0.4 * moved[None], moved


@pytest.mark.parametrize("value, field", [(0.2, "fovea_deg"), (float("nan"), "fovea_deg"), (True, "fovea_deg"),
                                          (200, "fovea_deg")])
def test_a_bad_fovea_is_refused_naming_the_field(value, field):
    with pytest.raises(ValidationError, match=field):
        CorrectorOptions(fovea_deg=value)


def test_a_fovea_needs_the_admm_method():
    with pytest.raises(ValidationError, match="only with filter 'admm'"):
        CorrectorOptions(fovea_deg=10, filter="fft")


def test_bench_cost_counts_a_15_degree_fovea_at_a_quest_2_eye_under_half_a_gigabyte(tmp_path):
    """Issue 45's bar, counted from the dispatches (a dry run: nothing runs): a Quest 2 eye
    (1832 x 1920) foveated at 15 degrees with the default periphery (a quarter-resolution correction
    of the whole view) moves at most 0.5 GB a changing frame, its window's FFT grid the window's
    (625 x 625: 2 x 283 px and a 41 px kernel's ring, 5-smooth), not the view's; the report says so,
    and what a cold frame costs."""
    from vrcorrect.studies.bench.cost import METHODS, run_cost_bench

    report = run_cost_bench((1832, 1920), "quest2", methods=METHODS[:1], fovea=(15.0,), dry_run=True, write=False,
                            out=tmp_path / "benchmarks.md")
    assert report["fovea"][0]["periphery"] == "quarter"
    (f,) = report["fovea"]
    assert f["radius_px"] == round(15 * PPD) and f["grid"][0] < 700 and f["grid"][1] < 700
    assert f["bytes_per_eye_frame"] <= 0.5e9 < report["default"]["bytes_per_eye_frame"]
    # a cold frame runs the window's and the periphery's cold iterations: more than a changing frame,
    # less than the full field's cold frame (its half-resolution level)
    assert f["bytes_per_eye_frame"] < f["cold_frame_bytes_per_eye_frame"] < \
        report["default"]["cold_frame_bytes_per_eye_frame"]
    assert "radius 15 deg" in report["markdown"] and "at most 0.5 GB: met" in report["markdown"]
    assert f"(a cold frame: {f['cold_frame_bytes_per_eye_frame'] / 1e9:.2f} GB" in report["markdown"]
    assert not (tmp_path / "benchmarks.md").exists()


def test_render_with_a_window_says_where_and_keeps_the_codes_outside_it(tmp_path, capsys, clip):
    """``vrcorrect render --fovea --gaze --periphery target``, as a user runs it: the summary names the
    window and what is outside it; the written picture is the input, code for code, outside the window
    the summary names, and corrected inside it."""
    from PIL import Image

    from vrcorrect.apps import cli

    Image.fromarray(clip[0]).save(tmp_path / "in.png")
    radius_deg = RADIUS / PPD
    code = cli.main(["render", str(tmp_path / "in.png"), "-o", str(tmp_path / "out.png"), "--fovea", f"{radius_deg}",
                     "--gaze", "1,0.5", "--periphery", "target", "--frames", "3"])
    text = capsys.readouterr().out
    assert code == 0
    line = next(line for line in text.splitlines() if "foveated:" in line)
    assert "the rest of the view as it is" in line and "around the gaze at (1, 0.5) deg" in line
    assert f"a cold frame runs {COLD_WINDOW_ITERATIONS} more on the window" in line
    rows, cols = line.split("rows ")[1].split(", columns ")
    y0, y1 = (int(v) for v in rows.split("-"))
    x0, x1 = (int(v) for v in cols.split(")")[0].split("-"))
    assert (y1 - y0, x1 - x0) == (2 * SOLVED, 2 * SOLVED)
    out = np.asarray(Image.open(tmp_path / "out.png").convert("RGB"))
    outside = np.ones((H, W), bool)
    outside[y0:y1, x0:x1] = False
    np.testing.assert_array_equal(out[outside], clip[0][outside])
    assert np.abs(out[y0:y1, x0:x1].astype(int) - clip[0][y0:y1, x0:x1]).max() >= 16


def test_render_with_a_budget_says_what_it_chose(tmp_path, capsys, clip):
    """``vrcorrect render --budget-ms``: the summary gives the budget's last choice (iterations a frame,
    the window's radius with --fovea) and the time it measured on this renderer."""
    from PIL import Image

    from vrcorrect.apps import cli

    Image.fromarray(clip[0]).save(tmp_path / "in.png")
    code = cli.main(["render", str(tmp_path / "in.png"), "-o", str(tmp_path / "out.png"), "--budget-ms", "10000",
                     "--fovea", f"{RADIUS / PPD}", "--frames", "4"])
    text = capsys.readouterr().out
    assert code == 0
    line = next(line for line in text.splitlines() if "frame budget" in line)
    assert "budget 10000 ms:" in line and "iterations a frame" in line and f"fovea {RADIUS / PPD:.3g} deg" in line
    assert "(last " in line                                   # a frame was timed (two frames late)
