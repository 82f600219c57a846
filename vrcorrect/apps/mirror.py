"""``vrcorrect mirror``: both eyes side by side in a window, corrected live
(:class:`~vrcorrect.runtime.shell.mirror.Mirror`): the command's options and its run."""

from __future__ import annotations

import argparse
import statistics
import time

from ..runtime.gl import format_ms
from ..runtime.shell.mirror import KEY_MAP, Mirror, MirrorConfig
from ..runtime.shell.source_spec import parse_size, parse_source
from ..runtime.shell.keys import key_map_text, knob_text
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

__all__ = ["add_parser", "cmd_mirror"]


def add_parser(subparsers: "argparse._SubParsersAction[argparse.ArgumentParser]") -> argparse.ArgumentParser:
    """Add the ``mirror`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "mirror", help="a window with both eyes side by side, corrected live (keys: press h)",
        description=("Open a window showing both eyes side by side (left eye on the left): the displayed,\n"
                     "pre-corrected image or what each eye sees of it, with live prescription edits,\n"
                     "screenshots and stage timings. Needs a display (X11/Wayland) and OpenGL 4.3." + KEPT_DESIGNS),
        epilog=key_map_text(KEY_MAP), formatter_class=argparse.RawDescriptionHelpFormatter)
    add_rx_option(p)
    p.add_argument("--display", default="quest2", metavar="PRESET",
                   help="display preset or profile .json (default quest2; list: vrcorrect displays)")
    p.add_argument("--source", default="demo", metavar="demo|IMAGE|VIDEO|DIR",
                   help="the built-in 3D scene (default), an image, a video (or animated GIF/PNG/WebP), "
                        "or a folder of images shown in turn")
    p.add_argument("--size", default="640x640", metavar="WxH",
                   help="each eye's size in pixels (default 640x640; the window is twice as wide)")
    p.add_argument("--frames", metavar="N", help="render N frames and exit (tests, CI)")
    p.add_argument("--screenshot-dir", default=".", metavar="DIR", help="where p writes screenshots (default .)")
    add_backend_option(p, help="correction backend: glsl (default) or onnx (a learned model per eye)")
    p.add_argument("--model", metavar="MODEL.onnx",
                   help="ONNX model for --backend onnx (default: models/default.onnx)")
    add_filter_options(p)
    add_reprojection_option(p)
    p.set_defaults(func=cmd_mirror)
    return p


def cmd_mirror(args: argparse.Namespace) -> int:
    """``vrcorrect mirror``: check the arguments, open the mirror, run it, print a summary."""
    frames = parse_frames(args.frames)
    options = corrector_options(args)
    config = MirrorConfig(rx=str(rx_path(args, say=False)), display=args.display, source=args.source, eye_size=parse_size(args.size),
                          frames=frames, screenshot_dir=args.screenshot_dir, vsync=frames is None,
                          backend=args.backend, corrector_options=options, reprojection=not args.no_reprojection)
    parse_source(config.source)  # fail on a bad source before anything slow
    say_sample_rx(args)          # after the arguments' checks: a refused command prints only its error
    print(key_map_text(KEY_MAP))
    if args.cold_start_note:
        print(f"cold start: {args.cold_start_note}")
    t0 = time.perf_counter()
    with Mirror(config) as mirror:
        t1 = time.perf_counter()
        mirror.run()
        t2 = time.perf_counter()
        n = mirror.frame
        times = mirror.frame_ms
        which = "after the first" if len(times) == max(n - 1, 0) else f"over the last {len(times)}"
        median = f"median {statistics.median(times):.1f} ms a frame {which}, " if times else ""
        print(f"{n} frame(s) in {t2 - t1:.2f} s ({median}{1e3 * (t2 - t1) / max(n, 1):.1f} ms on average; "
              f"set-up {t1 - t0:.1f} s) on {mirror.ctx.info.get('GL_RENDERER', '?')}")
        for name, (gpu, cpu) in mirror.timings_ms.items():
            print(f"  {name:<15} gpu {format_ms(gpu)} ms, cpu {cpu:.2f} ms (last frame)")
        knob = knob_text(mirror.correctors, config.eye_size, mirror.state.correction)
        if knob:
            print(f"  {knob}")
        for path in mirror.screenshots:
            print(f"wrote {path}")
    return 0
