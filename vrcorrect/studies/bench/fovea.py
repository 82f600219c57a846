"""``vrcorrect bench fovea``: what correcting only where the eye looks costs and keeps.

The real-time default's frame (ADMM over frames) solved on the whole view against the same frame
solved on a window around the gaze (:mod:`vrcorrect.solvers.foveated`, the CPU twin the GPU's
foveated frame equals, ``tests/test_runtime_fovea.py``), for window radii :data:`RADII_DEG` and
iterations per frame :data:`ITERATIONS`, on images the foveation was never tuned on (nothing in it
was tuned on an image: the ring is the kernel's radius; the blend band lies beyond the fovea's
radius, a tenth of it, set by the bytes of a Quest 2 eye at 15 degrees, not by a score):
scikit-image's stereo_motorcycle and rocket (colour photographs) and page (a scanned page of text,
grey paper), each centre-cropped and scaled to the view.  The view is :data:`VIEW` px square on ``quest2`` (18.9 px a degree:
51 degrees); the eye is the issue's (right, -2.00/-1.00 x 120) through a 3 mm pupil, a headset's
(Watson & Yellott 2012).  Each still is shown for :data:`FRAMES` frames (178 ms at 90 Hz, about a
fixation) from a cold start, as after a saccade or a cut.

What the eye sees of each is scored against the glasses-on view:

* **FovVideoVDP** (:func:`~vrcorrect.vision.vdp.foveated_jod`, foveated mode) with the eye
  fixating the window's centre, and fixating :data:`OFF_DEG` degrees to its right (the tracker's
  error, or a fixed window and a wandering eye), each against no correction and the full field;
* **ColorVideoVDP** (:func:`~vrcorrect.vision.vdp.jod`) on the window's crop (the fovea's
  radius, without the band beyond it; foveated against
  the full field there) and on the view's strips left and right of the window (foveated against no
  correction there: the view outside the window is the target, only the light the window spills
  changes it);
* beside them, on the whole view, **FLIP** (:func:`~vrcorrect.vision.metrics.flip`, lower is better) and
  the **objective** (the cone images' error, as a fraction of no correction's): a metric's verdict
  is read with the physics', never alone.

With ``video``, the three held-out clips (:func:`~vrcorrect.studies.bench.sequences.held_out`:
pictures and words the project never tuned on; a colour wheel sliding over the rocket, light text on
dark blue scrolling, and a pan across the rocket cut half-way to a microscope slide; :data:`VIDEO_CLIPS`), each
:data:`VIDEO_FRAMES` frames at the same view, are played through the full field's and the
:data:`CHECK_RADIUS_DEG` window's twins as ``vrcorrect render`` plays a clip (the content's motion
reprojects the warm start; a cut starts cold) and judged as video: FovVideoVDP in video mode
(:func:`~vrcorrect.vision.vdp.foveated_video_jod`) fixating the centre and :data:`OFF_DEG` off,
and the frames' mean FLIP.

Cost: the bytes of a changing frame counted from the GPU's dispatches (a dry run: nothing runs) at a
Quest 2 eye, 1832x1920, and the frame's wall time on this machine's OpenGL renderer at the bench's
view (the median of :data:`TIMED_FRAMES` frames after two untimed ones; on llvmpipe a measurement of
CPU cores, not of a GPU).  A table and a plot go into ``docs/benchmarks.md``.  Layer 6.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from ...physics.kernel import build_kernel, build_reference_kernel
from ...plumbing.errors import ValidationError
from ...runtime.strategies.foveated import DEFAULT_PERIPHERY, PERIPHERY_ITERATIONS
from ...solvers.foveated import (
    COLD_PERIPHERY_ITERATIONS,
    COLD_WINDOW_ITERATIONS,
    PERIPHERIES,
    FoveatedFrames,
    fovea_pixels,
)
from ...solvers.realtime import AdmmFrames
from ...specs.display import decode, get_display
from ...specs.prescription import EyeRx, Prescription
from ...specs.vocabulary import Periphery, names, one_of
from ...vision.metrics import evaluate_seen, flip
from ...vision.vdp import foveated_jod, foveated_video_jod, jod
from . import machine_description, markdown_table, publish

__all__ = ["RADII_DEG", "ITERATIONS", "VIEW", "FRAMES", "OFF_DEG", "EYE", "IMAGES", "run_fovea_bench"]

RADII_DEG = (5.0, 10.0, 15.0, 20.0)
"""Window radii (degrees). 30 degrees would be the whole of the bench's 51 degree view."""
ITERATIONS = (1, 2, 4)
DEFAULT_ITERATIONS = 2
VIEW = 960
FRAMES = 16
OFF_DEG = 10.0
TIMED_FRAMES = 3
QUEST2_EYE = (1832, 1920)
EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=3.0)
IMAGES = ("motorcycle", "rocket", "page")
CHECK_RADIUS_DEG = 15.0
VIDEO_CLIPS = ("sprite", "text", "cut")
"""The held-out clips played with ``video`` (:func:`video_cases`; of
:data:`~vrcorrect.studies.bench.sequences.HELD_OUT`)."""
VIDEO_FRAMES = 30
"""Frames a clip (a third of a second at 90 Hz; the cut falls half-way)."""
VIDEO_FPS = 90.0


def bench_image(name: str, size: int) -> np.ndarray:
    """A bench image, sRGB code values ``(size, size, 3)``."""
    if name == "chart":
        from ...plumbing.charts import (
            text_chart,  # on use: start-up time (the CLI imports the studies to build its parser)
        )
        from ...plumbing.images import (
            prepare_image,  # on use: start-up time (the CLI imports the studies to build its parser)
        )

        return prepare_image(text_chart(size, size), size, "chart")
    from .robust import held_out_image  # on use: start-up time (the CLI imports the studies to build its parser)

    return held_out_image(name, size)


def _frames(twin: Any, target: np.ndarray, k: int, frames: int, **kwargs: Any) -> tuple[np.ndarray, Any]:
    out = None
    for _ in range(frames):
        out = twin.frame(target, k, **kwargs)
    return np.clip(out.shown, 0.0, 1.0), out


def _gl_costs(radius: float | None, k: int, periphery: str, view: tuple[int, int], counted: tuple[int, int],
              timed: bool) -> dict[str, Any]:
    """The bytes of a changing frame of ``counted`` size (a dry run: nothing runs) and, when ``timed``,
    the frame's wall time at ``view`` on this machine's renderer (the median of :data:`TIMED_FRAMES`
    after one untimed)."""
    from ...runtime.corrector import (
        Corrector,  # on use: start-up time (the CLI imports the studies to build its parser)
    )
    from ...runtime.gl import (  # on use: start-up time (the CLI imports the studies to build its parser)
        headless_context,
        release,
        render_target,
        upload_texture,
        write_texture,
    )
    from .cost import eye_frame_cost  # on use: start-up time (the CLI imports the studies to build its parser)

    ctx = headless_context(require=430)
    rng = np.random.default_rng(5)
    rx = Prescription(right=EYE, left=EYE)
    options = {"iterations_per_frame": k, "early_stop": False, "cold_iterations": 0,
               **({} if radius is None else {"fovea_deg": radius, "fovea_periphery": periphery})}
    result: dict[str, Any] = {"renderer": ctx.info.get("GL_RENDERER", "?"), "ms": None}
    try:
        result["bytes"] = eye_frame_cost(ctx, rx, "quest2", "right", counted, options, dry_run=True).changing.bytes
        if timed:
            W, H = view
            c = Corrector(ctx, rx, "quest2", "right", **options)
            pictures = [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)]
            src = upload_texture(ctx, pictures[0])
            tex, fbo = render_target(ctx, width=W, height=H)
            try:
                write_texture(src, pictures[1])
                c.apply(src, fbo)                           # the cold frame, untimed
                times = []
                for i in range(TIMED_FRAMES):
                    write_texture(src, pictures[i % 2])
                    ctx.finish()
                    t0 = time.perf_counter()
                    c.apply(src, fbo)
                    ctx.finish()
                    times.append(1e3 * (time.perf_counter() - t0))
                result["ms"] = statistics.median(times)
            finally:
                c.release()
                release(fbo, tex, src)
    finally:
        ctx.release()
    return result


def _inset(win: tuple[int, int, int, int], band: int, view: int) -> tuple[int, int, int, int]:
    """The window solved, less its blend band along the edges inside the view: the fovea's radius."""
    y0, y1, x0, x1 = win
    return (y0 + band if y0 > 0 else 0, y1 - band if y1 < view else view,
            x0 + band if x0 > 0 else 0, x1 - band if x1 < view else view)


def settings_of(radii: Sequence[float], iterations: Sequence[int]) -> list[tuple[int, float | None, str]]:
    """The settings run per image, ``(iterations a frame, radius or None for the full field,
    periphery)``: every radius with every periphery at the default iterations; the full field and
    :data:`CHECK_RADIUS_DEG` with the default periphery at the other iterations."""
    out: list[tuple[int, float | None, str]] = []
    for k in iterations:
        out.append((k, None, "-"))
        if k == DEFAULT_ITERATIONS:
            out += [(k, r, p) for r in radii for p in PERIPHERIES]
        elif CHECK_RADIUS_DEG in radii:
            out.append((k, CHECK_RADIUS_DEG, DEFAULT_PERIPHERY))
    return out


def run_fovea_bench(out: Path, write: bool = True, plot: Path | None = None, json_out: Path | None = None,
                    force: bool = False, images: Sequence[str] = IMAGES, radii: Sequence[float] = RADII_DEG,
                    iterations: Sequence[int] = ITERATIONS, view: int = VIEW, frames: int = FRAMES,
                    video: bool = False, video_clips: Sequence[str] = VIDEO_CLIPS,
                    video_frames: int | None = None) -> dict[str, Any]:
    """Run the bench (module docstring; ``video``: also the clips); returns the report (with
    ``markdown``), writes the ``fovea`` section of ``out``, the plot and, with ``json_out``, the JSON."""
    display = get_display("quest2")
    ppd = float(display.pixels_per_degree)
    K, R = build_kernel(EYE, display), build_reference_kernel(EYE, display)
    shape = (view, view)
    centre = (view / 2.0, view / 2.0)
    off = (view / 2.0 + OFF_DEG * ppd, view / 2.0)
    t_start = time.perf_counter()
    settings = settings_of(radii, iterations)
    cases = []
    with tqdm(total=(2 + len(images)) * len(settings), desc="bench fovea", unit="setting", leave=False) as bar:
        costs = {}
        for k, r, p in settings:
            costs[(k, r, p)] = _gl_costs(r, k, p, (view, view), QUEST2_EYE, timed=k == DEFAULT_ITERATIONS)
            bar.update(2)
        for name in images:
            target = decode(display, bench_image(name, view)).astype(np.float32)

            none_metrics, none = evaluate_seen(target, target, K, display, reference_kernel=R, with_jod=False)
            base = {"centre": foveated_jod(none["target_srgb"], none["seen_srgb"], display, centre),
                    "off": foveated_jod(none["target_srgb"], none["seen_srgb"], display, off)}
            rows = []
            full_images: dict[int, dict[str, np.ndarray]] = {}
            for k, r, p in settings:
                if r is None:
                    shown, _ = _frames(AdmmFrames(K, R, shape), target, k, frames)
                    window = (0, view, 0, view)
                else:
                    radius_px, band_px = fovea_pixels(r, ppd)
                    twin = FoveatedFrames(K, R, shape, radius_px=radius_px, band_px=band_px, periphery=p,
                                          periphery_iterations=PERIPHERY_ITERATIONS.get(p))
                    shown, last = _frames(twin, target, k, frames, gaze_px=centre)
                    window = _inset(last.window.win, band_px, view)        # the fovea's radius: no band
                metrics, s = evaluate_seen(shown, target, K, display, reference_kernel=R, with_jod=False)
                c = costs[(k, r, p)]
                row = {"radius_deg": r, "iterations": k, "periphery": p, "window": list(window),
                       "fov_jod_centre": foveated_jod(s["target_srgb"], s["seen_srgb"], display, centre),
                       "fov_jod_off": foveated_jod(s["target_srgb"], s["seen_srgb"], display, off),
                       "flip": metrics.flip, "objective_fraction": metrics.objective / none_metrics.objective
                       if none_metrics.objective > 0 else float("nan"),
                       "bytes_quest2_eye": c["bytes"], "ms_view": c["ms"]}
                if r is None:
                    full_images[k] = s
                elif k == DEFAULT_ITERATIONS and r == CHECK_RADIUS_DEG and window != (0, view, 0, view):
                    y0, y1, x0, x1 = window
                    f = full_images[k]
                    row["crop_jod"] = jod(s["target_srgb"][y0:y1, x0:x1], s["seen_srgb"][y0:y1, x0:x1], display)
                    row["crop_jod_full"] = jod(f["target_srgb"][y0:y1, x0:x1], f["seen_srgb"][y0:y1, x0:x1], display)
                    strips = [(a, b) for a, b in ((0, x0), (x1, view)) if b - a >= 32]
                    row["outside_jod"] = [jod(s["target_srgb"][:, a:b], s["seen_srgb"][:, a:b], display)
                                          for a, b in strips]
                    row["outside_jod_none"] = [jod(none["target_srgb"][:, a:b], none["seen_srgb"][:, a:b], display)
                                               for a, b in strips]
                rows.append(row)
                bar.update()
            base["flip"] = none_metrics.flip
            cases.append({"image": name, "none": base, "rows": rows})
    video_rows = video_cases(display, K, R, view, VIDEO_FRAMES if video_frames is None else video_frames,
                             video_clips) if video else []
    report = {"machine": machine_description(), "renderer": costs[settings[0]]["renderer"],
              "view": view, "ppd": ppd, "frames": frames, "off_deg": OFF_DEG, "eye": "right, -2.00/-1.00 x 120",
              "periphery_iterations": PERIPHERY_ITERATIONS, "seconds": time.perf_counter() - t_start, "cases": cases,
              "video": video_rows}
    report["markdown"] = _markdown(report)
    if plot is not None and write:
        _plot(report, plot)
    return publish(report, "fovea", out, write, json_out, force)


def _play(twin: Any, frames: Sequence[np.ndarray], motions: Sequence[Any], k: int, **kwargs: Any) -> list[np.ndarray]:
    """``frames`` (linear) through ``twin`` as ``vrcorrect render`` plays a clip: the estimated motion
    reprojects the warm start, a cut starts cold; the frames shown."""
    shown = []
    for i, frame in enumerate(frames):
        m = None if i == 0 else motions[i - 1]
        cut = m == "cut"
        out = twin.frame(frame, k, shift=None if (cut or m is None) else m, cold=cut, **kwargs)
        shown.append(np.clip(out.shown, 0.0, 1.0))
    return shown


def video_cases(display: Any, K: Any, R: Any, view: int, frames: int, clips: Sequence[str] = VIDEO_CLIPS,
                radius: float = CHECK_RADIUS_DEG, k: int = DEFAULT_ITERATIONS,
                periphery: str | None = None) -> list[dict[str, Any]]:
    """The clips (module docstring): for each, no correction, the full field and the ``radius``
    window (``periphery``; None: the default), judged as video against the glasses-on view."""
    from ...specs.display import encode  # on use: start-up time (the CLI imports the studies to build its parser)
    from ...vision.forward import (  # on use: start-up time (the CLI imports the studies to build its parser)
        lms_to_display,
        simulate_lms,
    )
    from .realtime import _motions, linear  # on use: start-up time (the CLI imports the studies to build its parser)
    from .sequences import HELD_OUT, held_out  # on use: start-up time (the CLI imports the studies to build its parser)

    for name in clips:
        if name not in HELD_OUT:
            raise ValidationError("clips", name, "held-out clips: " + ", ".join(HELD_OUT))
    periphery = DEFAULT_PERIPHERY if periphery is None else periphery
    if periphery not in names(Periphery):
        raise ValidationError("periphery", periphery, one_of(Periphery))

    def seen(kernel: Any, x: np.ndarray) -> np.ndarray:       # what the eye sees, in K's display RGB, sRGB
        return np.clip(encode("srgb", lms_to_display(simulate_lms(x, kernel)[0], K)), 0.0, 1.0)

    ppd = float(display.pixels_per_degree)
    shape = (view, view)
    centre, off = (view / 2.0, view / 2.0), (view / 2.0 + OFF_DEG * ppd, view / 2.0)
    radius_px, band_px = fovea_pixels(radius, ppd)
    rows = []
    made = {c.name: c for c in held_out(view, frames)}
    chosen = [made[name] for name in clips]
    for clip in tqdm(chosen, desc="bench fovea: clips", unit="clip", leave=False):
        lin = [linear(f) for f in clip.frames]
        motions = _motions(clip.frames)
        ref = [seen(R, x) for x in lin]
        fov = FoveatedFrames(K, R, shape, radius_px=radius_px, band_px=band_px, periphery=periphery,
                             periphery_iterations=PERIPHERY_ITERATIONS.get(periphery))
        runs = {"none": lin, "full": _play(AdmmFrames(K, R, shape), lin, motions, k),
                "foveated": _play(fov, lin, motions, k, gaze_px=centre)}
        row: dict[str, Any] = {"clip": clip.name, "what": clip.what, "frames": len(lin)}
        for name, shown in runs.items():
            eye = [seen(K, x) for x in shown]
            row[name] = {"centre": foveated_video_jod(ref, eye, display, centre, VIDEO_FPS),
                         "off": foveated_video_jod(ref, eye, display, off, VIDEO_FPS),
                         "flip": float(np.mean([flip(a, b, ppd)[0] for a, b in zip(ref, eye)]))}
        rows.append(row)
    return rows


def _setting(r: float | None) -> str:
    return "off (full field)" if r is None else f"{r:g} deg"


def _share(row: dict, full: dict, none: dict, where: str) -> float:
    gain = full[f"fov_jod_{where}"] - none[where]
    return (row[f"fov_jod_{where}"] - none[where]) / gain if gain > 1e-9 else float("nan")


def _full(case: dict, k: int) -> dict:
    return next(r for r in case["rows"] if r["radius_deg"] is None and r["iterations"] == k)


def checks(report: dict) -> list[dict[str, Any]]:
    """Issue 45's bars at :data:`CHECK_RADIUS_DEG` and the default iterations, per image and periphery."""
    out = []
    for case in report["cases"]:
        full = _full(case, DEFAULT_ITERATIONS)
        for row in case["rows"]:
            if row["radius_deg"] != CHECK_RADIUS_DEG or row["iterations"] != DEFAULT_ITERATIONS:
                continue
            out.append({"image": case["image"], "periphery": row["periphery"],
                        "delta_centre": row["fov_jod_centre"] - full["fov_jod_centre"],
                        "share_off": _share(row, full, case["none"], "off"),
                        "crop_delta": row.get("crop_jod", float("nan")) - row.get("crop_jod_full", float("nan")),
                        "outside_least": min((a - b for a, b in zip(row.get("outside_jod", []),
                                                                    row.get("outside_jod_none", []))),
                                             default=float("nan")),
                        "flip_delta": row["flip"] - full["flip"],
                        "bytes": row["bytes_quest2_eye"]})
    return out


def _periphery(p: str, report: dict) -> str:
    if p == "-":
        return "-"
    k = report["periphery_iterations"].get(p)
    return "the target" if p == "target" else f"{p} resolution, {k} iteration{'s' if k != 1 else ''}"


def _markdown(report: dict) -> str:
    view, ppd = report["view"], report["ppd"]
    parts = [
        "## Correct where the eye looks: foveated correction (`vrcorrect bench fovea`)\n\n"
        f"Machine: {report['machine']}; OpenGL renderer: {report['renderer']}. {len(report['cases'])} image(s) in "
        f"{report['seconds'] / 60:.0f} min. The real-time default's frame (ADMM over frames; its CPU twin, which the "
        "GPU's frame equals) on the whole view, and on a window of each radius around the gaze with the view outside "
        "it either the target itself or a correction of the whole view at half or a quarter of the resolution "
        f"(the periphery). Each still is shown for {report['frames']} frames from a cold start (178 ms at 90 Hz, "
        f"about a fixation). A {view}x{view} view on quest2 ({ppd:.2f} px a degree: {view / ppd:.0f} degrees); the "
        f"eye {report['eye']} through a 3 mm pupil, a headset's. Images: scikit-image's stereo_motorcycle and rocket "
        "(photographs) and page (scanned text), none used to choose anything in the foveation. Judged on what the eye "
        "sees against its glasses-on view: FovVideoVDP (foveated JOD) with the eye fixating the window's centre and "
        f"fixating {report['off_deg']:g} degrees to its right; ColorVideoVDP on the window's crop and on the strips of "
        "the view left and right of it.\n\n"
        "Bytes: a changing frame of the GPU's path at a Quest 2 eye (1832x1920), counted from its dispatches (a dry "
        "run). ms: the GPU path's frame, wall time at the bench's view on "
        f"{report['renderer']} at {DEFAULT_ITERATIONS} iterations a frame (the median of {TIMED_FRAMES} after one "
        f"untimed; on llvmpipe, CPU cores, not a GPU). The default periphery is {DEFAULT_PERIPHERY} resolution.\n"]
    checked = checks(report)
    if checked:
        parts.append(f"\n### The checks ({CHECK_RADIUS_DEG:g} degrees, {DEFAULT_ITERATIONS} iterations a frame)\n\n"
                     "Issue 45's bars: within 0.2 JOD of the full field (FovVideoVDP, fixating the window's centre); "
                     f"fixating {report['off_deg']:g} degrees off, at least 50 % of the full field's gain over no "
                     "correction; inside the window within 0.1 JOD of the full field (ColorVideoVDP on the crop); "
                     "outside it never below no correction; at most 0.5 GB a Quest 2 eye frame.\n\n"
                     + markdown_table(["image", "periphery", "foveated - full, at the centre",
                                       f"share of the full field's gain, {report['off_deg']:g} deg off",
                                       "window crop: foveated - full", "outside: least foveated - none",
                                       "FLIP: foveated - full (lower is better)", "GB a Quest 2 eye frame"],
                                      [[c["image"], _periphery(c["periphery"], report), f"{c['delta_centre']:+.2f}",
                                        f"{100 * c['share_off']:.0f} %", f"{c['crop_delta']:+.2f}",
                                        f"{c['outside_least']:+.2f}", f"{c['flip_delta']:+.3f}",
                                        f"{c['bytes'] / 1e9:.2f}"] for c in checked])
                     + "\n")
    for case in report["cases"]:
        none = case["none"]
        rows = []
        for r in case["rows"]:
            f = _full(case, r["iterations"])
            rows.append([_setting(r["radius_deg"]), _periphery(r["periphery"], report), r["iterations"],
                         f"{r['bytes_quest2_eye'] / 1e9:.2f}",
                         "-" if r["ms_view"] is None else f"{r['ms_view']:.0f}", f"{r['fov_jod_centre']:.2f}",
                         f"{r['fov_jod_centre'] - none['centre']:+.2f}", f"{r['fov_jod_off']:.2f}",
                         f"{100 * _share(r, f, none, 'off'):.0f} %", f"{r['flip']:.3f}",
                         f"{100 * r['objective_fraction']:.0f} %"])
        parts.append(f"\n### {case['image']}\n\nNo correction: FovVideoVDP {none['centre']:.2f} fixating the centre, "
                     f"{none['off']:.2f} fixating {report['off_deg']:g} deg off; FLIP {none['flip']:.3f}.\n\n"
                     + markdown_table(["fovea radius", "periphery", "iterations a frame", "GB a Quest 2 eye frame",
                                       f"ms a frame at {view} px (this renderer)", "FovVideoVDP, centre",
                                       "gain over none", f"FovVideoVDP, {report['off_deg']:g} deg off",
                                       "share of the full field's gain, off", "FLIP",
                                       "objective (of no correction's)"], rows) + "\n")
    if report.get("video"):
        rows = []
        for v in report["video"]:
            n, full, fov = v["none"], v["full"], v["foveated"]
            gain_off = full["off"] - n["off"]
            rows.append([v["clip"], f"{n['centre']:.2f}", f"{full['centre']:.2f}", f"{fov['centre']:.2f}",
                         f"{fov['centre'] - full['centre']:+.2f}", f"{n['off']:.2f}", f"{full['off']:.2f}",
                         f"{fov['off']:.2f}",
                         f"{100 * (fov['off'] - n['off']) / gain_off:.0f} %" if gain_off > 1e-9 else "-",
                         f"{n['flip']:.3f} / {full['flip']:.3f} / {fov['flip']:.3f}"])
        frames = report["video"][0]["frames"]
        parts.append(f"\n### As video: held-out clips at a {CHECK_RADIUS_DEG:g} degree window\n\n"
                     f"Clips the project never tuned on (the held-out set: {'; '.join(v['what'] for v in report['video'])}), "
                     f"{frames} frames each at 90 Hz on the same view, played as `vrcorrect render` plays them "
                     "(the content's motion reprojects the warm start, a cut starts cold), the window's periphery "
                     f"{DEFAULT_PERIPHERY} resolution, {DEFAULT_ITERATIONS} iterations a frame (a cold frame, the first "
                     f"and after a cut: the window {COLD_WINDOW_ITERATIONS} more, the periphery "
                     f"{COLD_PERIPHERY_ITERATIONS}). FovVideoVDP in video "
                     f"mode fixating the window's centre and {report['off_deg']:g} degrees off; FLIP the frames' "
                     "mean (lower is better).\n\n"
                     + markdown_table(["clip", "none, centre", "full, centre", "foveated, centre",
                                       "foveated - full, centre", f"none, {report['off_deg']:g} deg off",
                                       "full, off", "foveated, off", "share of the full field's gain, off",
                                       "FLIP: none / full / foveated"], rows) + "\n")
    parts.append("\n![Foveated JOD against the window's radius, by periphery](fovea_tradeoff.png)\n")
    return "".join(parts)                      # the date: write_section's line


def _plot(report: dict, path: Path) -> None:
    from ..plots import pyplot, save_figure  # on use: start-up time (the CLI imports the studies to build its parser)

    plt = pyplot()
    cases = report["cases"]
    fig, axes = plt.subplots(1, len(cases), figsize=(5.0 * len(cases), 3.8), squeeze=False)
    colours = {"target": "tab:red", "half": "tab:blue", "quarter": "tab:green"}
    for ax, case in zip(axes[0], cases):
        rows = [r for r in case["rows"] if r["iterations"] == DEFAULT_ITERATIONS]
        full = _full(case, DEFAULT_ITERATIONS)
        for p, colour in colours.items():
            fov = [r for r in rows if r["periphery"] == p]
            if not fov:
                continue
            x = [r["radius_deg"] for r in fov]
            ax.plot(x, [r["fov_jod_centre"] for r in fov], color=colour, marker="o", ms=3,
                    label=f"periphery: {_periphery(p, report)}")
            ax.plot(x, [r["fov_jod_off"] for r in fov], color=colour, ls=":", marker="s", ms=3)
        ax.axhline(full["fov_jod_centre"], color="k", lw=0.9, label="full field")
        ax.axhline(case["none"]["centre"], color="0.5", lw=0.9, ls="--", label="no correction")
        ax.set_xlabel(f"fovea radius (degrees); dotted: fixating {report['off_deg']:g} deg off")
        ax.set_ylabel("FovVideoVDP (JOD)")
        ax.set_title(case["image"], fontsize=9)
    axes[0][0].legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, path)
