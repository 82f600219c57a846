"""The plugin on a real headless GL context (Mesa llvmpipe in CI): the GLSL correction against
the CPU ``wiener`` method, the GPU forward model against the CPU one, sRGB handling, the
identity at a zero prescription, live changes, prescription hot reload and the ONNX slot."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import count_gl_objects

from vrcorrect.specs.display import decode, encode, get_display
from vrcorrect.plumbing.errors import ValidationError, ValidationErrors
from vrcorrect.studies.evaluation import PRESCRIPTIONS, prescription_eye
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.vision.forward import what_the_eye_sees
from vrcorrect.physics.kernel import KernelOptions, build_reference_kernel
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.specs.prescription import Prescription
from vrcorrect.runtime import gl as G
from vrcorrect.runtime.corrector import Corrector
from vrcorrect.runtime.filters import apply_separable, separable_bank
from vrcorrect.runtime.onnx_backend import write_one_minus_x_model
from vrcorrect.solvers import make_problem
from vrcorrect.solvers.wiener import correction_filters, wiener

SAMPLE_RX = Path(__file__).resolve().parents[1] / "vrcorrect" / "data" / "sample_rx.json"
SIZE = 64
PHOTOS = ("astronaut", "coffee", "chelsea", "rocket")


def to_u8(srgb: np.ndarray) -> np.ndarray:
    return np.round(np.clip(srgb, 0, 1) * 255).astype(np.uint8)


def run(ctx, corrector: Corrector, image_u8: np.ndarray, how: str = "apply", **kw) -> np.ndarray:
    src = G.upload_texture(ctx, image_u8)
    tex, fbo = G.render_target(ctx, width=image_u8.shape[1], height=image_u8.shape[0])
    try:
        getattr(corrector, how)(src, fbo, **kw)
        return G.read_framebuffer(fbo)
    finally:
        G.release(fbo, tex, src)


def rx_doc(sphere=-1.5, cylinder=0.0, axis=0.0) -> dict:
    eye = {"sphere_D": sphere, "cylinder_D": cylinder, "axis_deg": axis, "pupil_diameter_mm": 4.0}
    return {"schema": "vrcorrect.prescription/1", "right": dict(eye), "left": dict(eye)}


@pytest.fixture(scope="module")
def images():
    return [(name, to_u8(img)) for name, img in bundled_images(SIZE)]


@pytest.fixture(scope="module", params=["fft", "separable"])
def evaluation_corrector(headless_gl, request):
    """The evaluation's myopia (-1.50 D, 4 mm) on the desktop preset at infinity, blend fixed;
    each GLSL strategy."""
    eye = prescription_eye(PRESCRIPTIONS[0])
    rx = Prescription(right=eye, left=eye)
    with headless_gl:
        c = Corrector(headless_gl, rx, "desktop", "right", beta=0.7, filter=request.param,
                      kernel_options=KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf)))
        yield c
        c.release()


def test_separable_bank_matches_the_designed_filters():
    """The low-rank bank (CPU twin of the GL passes) reproduces the designed filters' output
    within its stated error on a real photograph."""
    eye = prescription_eye(PRESCRIPTIONS[2])
    from vrcorrect.physics.kernel import build_kernel

    k = build_kernel(eye, get_display("quest2"), KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf)))
    f = correction_filters(k, 0.3)
    bank = separable_bank(f.taps, tolerance=1e-3)
    assert bank.error <= 1e-3 and sum(bank.ranks) == bank.components
    assert bank.taps_per_pixel < f.size ** 2 * 9                 # cheaper than the dense bank
    img = decode("srgb", bundled_images(48)[1][1]).astype(np.float32)
    from vrcorrect.solvers.wiener import apply_filters

    dense = np.moveaxis(apply_filters(np.moveaxis(img, 2, 0), f.taps), 0, 2)
    assert np.abs(apply_separable(img, bank) - dense).max() <= 2e-3
    coarse = separable_bank(f.taps, tolerance=1e-1)
    assert sum(coarse.ranks) < sum(bank.ranks)


def test_glsl_correction_matches_cpu_wiener(gl, evaluation_corrector, images):
    """Every evaluation image: the GPU output equals the CPU wiener with the same regulariser and
    blend within 2/255 per channel (8-bit sRGB, as displayed): the FFT strategy against the
    untruncated inverse on the same grid, the separable one against the designed filters."""
    c = evaluation_corrector
    m = c.model
    assert m.beta == 0.7 and not m.identity
    ref_kernel = build_reference_kernel(m.eye, c.display, c.options.kernel_options)
    worst = 0
    for name, img in images:
        gpu = run(gl, c, img)
        target = decode("srgb", img.astype(np.float32) / 255)
        if c.options.filter == "fft":
            grid, margin = c.fft_grid_for((SIZE, SIZE))
            extra = dict(design=False, grid=grid, margin=margin)
        else:
            extra = {}
        cpu = wiener(make_problem(target, m.kernel, ref_kernel), regularisation=(m.mu_rel,), beta=m.beta,
                     **extra).image
        diff = np.abs(gpu.astype(int) - to_u8(encode("srgb", cpu)).astype(int))
        worst = max(worst, int(diff.max()))
        assert not np.array_equal(gpu, img), name                  # it did correct
    assert worst <= 2


def test_gpu_forward_model_matches_cpu(gl, evaluation_corrector, images):
    c = evaluation_corrector
    for name, img in images[:3]:
        seen = run(gl, c, img, "simulate", corrected=False)
        cpu, _ = what_the_eye_sees(decode("srgb", img.astype(np.float32) / 255), c.model.kernel)
        assert np.abs(seen.astype(int) - to_u8(encode("srgb", cpu)).astype(int)).max() <= 2, name


def test_per_frame_blend_matches_cpu_wiener_and_never_loses(gl, images):
    """The FFT strategy (blend computed on the GPU every frame): on every evaluation image the
    GPU's blend equals the CPU wiener's (same regulariser, same grid), the output matches within
    2/255, and the objective is never above the uncorrected one (below it on photographs)."""
    from vrcorrect.solvers import objective

    eye = prescription_eye(PRESCRIPTIONS[0])
    opts = KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf))
    c = Corrector(gl, Prescription(right=eye, left=eye), "desktop", "right", kernel_options=opts, filter="fft")
    try:
        m = c.model
        grid, margin = c.fft_grid_for((SIZE, SIZE))
        for name, img in images:
            target = decode("srgb", img.astype(np.float32) / 255)
            gpu = run(gl, c, img)
            p = make_problem(target, m.kernel, m.reference)
            found = wiener(p, regularisation=(m.mu_rel,), design=False, grid=grid, margin=margin, descent=False)
            cpu, settings = found.image, found.settings
            assert abs(c.last_blend((SIZE, SIZE)) - settings["beta"]) <= 1e-3, name
            assert np.abs(gpu.astype(int) - to_u8(encode("srgb", cpu)).astype(int)).max() <= 2, name
            shown = decode("srgb", gpu.astype(np.float32) / 255)
            none = objective(target, p)
            assert objective(shown, p) <= none * (1 + 1e-4), name
            if name in PHOTOS:
                assert objective(shown, p) < 0.99 * none, name
    finally:
        c.release()


def test_disabled_is_an_exact_srgb_round_trip(gl, evaluation_corrector, images):
    c = evaluation_corrector
    c.enabled = False
    try:
        for _, img in images[:2]:
            assert np.array_equal(run(gl, c, img), img)
    finally:
        c.enabled = True


def test_zero_prescription_returns_the_input(gl, tmp_path, images):
    path = tmp_path / "rx.json"
    path.write_text(json.dumps(rx_doc(0.0)))
    c = Corrector(gl, path, "quest2", "right",
                  kernel_options=KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf)))
    try:
        assert c.model.identity
        for _, img in images[:2]:
            assert np.abs(run(gl, c, img).astype(int) - img).max() <= 1
    finally:
        c.release()


def test_an_eye_that_focuses_on_the_monitor_by_its_age_gets_frames_as_they_are(gl, tmp_path, images):
    """-1.00 D of sphere alone at the desktop's 0.6 m is 0.67 D from focus on the near side: an eye of 40
    stating no accommodation (6.5 D from its age) focuses it away, and the real-time path passes its
    frames through; the same eye stated as a presbyope (accommodation 0) is corrected."""
    doc = rx_doc(-1.0)
    doc["age_years"] = 40
    path = tmp_path / "rx.json"
    path.write_text(json.dumps(doc))
    c = Corrector(gl, path, "desktop", "right")
    try:
        assert c.model.identity and c.model.eye.accommodation_D == 6.5
        assert any("as well as with its glasses" in n for n in c.model.notes), c.model.notes
        for _, img in images[:2]:
            assert np.abs(run(gl, c, img).astype(int) - img).max() <= 1
    finally:
        c.release()
    for eye in ("right", "left"):
        doc[eye]["accommodation_D"] = 0.0
    path.write_text(json.dumps(doc))
    c = Corrector(gl, path, "desktop", "right")
    try:
        assert not c.model.identity
        assert np.abs(run(gl, c, images[0][1]).astype(int) - images[0][1]).max() > 10
    finally:
        c.release()


def test_no_gpu_allocations_after_warm_up(gl, evaluation_corrector, images):
    c = evaluation_corrector
    img = images[0][1]
    src = G.upload_texture(gl, img)
    tex, fbo = G.render_target(gl, width=SIZE, height=SIZE)
    try:
        c.apply(src, fbo)
        c.simulate(src, fbo)
        c.simulate(src, fbo, corrected=False)
        with count_gl_objects(gl) as made:
            for _ in range(3):
                c.apply(src, fbo)
                c.simulate(src, fbo)
                c.simulate(src, fbo, corrected=False)
        assert made == []
    finally:
        G.release(fbo, tex, src)


def test_live_adjust_and_its_limits(gl, tmp_path):
    path = tmp_path / "rx.json"
    path.write_text(json.dumps(rx_doc(-1.0)))
    c = Corrector(gl, path, "quest2", "left", beta=0.5)
    try:
        c.adjust(sphere_D=-0.25, cylinder_D=-0.5, axis_deg=5)
        assert (c.eye_rx.sphere_D, c.eye_rx.cylinder_D, c.eye_rx.axis_deg) == (-1.25, -0.5, 5.0)
        with pytest.raises(ValidationErrors, match="sphere_D"):
            c.adjust(sphere_D=-100)
        assert c.eye_rx.sphere_D == -1.25                        # kept
        c.adjust(axis_deg=-10)
        assert c.eye_rx.axis_deg == 175.0                        # wraps within [0, 180)
    finally:
        c.release()


def test_correctors_of_a_shared_eye_source_read_the_prescription_from_it(gl, tmp_path):
    """One owner: correctors given the application's EyeSource hold no prescription, file stamp or
    offsets of their own.  They read the source's, install what it designs, and refuse to poll or
    adjust behind its back (ValidationError naming the call)."""
    from vrcorrect.runtime.eye_model import CorrectorOptions
    from vrcorrect.runtime.eye_source import EyeSource

    path = tmp_path / "rx.json"
    path.write_text(json.dumps(rx_doc(-1.0)))
    options = CorrectorOptions(filter="fft", beta=0.5)
    source = EyeSource(path, get_display("quest2"), options)
    right = Corrector(gl, source, "quest2", "right", options=options)
    left = Corrector(gl, source, "quest2", "left", options=options)
    try:
        assert right.source is source and right.prescription is source.prescription and right.rx_path == path
        for name in ("_offset", "_stamp", "_last_poll"):
            assert not hasattr(right, name)
        for call in (right.poll, lambda: right.adjust(sphere_D=0.25)):
            with pytest.raises(ValidationError, match="Corrector"):
                call()
        source.adjust("right", (0.5, 0.0, 0.0))
        assert right.live_offset == (0.0, 0.0, 0.0)          # asked for, not yet designed
        assert source.wait(120)
        updates, messages = source.poll()
        assert messages == [] and [u.eye for u in updates] == ["right"]
        right.install(updates[0].model)
        assert right.eye_rx.sphere_D == -0.5 and right.live_offset == (0.5, 0.0, 0.0)
        assert left.eye_rx.sphere_D == -1.0 and left.live_offset == (0.0, 0.0, 0.0)
        with pytest.raises(ValidationError, match="shared EyeSource"):
            Corrector(gl, EyeSource(path, get_display("quest2"), options, eyes=("left",), worker=False),
                      "quest2", "right", options=options)
        right.release()
        left.release()
        source.adjust("left", (0.25, 0.0, 0.0))              # the application's to close, not a corrector's
        assert source.wait(120) and [u.eye for u in source.poll()[0]] == ["left"]
    finally:
        right.release()
        left.release()
        source.close()


def test_a_prebuilt_eye_model_gives_the_same_correction_and_a_wrong_eye_is_refused(gl, tmp_path, images):
    """``eye_model=``: designed elsewhere (a worker thread), uploaded by the constructor; the same
    frames as a corrector that designs its own.  A model of another eye is refused."""
    from vrcorrect.runtime.corrector import CorrectorOptions, build_eye_model
    from vrcorrect.runtime.rx_snapshot import RxSnapshot

    path = tmp_path / "rx.json"
    doc = rx_doc(-1.5, -0.5, 180)                   # axis 180: the corrector's own build wraps it to 0
    doc["left"] = dict(doc["left"], sphere_D=-3.0)
    path.write_text(json.dumps(doc))
    snapshot = RxSnapshot.read(path)
    display = get_display("quest2")
    options = {"filter": "fista", "iterations_per_frame": 2}
    model = build_eye_model(snapshot.prescription.eye("right"), display, CorrectorOptions(**options))
    img = images[0][1]
    own = Corrector(gl, snapshot, display, "right", **options)
    given = Corrector(gl, snapshot, display, "right", eye_model=model, **options)
    try:
        assert given.model is model and given.rx_path == path
        for _ in range(3):                          # the warm-started frames too
            assert np.array_equal(run(gl, given, img), run(gl, own, img))
        assert given.poll() is False                # watching the file as usual
    finally:
        own.release()
        given.release()
    with pytest.raises(ValidationError, match="eye_model"):
        Corrector(gl, snapshot, display, "left", eye_model=model, **options)


def _touch(path: Path, text: str) -> None:
    path.write_text(text)
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))  # a visible change even on coarse clocks


def test_hot_reload_and_invalid_file_mid_run(gl, tmp_path, images):
    path = tmp_path / "rx.json"
    path.write_text(json.dumps(rx_doc(-1.0)))
    # a filter without memory, so that a frame can be compared with an earlier one (fista's reset
    # on a prescription change: tests/test_runtime_fista.py)
    c = Corrector(gl, path, "quest2", "right", beta=0.5, filter="fft")
    c.source.poll_interval_s = 0.0
    try:
        img = images[0][1]
        first = run(gl, c, img)
        assert c.poll() is False                                  # unchanged file
        _touch(path, json.dumps(rx_doc(-2.0)))
        assert c.poll() is True and c.eye_rx.sphere_D == -2.0 and c.status == ""
        second = run(gl, c, img)
        assert not np.array_equal(first, second)
        _touch(path, '{"schema": "vrcorrect.prescription/1", "right": {"sphere_D": "oops"}')
        assert c.poll() is False
        assert str(path) in c.status and "last good" in c.status
        assert c.eye_rx.sphere_D == -2.0
        assert np.array_equal(run(gl, c, img), second)             # still the last good correction
        _touch(path, json.dumps(rx_doc(-2.0, -1.0, 90)))
        assert c.poll() is True and c.status == "" and c.eye_rx.cylinder_D == -1.0
    finally:
        c.release()


def test_onnx_slot_runs_a_model_on_the_eye_texture(gl, tmp_path, images):
    model = tmp_path / "negate.onnx"
    write_one_minus_x_model(model)                     # y = 1 - x, built with the onnx package
    c = Corrector(gl, SAMPLE_RX, "quest2", "right", backend="onnx", model=str(model))
    try:
        img = images[2][1]
        out = run(gl, c, img)
        expected = to_u8(encode("srgb", 1.0 - decode("srgb", img.astype(np.float32) / 255)))
        assert np.abs(out.astype(int) - expected).max() <= 1
        top = np.zeros_like(img)
        top[:4] = 255                                             # orientation survives the round trip
        assert run(gl, c, top)[:4].max() == 0 and run(gl, c, top)[-4:].min() == 255
    finally:
        c.release()


def test_bad_arguments_are_named(gl, tmp_path):
    with pytest.raises(ValidationError, match="backend"):
        Corrector(gl, SAMPLE_RX, "quest2", "right", backend="cuda")
    with pytest.raises(ValidationError, match="eye"):
        Corrector(gl, SAMPLE_RX, "quest2", "middle")
    with pytest.raises(ValidationError, match="model"):
        Corrector(gl, SAMPLE_RX, "quest2", "right", backend="onnx")
    with pytest.raises(ValidationError, match="beta"):
        Corrector(gl, SAMPLE_RX, "quest2", "right", beta=2.0)


# --------------------------------------------------------------------------
# vrcorrect render
# --------------------------------------------------------------------------


def test_render_command_writes_each_view(tmp_path, images, capsys):
    from PIL import Image

    from vrcorrect.apps.cli import main

    src = tmp_path / "in.png"
    Image.fromarray(images[0][1]).save(src)
    rx = tmp_path / "rx.json"
    rx.write_text(json.dumps(rx_doc(-3.0)))
    outs = {}
    for view in ("corrected", "seen-corrected", "seen-uncorrected"):
        out = tmp_path / f"{view}.png"
        assert main(["render", str(src), "-o", str(out), "--rx", str(rx), "--display", "quest2",
                     "--distance-m", "inf", "--view", view]) == 0
        outs[view] = np.asarray(Image.open(out))
        assert outs[view].shape == images[0][1].shape
    printed = capsys.readouterr().out
    # the default: ADMM, 10 frames of the still picture (a settled view)
    assert "ADMM, 2 iteration(s) per frame, 10 frame(s) warm-started, 4 FFT round trips a frame" in printed
    # the time is told apart: the first frame (its programs' first run on llvmpipe) and the nine after it
    times = re.search(r"10 frame\(s\) ([\d.]+) ms: the first ([\d.]+) ms \(.*\), then ([\d.]+) ms a frame", printed)
    assert times, printed
    total, first, rest = map(float, times.groups())
    assert abs(first + 9 * rest - total) < 0.6, times.group(0)
    assert re.search(r"build [\d.]+ s, 1 frame\(s\) [\d.]+ ms \(incl\. read-back\)", printed), printed  # blur alone
    assert "wrote" in printed
    assert not np.array_equal(outs["corrected"], images[0][1])
    assert not np.array_equal(outs["seen-corrected"], outs["seen-uncorrected"])


@pytest.mark.parametrize("method", ["admm", "fista", "fft"])
def test_render_command_states_each_setting_once(method, tmp_path, images, capsys):
    """Issue 26: the settings line and the eye model's note said the same settings twice."""
    from PIL import Image

    from vrcorrect.apps.cli import main

    src = tmp_path / "in.png"
    Image.fromarray(images[0][1]).save(src)
    assert main(["render", str(src), "-o", str(tmp_path / "out.png"), "--filter", method, "--frames", "1"]) == 0
    printed = capsys.readouterr().out
    if method == "fft":
        assert printed.count("regulariser") == 1 and printed.count("blend") == 1, printed
        assert "chosen by wiener" in printed                        # how they were chosen is still said
    else:
        assert printed.count("iteration(s) per frame") == 1, printed
    if method == "admm":
        assert "half precision" in printed


def test_render_command_errors_are_one_line(tmp_path, images, capsys):
    from PIL import Image

    from vrcorrect.apps.cli import main

    src = tmp_path / "in.png"
    Image.fromarray(images[0][1]).save(src)
    out = tmp_path / "out.png"
    out.write_bytes(b"keep me")
    assert main(["render", str(src), "-o", str(out)]) == 2                       # no overwrite
    assert out.read_bytes() == b"keep me"
    assert main(["render", str(src), "-o", str(tmp_path / "o.png"), "--backend", "onnx", "--model",
                 str(tmp_path / "no.onnx")]) == 2
    assert main(["render", str(src), "-o", str(tmp_path / "o.png"), "--display", "crt"]) == 2
    assert main(["render", str(tmp_path / "missing.png"), "-o", str(tmp_path / "o.png")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "--model" in err and "transfer" in err and "missing.png" in err
    assert not (tmp_path / "o.png").exists()
