"""``vrcorrect bench render``: milliseconds per frame of the real-time path for two eyes.

Two 1832 x 1920 eyes (Quest 2 panels) with the bundled sample prescription, on a headless
EGL context (Mesa llvmpipe on a machine without a GPU; the GPU's own driver where there is
one).  Each case runs both eyes' ``Corrector`` on a static frame: warm-up first (kernel,
regulariser choice, the FFT grid's spectra, GPU allocations), then the median of
``repeats`` frames, each ended by ``glFinish`` so the wall clock holds the GPU's work.

Cases: passthrough (sRGB decode + encode: the floor every frame pays), the default GLSL
correction, projected gradient (``filter="fista"``, k = 4 iterations a frame: 2k + 3 = 11 FFT
round trips and a reduction), ``wiener``'s one-pass inverse by FFT with the per-frame blend
(``filter="fft"``: 4 FFT filterings and a reduction), the same with
the blend fixed at build time, the eye's forward model (simulation, for previews), the ONNX slot with
a trivial graph (``1 - x``: the read-back, onnxruntime call and upload the learned model
will pay on top of its own cost), and the separable low-rank strategy at a smaller size for
comparison (its cost grows with filter width x rank).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ...plumbing.charts import siemens_star
from ...runtime.corrector import Corrector
from ...runtime.gl import headless_context, release, render_target, upload_texture
from ...runtime.onnx_backend import write_one_minus_x_model
from ...specs.prescription import bundled_sample_path, load_prescription
from ...specs.vocabulary import VIEW_ORDER, Backend
from . import machine_description, markdown_table, write_section

EYE_SIZE = (1832, 1920)                          # width, height of one Quest 2 eye
SEPARABLE_SIZE = (256, 256)


def _frame_image(width: int, height: int) -> np.ndarray:
    star = siemens_star(min(width, height))
    img = np.zeros((height, width, 3), np.float32)
    h, w = star.shape[:2]
    img[:h, :w] = star if star.ndim == 3 else star[..., None]
    img[:, w:] = np.linspace(0, 1, width - w, dtype=np.float32)[None, :, None] if width > w else 0
    return np.round(img * 255).astype(np.uint8)


def _time_frames(ctx, correctors, src, fbos, how: str, repeats: int) -> list[float]:
    def frame():
        for c, fbo in zip(correctors, fbos):
            if how == "simulate":
                c.simulate(src, fbo, corrected=False)
            else:
                c.apply(src, fbo)
        ctx.finish()

    frame()                                      # warm-up: per-size spectra and allocations
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        frame()
        times.append(time.perf_counter() - t0)
    return times


def run_render_bench(repeats: int = 5, out: Path = Path("docs/benchmarks.md"), write: bool = True,
                     size: tuple[int, int] = EYE_SIZE) -> str:
    """Measure every case; returns the Markdown (and writes the ``render`` section of ``out``)."""

    ctx = headless_context(require=430)
    renderer = ctx.info.get("GL_RENDERER", "?")
    rx = load_prescription(bundled_sample_path())
    W, H = size
    rows = []
    tmp = tempfile.TemporaryDirectory()
    model = Path(tmp.name) / "one_minus_x.onnx"
    write_one_minus_x_model(model)
    cases = [("passthrough (decode + encode)", "apply", dict(), size, False),
             ("GLSL correction, projected gradient k = 4 (default)", "apply", dict(), size, True),
             ("GLSL correction, FFT one pass, per-frame blend", "apply", dict(filter="fft"), size, True),
             ("GLSL correction, FFT one pass, fixed blend", "apply", dict(filter="fft", blend="fixed"), size, True),
             ("simulation (forward model, FFT)", "simulate", dict(), size, True),
             ("ONNX slot, trivial graph", "apply", dict(backend=Backend.ONNX, model=str(model)), size, True),
             (f"GLSL correction, separable, {SEPARABLE_SIZE[0]}x{SEPARABLE_SIZE[1]}", "apply",
              dict(filter="separable"), SEPARABLE_SIZE, True)]
    base_ms = None
    try:
        for label, how, options, (w, h), enabled in tqdm(cases, desc="bench render", unit="case", leave=False):
            src = upload_texture(ctx, _frame_image(w, h))
            targets = [render_target(ctx, width=w, height=h) for _ in range(2)]
            t0 = time.perf_counter()
            correctors = [Corrector(ctx, rx, "quest2", eye, **options) for eye in VIEW_ORDER]
            build_s = time.perf_counter() - t0
            for c in correctors:
                c.enabled = enabled
            reps = repeats if (w, h) == size or w * h < 300_000 else max(1, repeats // 2)
            times = _time_frames(ctx, correctors, src, [fb for _, fb in targets], how, reps)
            ms = 1e3 * statistics.median(times)
            if base_ms is None:
                base_ms = ms
            same = (w, h) == (W, H)
            ratio = f"{ms / base_ms:.1f}" if same else "-"
            info = correctors[1].describe()
            if "ranks" in info:
                what = f"width {info['filter_size']}, ranks {info['ranks']}, {info['taps_per_pixel']} taps/px"
            elif options.get("backend") == Backend.ONNX:
                what = "read back, onnxruntime (CPU), upload"
            elif how == "simulate":
                grid = correctors[1].fft_grid_for((w, h))[0]
                what = f"kernel {info['kernel_size']} px, FFT grid {grid[1]}x{grid[0]}"
            elif enabled and info.get("filter") == "fista":
                grid = correctors[1].fft_grid_for((w, h))[0]
                fraction = correctors[1].last_objective_fraction((w, h))
                what = (f"FFT grid {grid[1]}x{grid[0]}, {info['iterations_per_frame']} iterations a frame, "
                        f"warm-started (right eye's objective {fraction:.3f} of uncorrected at the last frame)")
            elif enabled:
                grid = correctors[1].fft_grid_for((w, h))[0]
                beta = correctors[1].last_blend((w, h))
                blend = (f"blend per frame on the GPU (right eye: {beta:.2f})" if beta is not None
                         else f"blend fixed at {info['beta']:.2f} (right eye)")
                what = (f"FFT grid {grid[1]}x{grid[0]} (log2 {int(np.log2(max(grid)))} stages), regulariser "
                        f"{info['mu_rel']:g}, {blend}")
            else:
                what = "-"
            rows.append([label, f"{w}x{h}", f"{ms:.1f}", f"{min(times) * 1e3:.1f}-{max(times) * 1e3:.1f}", ratio,
                         f"{build_s:.1f}", what])
            for c in correctors:
                c.release()
            for tex, fb in targets:
                release(fb, tex)
            release(src)
    finally:
        tmp.cleanup()
        ctx.release()
    left, right = rx.left, rx.right
    body = (
        "## Real-time path: two eyes per frame\n\n"
        f"Machine: {machine_description()}; OpenGL renderer: {renderer}.\n"
        f"Prescription: the bundled sample (right {right.sphere_D:+.2f} / {right.cylinder_D:+.2f} x {right.axis_deg:g}, "
        f"left {left.sphere_D:+.2f} / {left.cylinder_D:+.2f} x {left.axis_deg:g}, 4 mm pupils), display Quest 2 "
        f"at its own focal distance. Each frame runs both eyes and ends with glFinish; median of {repeats} "
        "frames after one warm-up frame (fewer at large sizes for slow cases). `build` is the two correctors' "
        "construction (kernel, regulariser and blend chosen on the sample image); the FFT spectra for a new "
        "image size are made in the warm-up frame.\n\n"
        + markdown_table(["case", "per eye", "ms / frame (2 eyes)", "range ms", "x passthrough", "build s",
                          "what it runs"], rows)
        + "\n\nThe GLSL correction's cost per pixel is O(log N) (N: the FFT grid) for any prescription; the "
        "separable strategy's grows with filter width x rank. On llvmpipe (2 CPU cores) these are "
        "seconds per frame, far from real time: the figures that matter for a headset come from a GPU.\n"
    )
    if write:
        write_section(out, "render", body)
    return body
