"""``vrcorrect render``: frames of an image through the real-time GL pipeline (headless EGL), the
last one written: what the headset would show, or what the eye sees of it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm import tqdm

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import check_readable, check_writable
from ..plumbing.imageio import read_image, write_png
from ..runtime.model_path import model_for_backend
from ..specs.prescription import bundled_sample_path, load_prescription
from .common import add_model_options, kernel_options, print_notes
from ..runtime.eye_model import ITERATIVE_FILTERS
from .realtime_options import add_filter_options, filter_options, parse_frames

METHOD_TITLES = {"admm": "ADMM", "fista": "projected gradient (FISTA)"}


def cmd_render(args: argparse.Namespace) -> int:
    from ..runtime.render import MAX_FRAMES, SETTLED_FRAMES, render_frame  # on use: start-up time (apps/__init__)

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    options = {"kernel_options": kernel_options(args), **filter_options(args)}
    frames = parse_frames(args.frames, "--frames", MAX_FRAMES)
    if frames is None:
        frames = SETTLED_FRAMES if args.backend == "glsl" and options["filter"] in ITERATIVE_FILTERS else 1
    check_readable(args.input)
    check_writable(out, force=args.force)
    model = model_for_backend(args.backend, args.model)
    rx_path = args.rx or str(bundled_sample_path())
    rx = load_prescription(rx_path)
    notes: list[str] = []
    image = read_image(args.input, notes)
    print_notes(notes)
    if model:
        options["model"] = model

    with tqdm(total=frames, desc="render", unit="frame", disable=None, leave=False, file=sys.stderr) as bar:
        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()

        result, info = render_frame(image, rx, args.display, args.eye, args.backend, view=args.view,
                                    frames=frames, progress=progress, **options)
    write_png(out, result / 255.0, bits=8, force=args.force)
    print(f"{info['renderer']}: {args.eye} eye, sphere {info['sphere_D']:+.2f} D, cylinder {info['cylinder_D']:+.2f} D, "
          f"axis {info['axis_deg']:g} deg on {info['display']}; backend {info['backend']}")
    fraction = info.get("objective_fraction")
    if args.backend == "glsl" and info["filter"] in ITERATIVE_FILTERS:
        print(f"  {METHOD_TITLES[info['filter']]}, {info.get('iterations_per_frame', '-')} iteration(s) per frame, "
              f"{frames} frame(s) warm-started, {info.get('fft_round_trips_per_frame', '-')} FFT round trips a frame"
              + (f"; last frame's objective {fraction:.3f} of uncorrected" if fraction is not None else ""))
    elif args.backend == "glsl" and "ranks" in info:
        print(f"  separable filters {info['filter_size']} px, ranks {info['ranks']} ({info['taps_per_pixel']} "
              f"taps/pixel), regulariser {info['mu_rel']:g}, blend {info['beta']:.3f}")
    elif args.backend == "glsl":
        print(f"  FFT filter, margin {info['margin']} px, regulariser {info['mu_rel']:g}, blend {info['beta']:.3f}")
    for note in info["notes"]:
        print(f"  - {note}")
    per = f", {1e3 * info['frame_s'] / frames:.1f} ms per frame" if frames > 1 else ""
    print(f"  build {info['build_s']:.2f} s, {frames} frame(s) {1e3 * info['frame_s']:.1f} ms{per} "
          "(incl. upload and read-back)")
    print(f"wrote {out} ({info['view']})")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="frames through the real-time GL pipeline (headless EGL), the last written")
    p.add_argument("input", help="image (PNG/JPEG, sRGB)")
    p.add_argument("-o", "--output", required=True, help="output PNG")
    add_model_options(p)
    p.add_argument("--backend", choices=("glsl", "onnx"), default="glsl", help="correction backend (default glsl)")
    p.add_argument("--model", metavar="MODEL.onnx", help="ONNX model for --backend onnx")
    add_filter_options(p)
    p.add_argument("--frames", metavar="N",
                   help="run N frames of the input as a still video and write the last; with --filter admm or fista each "
                        "frame continues the last one's iterations (default: 10 with admm and fista, a still view settled "
                        "after a tenth of a second at 90 Hz; 1 with the one-pass filters and the onnx backend)")
    p.add_argument("--view", choices=("corrected", "seen-corrected", "seen-uncorrected"), default="corrected",
                   help="the displayed image (default) or what the eye sees of it")
    p.add_argument("--force", action="store_true", help="overwrite the output")
    p.set_defaults(func=cmd_render)
