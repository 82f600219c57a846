"""``vrcorrect xr``: the headset, an OpenXR session with each eye corrected before it is submitted
(:class:`~vrcorrect.runtime.shell.xr.XrApp`): the command's options, its run and its exit statuses."""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from ..plumbing.errors import ValidationError, XrUnavailableError
from ..runtime.model_path import model_for_backend
from ..runtime.shell.source_spec import parse_source
from ..runtime.shell.xr import EXIT_NO_RUNTIME, EXIT_SESSION_LOST, XrApp, XrConfig
from .common import rx_path
from .realtime_options import (
    KEPT_DESIGNS,
    add_backend_option,
    add_filter_options,
    add_reprojection_option,
    add_rx_option,
    filter_options,
    parse_frames,
    parse_whole_number,
)

__all__ = ["add_parser", "cmd_xr"]


def add_parser(subparsers: "argparse._SubParsersAction[argparse.ArgumentParser]") -> argparse.ArgumentParser:
    """Add the ``xr`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "xr", help="the headset: an OpenXR session, each eye corrected before it is submitted",
        description=("Run an OpenXR session (pyopenxr, XR_KHR_opengl_enable, X11/GLX) and submit each eye's image,\n"
                     "corrected for that eye's prescription: the 3D demo scene from the tracked eyes, or a\n"
                     "picture source. Needs an OpenXR runtime (Monado, SteamVR) and a headset; without one it\n"
                     f"says so and exits with status {EXIT_NO_RUNTIME}. Ctrl-C (or closing the mirror window) ends\n"
                     f"the session cleanly (status 0); a session the runtime lost exits with status {EXIT_SESSION_LOST}."
                     + KEPT_DESIGNS),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    add_rx_option(p)
    p.add_argument("--display", default="quest2", metavar="PRESET",
                   help="the headset's display preset or profile .json (default quest2; list: vrcorrect displays)")
    p.add_argument("--source", default="demo", metavar="demo|IMAGE|VIDEO|DIR|screen",
                   help="the 3D scene seen from the tracked eyes (default), an image, a video (or animated "
                        "GIF/PNG/WebP), a folder of images shown in turn, or the X11 screen")
    p.add_argument("--region", metavar="X,Y,W,H", help="with --source screen: the part of the screen (default all)")
    p.add_argument("--frames", metavar="N", help="leave after N rendered frames (tests, benchmarks)")
    p.add_argument("--mirror", action="store_true", help="show what each eye is sent in a window")
    p.add_argument("--mirror-height", default="480", metavar="PX", help="the mirror window's height (default 480)")
    p.add_argument("--validation", action="store_true",
                   help="insert Khronos' core validation layer (bundled with pyopenxr; messages on stdout)")
    add_backend_option(p)
    p.add_argument("--model", metavar="MODEL.onnx", help="ONNX model for --backend onnx")
    add_filter_options(p, eye_tracker=True)
    add_reprojection_option(p)
    p.set_defaults(func=cmd_xr)
    return p


def cmd_xr(args: argparse.Namespace) -> int:
    """``vrcorrect xr``: check the arguments, run the session, print a summary."""
    frames = parse_frames(args.frames)
    options = filter_options(args)
    mirror_height = parse_whole_number(args.mirror_height, "--mirror-height", 16, 4096, "pixels")
    if args.region is not None and args.source != "screen":
        raise ValidationError("--region", args.region, "only with --source screen")
    if args.source != "screen":
        parse_source(args.source)
    model = model_for_backend(args.backend, args.model)
    if model:
        options["model"] = model
    config = XrConfig(rx=str(rx_path(args)), display=args.display, source=args.source, region=args.region, frames=frames,
                      mirror=args.mirror, mirror_height=mirror_height, validation=args.validation,
                      backend=args.backend, corrector_options=options, reprojection=not args.no_reprojection)
    try:
        app = XrApp(config)
    except XrUnavailableError as exc:
        print(f"vrcorrect xr: {exc}", file=sys.stderr)
        return EXIT_NO_RUNTIME
    with app:
        s = app.summary
        print(f"runtime: {s.runtime}; system: {s.system}; {s.eye_size[0]}x{s.eye_size[1]} per eye; swapchains "
              f"{s.swapchain_format}; OpenGL: {s.renderer}")
        if args.cold_start_note:
            print(f"cold start: {args.cold_start_note}")
        t0 = time.perf_counter()
        summary = app.run()
        wall = time.perf_counter() - t0
    print(f"session ended ({summary.reason}); states: {' -> '.join(summary.states)}")
    n = summary.frames
    print(f"{n} frame(s) rendered, {summary.frames_total} submitted, in {wall:.2f} s"
          + (f" (median {statistics.median(summary.frame_ms):.1f} ms per rendered frame)" if summary.frame_ms else ""))
    for name, (gpu, cpu) in summary.medians().items():
        print(f"  {name:<14} gpu {'-' if gpu is None else f'{gpu:.2f}'} ms, cpu {cpu:.2f} ms (median)")
    if summary.objective:
        print(f"  {summary.method}, {summary.iterations_per_frame} iteration(s) per frame at the end; objective as a fraction "
              "of uncorrected (median over frames): "
              + ", ".join(f"{eye} {statistics.median(v):.3f}" for eye, v in summary.objective.items()))
    if summary.gaze:
        print(f"  fovea: {summary.tracked_frames} of {n} frame(s) placed at the eye tracker's gaze"
              if summary.tracked_frames else f"  fovea: {summary.gaze}")
    if summary.reason == "session lost":
        print(f"vrcorrect xr: the runtime lost the session (LOSS_PENDING); exit status {EXIT_SESSION_LOST}",
              file=sys.stderr)
    return summary.exit_code
