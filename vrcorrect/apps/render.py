"""``vrcorrect render``: frames of an image through the real-time GL pipeline (headless EGL), the
last one written: what the headset would show, or what the eye sees of it.  A clip (a folder of
frames, an animated image, a video) is played through it at the headset's rate (``--fps``), the
warm start carried from frame to frame, and every frame written to a folder."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import check_readable, check_writable
from ..plumbing.imageio import read_image, write_png
from ..runtime.model_path import model_for_backend
from ..specs.prescription import load_prescription
from ..specs.vocabulary import ITERATIVE_FILTERS, Backend, Filter
from . import clips
from .common import add_model_options, check_not_input, kernel_options, print_notes, rx_path, small_image_note
from .progress import Progress, duration_text
from .realtime_options import (
    add_backend_option,
    add_filter_options,
    add_reprojection_option,
    filter_options,
    parse_frames,
)

METHOD_TITLES = {Filter.ADMM: "ADMM", Filter.FISTA: "projected gradient (FISTA)"}
#: The headset rate a clip is played at unless ``--fps`` says otherwise.
DEFAULT_FPS = 90.0
#: Seconds a frame of the default (ADMM, 2 iterations a frame) takes on Mesa's llvmpipe for changing content (a
#: pan played at its own rate: every frame iterates; a settled still view costs less), keyed by the FFT grid's
#: pixels of an image with a 27 px kernel padded to powers of two (96x64 -> 128x128, 256x256 -> 512x512,
#: 512x512 -> 1024x1024), measured with ``vrcorrect render --fps 30`` on the project's 2-core AMD EPYC with
#: nothing else running, 2026-12-05 (0.23, 0.74, 2.35 s; on 2026-11-28, before issue 43's engine and shared
#: with two other jobs, 0.3, 6.0 and 36 s): what ``render`` says before its first frames, interpolated in
#: log-log, scaled by the FFT round trips a frame (iterations + 2).
SOFTWARE_S_PER_FRAME = ((128 * 128, 0.23), (512 * 512, 0.74), (1024 * 1024, 2.35))


def _software_seconds(size: tuple[int, int], kernel_px: int = 27) -> float:
    """The table above at the grid of an image of ``size`` (W, H) with a ``kernel_px`` kernel."""
    grid = 1
    for side in size:
        grid *= 2 ** math.ceil(math.log2(side + kernel_px - 1))
    points = SOFTWARE_S_PER_FRAME
    (g0, t0), (g1, t1) = (points[0], points[1]) if grid <= points[1][0] else (points[1], points[2])
    p = math.log(t1 / t0) / math.log(g1 / g0)
    return t0 * (grid / g0) ** p


def estimate_text(renderer: str, size: tuple[int, int], frames: int, options: dict[str, Any]) -> str:
    """What ``render`` says at its start about the time it will take on ``renderer``."""
    from ..runtime.eye_model import DEFAULT_ITERATIONS  # light
    from ..runtime.gl import software_renderer  # on use: start-up time (apps/__init__: the parser loads no layer below)

    name = renderer.split(" (")[0]
    if not software_renderer(renderer):
        return f"on {name}: the time a frame takes is measured on the first frames"
    method = options.get("filter", Filter.ADMM)
    if method not in (Filter.ADMM, Filter.FISTA):
        return f"on {name} (software rendering on the CPU): the time a frame takes is measured on the first frames"
    k = options.get("iterations_per_frame") or DEFAULT_ITERATIONS.get(method, 2)
    if method == Filter.FISTA:        # k = 4 took 0.46-0.77 of the default's frame (the table's day: 0.18, 0.40, 1.09 s)
        per = _software_seconds(size) * 0.6 * k / 4
    else:
        per = _software_seconds(size) * (k + 2) / 4
    return (f"on {name} (software rendering on the CPU) expect roughly {duration_text(per)} a frame while the "
            f"picture changes, {duration_text(per * frames)} for the {frames} frames, plus the shaders' first "
            "compile; measured on the first frames from here on")


def cmd_render(args: argparse.Namespace) -> int:
    check_not_input(args)                                     # never over the input, --force or not
    clip = clips.input_clip(args, still_options=("frames",))  # before the heavy imports: a bad clip is told at once
    if clip is not None:
        return _render_clip(args, clips.plan_frames(clip, args, DEFAULT_FPS))
    from ..runtime.shell.render import MAX_FRAMES, SETTLED_FRAMES, render_frame  # on use: start-up time (apps/__init__)

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    options = {"kernel_options": kernel_options(args), **filter_options(args)}
    frames = parse_frames(args.frames, "--frames", MAX_FRAMES)
    if frames is None:
        frames = SETTLED_FRAMES if args.backend == Backend.GLSL and options["filter"] in ITERATIVE_FILTERS else 1
    check_readable(args.input)
    check_writable(out, force=args.force)
    model = model_for_backend(args.backend, args.model)
    rx = load_prescription(rx_path(args))
    notes: list[str] = []
    image = read_image(args.input, notes)
    print_notes(notes)
    if model:
        options["model"] = model
    from ..runtime.gl import headless_context  # on use: start-up time (apps/__init__: the parser loads no layer below)

    ctx = headless_context(require=430)
    try:
        total = frames if args.view != "seen-uncorrected" else 1
        h, w = image.shape[:2]
        print(f"render: {total} frame(s) of {args.input} ({w}x{h}) as a still video, the last written; "
              + estimate_text(ctx.info.get("GL_RENDERER", "?"), (w, h), total, options), flush=True)
        with Progress("render", "frame", total) as bar:
            result, info = render_frame(image, rx, args.display, args.eye, args.backend, view=args.view, ctx=ctx,
                                        frames=frames, progress=bar.update, **options)
    finally:
        ctx.release()
    write_png(out, result / 255.0, bits=8, force=args.force)
    small = small_image_note(w, h, int(info.get("kernel_size", 1)), "the correction")
    if small and not info["identity"]:
        print_notes([small])
    _print_eye(args, info)
    fraction = info.get("objective_fraction")
    # With the GLSL backend and a correction that is not the identity, the eye model's last note describes
    # the settings it designed (the method and its iterations, or the regulariser and blend and how they
    # were chosen; runtime.eye_model.build_eye_model): the line below states them, once, with what only
    # that note said; other notes (an identity correction and why, the ONNX model) are printed as they are.
    designed = args.backend == Backend.GLSL and not info["identity"]
    chosen = " (chosen by wiener on the sample image)" if designed else ""
    if designed and info["filter"] in ITERATIVE_FILTERS:   # (an identity: its note says why, below)
        storage = f", {info['precision']} precision storage" if info.get("precision") else ""
        print(f"  {METHOD_TITLES[info['filter']]}, {info.get('iterations_per_frame', '-')} iteration(s) per frame, "
              f"{frames} frame(s) warm-started, {info.get('fft_round_trips_per_frame', '-')} FFT round trips a frame"
              + storage + (f"; last frame's objective {fraction:.3f} of uncorrected" if fraction is not None else ""))
        _print_fovea(info)
    elif designed and "ranks" in info:
        print(f"  separable filters {info['filter_size']} px, ranks {info['ranks']} ({info['taps_per_pixel']} "
              f"taps/pixel), regulariser {info['mu_rel']:g}, blend {info['beta']:.3f}{chosen}")
    elif designed:
        print(f"  FFT filter, margin {info['margin']} px, regulariser {info['mu_rel']:g}, blend {info['beta']:.3f}"
              + chosen)
    for note in info["notes"][:-1] if designed else info["notes"]:
        print(f"  - {note}")
    first = info.get("first_frame_s")
    ran = frames if args.view != "seen-uncorrected" else 1          # the eye's blur alone is one frame
    if ran > 1 and first is not None:
        per = (f": the first {1e3 * first:.1f} ms (the upload, the cold start and its programs' first run), then "
               f"{1e3 * (info['frame_s'] - first) / (ran - 1):.1f} ms a frame")
    else:
        per = ""
    print(f"  build {info['build_s']:.2f} s, {ran} frame(s) {1e3 * info['frame_s']:.1f} ms{per} "
          "(incl. read-back)")
    print(f"wrote {out} ({_view_said(args, info)})")
    return 0


def _render_clip(args: argparse.Namespace, plan: clips.ClipPlan) -> int:
    """A clip through one Corrector, every frame to the output folder."""
    from ..runtime.shell.render import render_clip  # on use: start-up time (apps/__init__)

    options = {"kernel_options": kernel_options(args), **filter_options(args)}
    folder = clips.output_folder(args, plan)        # checked before any work
    model = model_for_backend(args.backend, args.model)
    if model:
        options["model"] = model
    rx = load_prescription(rx_path(args))
    print_notes(plan.clip.notes)
    from ..runtime.gl import headless_context  # on use: start-up time (apps/__init__: the parser loads no layer below)

    print(f"render: {plan.text}" + _rate_note(args, plan), flush=True)
    ctx = headless_context(require=430)
    try:
        print("render: " + estimate_text(ctx.info.get("GL_RENDERER", "?"), plan.clip.size, plan.count, options),
              flush=True)
        with folder, clips.frames_bar("render", plan.count) as bar:
            def emit(index: int, out) -> None:
                folder.write(index, out / 255.0, bits=8)

            info = render_clip(clips.planned_frames(plan), rx, args.display, args.eye, args.backend, view=args.view,
                               ctx=ctx, reprojection=not args.no_reprojection, emit=emit, progress=bar.update,
                               frame_time_s=1.0 / (plan.frames_per_s or DEFAULT_FPS), **options)
            folder.commit()
    finally:
        ctx.release()
    _print_clip_summary(args, plan, info)
    return 0


def _rate_note(args: argparse.Namespace, plan: clips.ClipPlan) -> str:
    """Where the clip is played at another rate than its own by default: say so, and how to keep it."""
    clip = plan.clip
    own = clip.frames_per_s
    if own is None and clip.durations_s and max(clip.durations_s) - min(clip.durations_s) < 1e-9:
        own = 1.0 / clip.durations_s[0]
    if args.fps is not None or getattr(args, "clip_fps", None) is not None or own is None or abs(own - DEFAULT_FPS) < 1e-6:
        return ""
    return (f"; played at the headset's {DEFAULT_FPS:g} fps by default (--fps {own:.3g} keeps one frame per "
            "source frame)")


def _view_said(args: argparse.Namespace, info: dict) -> str:
    """The view ``wrote`` names; for an eye with nothing to correct, that its frames are the picture as it is."""
    return info["view"] + (": the picture as it is, nothing to correct"
                           if info["identity"] and args.view == "corrected" else "")


def _print_eye(args: argparse.Namespace, info: dict) -> None:
    focus = (f", accommodation {info['accommodation_D']:.2f} D" if info.get("accommodation_D") else "") + (
        f", lag {info['accommodative_lag_D']:.2f} D at 40 cm" if info.get("accommodative_lag_D") else "")
    print(f"{info['renderer']}: {args.eye} eye, sphere {info['sphere_D']:+.2f} D, cylinder {info['cylinder_D']:+.2f} "
          f"D, axis {info['axis_deg']:g} deg{focus} on {info['display']}; backend {info['backend']}")
    if getattr(args, "cold_start_note", ""):
        print(f"  cold start: {args.cold_start_note}")
    if info.get("pupil_status"):
        print(f"  {info['pupil_status']}" + ("; robust design" if info.get("robust") else ""))
    elif info.get("pupil_mm") is not None:
        print(f"  designed for a {info['pupil_mm']:.2f} mm pupil" + (", robust" if info.get("robust") else ""))


def _print_fovea(info: dict) -> None:
    """The frame budget's last choice (with ``--budget-ms``) and the foveated window, where the
    correction was solved (nothing without ``--fovea``)."""
    if info.get("budget"):
        print(f"  frame {info['budget']} (the iterations chosen frame by frame, timed on this renderer)")
    if info.get("fovea_deg") is None:
        return
    x, y = info["gaze_deg"]
    window = info.get("fovea_window")
    where = "" if window is None else (f" (the last frame's window with its band: rows {window[0]}-{window[1]}, "
                                       f"columns {window[2]}-{window[3]})")
    periphery = info.get("fovea_periphery", "target")
    outside = ("the rest of the view as it is" if periphery == "target" else
               f"outside it a correction of the whole view at {'half' if periphery == 'half' else 'a quarter of'} the "
               f"resolution ({info.get('fovea_periphery_iterations')} iteration(s) a frame)")
    band = info["fovea_band_px"]
    print(f"  foveated: corrected on a window of radius {info['fovea_deg']:g} deg ({info['fovea_radius_px'] - band} px) "
          f"around the gaze at ({x:g}, {y:g}) deg and faded over {band} px beyond it{where}; {outside}; a cold "
          f"frame runs {info.get('fovea_cold_iterations')} more on the window; the objective is the window's "
          "sub-image's")


def _median(values) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.median(kept)) if kept else None


def _print_clip_summary(args: argparse.Namespace, plan: clips.ClipPlan, info: dict) -> None:
    from ..runtime.gl import software_renderer  # on use: start-up time (apps/__init__)

    _print_eye(args, info)
    print(f"  {plan.text}")
    iterative = args.backend == Backend.GLSL and info["filter"] in ITERATIVE_FILTERS and args.view != "seen-uncorrected"
    if info["identity"] and args.view != "seen-uncorrected":
        print("  the eye sees the display as well as with its glasses: nothing to correct, each frame shown as it is")
    elif iterative:
        title = METHOD_TITLES[info["filter"]]
        if info["motion_tracked"]:
            cuts = info["cuts"]
            shown = ", ".join(str(c) for c in cuts[:10]) + (" ..." if len(cuts) > 10 else "")
            where = f": at frame {shown}" if cuts else ""
            carry = (f"warm start carried across frames, moved by the estimated motion; {len(cuts)} cut(s) detected"
                     f"{where} (cold start)")
        else:
            carry = "warm start carried across frames as it was (--no-reprojection: no motion, no cut detection)"
        print(f"  {title}, {info.get('iterations_per_frame', '-')} iteration(s) per frame; {carry}")
        _print_fovea(info)
    elif args.view == "seen-uncorrected":
        print("  what the eye sees of each frame without correction")
    fraction = _median(info["objective_fractions"])
    if fraction is not None:
        print(f"  median objective {fraction:.3f} of uncorrected (the GPU's own, read one frame late)")
    ms = _median(info["frame_ms"])
    renderer = str(info["renderer"])
    soft = software_renderer(renderer)
    print(f"  median {ms:.1f} ms per frame (upload, correction and read-back)"
          + (f" on {renderer.split(' (')[0]}, Mesa's software renderer on the CPU: a GPU is far faster" if soft else "")
          + f"; build {info['build_s']:.2f} s")
    print(f"wrote {args.output} ({info['frames']} frames, {_view_said(args, info)})")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="frames through the real-time GL pipeline (headless EGL), the last written; "
                                      "a clip: every frame, to a folder",
                       description="Run an image, or a clip, through the real-time GL pipeline on a headless EGL "
                                   "context. " + clips.CLIP_HELP + " A clip is played at the headset's rate (--fps, "
                                   "default 90): source frames are repeated or dropped by their presentation time "
                                   "(a video's frame rate, an animation's frame durations, a folder's --clip-fps); one "
                                   "corrector carries its warm start from frame to frame, moved by the picture's "
                                   "estimated motion and restarted cold on a scene cut, as in a headset.")
    clips.add_input_output(p, "image (PNG/JPEG, sRGB)")
    add_model_options(p)
    add_backend_option(p)
    p.add_argument("--model", metavar="MODEL.onnx", help="ONNX model for --backend onnx")
    add_filter_options(p)
    p.add_argument("--frames", metavar="N",
                   help="a still image: run N frames of it as a still video and write the last; with --filter admm or "
                        "fista each frame continues the last one's iterations (default: 10 with admm and fista, a "
                        "still view settled after a tenth of a second at 90 Hz; 1 with the one-pass filters and the "
                        "onnx backend)")
    p.add_argument("--view", choices=("corrected", "seen-corrected", "seen-uncorrected"), default="corrected",
                   help="the displayed image (default) or what the eye sees of it")
    add_reprojection_option(p)
    clips.add_clip_options(p, fps_help=f"a clip: the headset's frame rate it is played at (default "
                                       f"{DEFAULT_FPS:g}); the output has one frame per displayed frame")
    p.add_argument("--force", action="store_true", help="overwrite the output (a clip's: replace its folder of frames)")
    p.set_defaults(func=cmd_render)
