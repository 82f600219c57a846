"""``vrcorrect overlay``: frames from a video, images or the screen, corrected for one eye and
shown full-screen or in a window (:class:`~vrcorrect.runtime.shell.overlay.Overlay`): the command's
options and its run."""

from __future__ import annotations

import argparse
import time

from ..runtime.shell.overlay import KEY_MAP, Overlay, OverlayConfig
from ..runtime.shell.source_spec import parse_region, parse_size
from ..runtime.shell.keys import key_map_text
from ..specs.vocabulary import Eye, names
from .common import rx_path, say_sample_rx
from .realtime_options import (
    KEPT_DESIGNS,
    add_backend_option,
    add_filter_options,
    add_reprojection_option,
    add_rx_option,
    corrector_options,
    parse_frames,
)

__all__ = ["add_parser", "cmd_overlay"]


def add_parser(subparsers: "argparse._SubParsersAction[argparse.ArgumentParser]") -> argparse.ArgumentParser:
    """Add the ``overlay`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "overlay", help="correct frames from a video, images or the screen and show them full-screen or in a "
                        "window",
        description=("Show frames from an external source (a video, a folder of images, an image, or a\n"
                     "region of the X11 screen) corrected for one eye, full-screen on the primary monitor\n"
                     "or in a window. Needs a display (X11) and OpenGL 4.3." + KEPT_DESIGNS),
        epilog=key_map_text(KEY_MAP), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--source", required=True, metavar="VIDEO|DIR|IMAGE|screen",
                   help="a video (or animated GIF/PNG/WebP), a folder of images shown in turn, an image, or "
                        "'screen' (a region of the X11 screen)")
    p.add_argument("--region", metavar="X,Y,W,H",
                   help="with screen: the rectangle to grab (default: another monitor full-screen; with --window, "
                        "the screen's top-left, the window's size, the window placed beside it)")
    add_rx_option(p)
    p.add_argument("--eye", choices=names(Eye), default=Eye.RIGHT.value,
                   help="whose prescription (a monitor is seen by both eyes; default right)")
    p.add_argument("--display", metavar="PRESET",
                   help="display preset or profile .json (default: desktop for screen, quest2 otherwise)")
    p.add_argument("--window", metavar="WxH", help="a window of this size instead of full-screen")
    p.add_argument("--frames", metavar="N", help="render N frames and exit (tests, CI)")
    add_backend_option(p)
    p.add_argument("--model", metavar="M.onnx", help="ONNX model for --backend onnx")
    add_filter_options(p)
    add_reprojection_option(p)
    p.add_argument("--screenshot-dir", default=".", metavar="DIR", help="where p writes screenshots (default .)")
    p.set_defaults(func=cmd_overlay)
    return p


def cmd_overlay(args: argparse.Namespace) -> int:
    """``vrcorrect overlay``: check the arguments, open the overlay, run it, print a summary."""
    frames = parse_frames(args.frames)
    options = corrector_options(args)
    config = OverlayConfig(
        source=args.source, region=None if args.region is None else parse_region(args.region),
        rx=str(rx_path(args, say=False)),
        eye=args.eye, display=args.display, window=None if args.window is None else parse_size(args.window, "--window"),
        frames=frames, screenshot_dir=args.screenshot_dir, backend=args.backend, corrector_options=options,
        reprojection=not args.no_reprojection,
        vsync=frames is None)
    t0 = time.perf_counter()
    with Overlay(config) as overlay:
        say_sample_rx(args)                                 # once the arguments, the source and the screen passed
        print(key_map_text(KEY_MAP))
        if args.cold_start_note:
            print(f"cold start: {args.cold_start_note}")
        t1 = time.perf_counter()
        overlay.run()
        t2 = time.perf_counter()
        n = overlay.frame
        print(f"{n} frame(s) in {t2 - t1:.2f} s ({1e3 * (t2 - t1) / max(n, 1):.1f} ms per frame; set-up "
              f"{t1 - t0:.1f} s) at {overlay.output_size[0]}x{overlay.output_size[1]} on "
              f"{overlay.ctx.info.get('GL_RENDERER', '?')}")
        for path in overlay.screenshots:
            print(f"wrote {path}")
    return 0
