"""``vrcorrect simulate``: what an eye sees of an image on a display; of each frame of a clip, into a
folder of frames."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import check_readable, check_writable
from ..plumbing.imageio import read_image, write_png
from ..specs.display import decode, encode, get_display
from . import clips
from .common import (PupilPerFrame, add_model_options, add_pupil_options, build_eye_kernel, check_not_input,
                     kernel_decisions, load_eye_and_age, parse_pupil, print_notes, viewing_pupil)


def cmd_simulate(args: argparse.Namespace) -> int:
    check_not_input(args)                                 # never over the input, --force or not
    clip = clips.input_clip(args)                         # a clip is checked before any heavy import
    if clip is not None:
        return _simulate_clip(args, clips.plan_frames(clip, args, None))
    check_readable(args.input)                      # before the heavy imports: a typo is told at once
    from ..vision.forward import what_the_eye_sees  # on use: start-up time (apps/__init__)

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    check_writable(out, force=args.force)
    parse_pupil(args.pupil)
    notes: list[str] = []
    image = read_image(args.input, notes)           # a broken input is the one line, before any other
    rx_path, eye, age = load_eye_and_age(args)
    display = get_display(args.display)
    print_notes(notes)
    eye = _at_pupil(args, eye, display, decode(display, image), age)
    t0 = time.perf_counter()
    kernel = build_eye_kernel(args, eye, display)
    t1 = time.perf_counter()
    seen, info = what_the_eye_sees(decode(display, image), kernel, method=args.method)
    t2 = time.perf_counter()
    write_png(out, encode(display, seen), bits=16 if args.sixteen_bit else 8, force=args.force)
    if args.explain:
        print(f"prescription {rx_path} ({args.eye} eye): sphere {eye.sphere_D:+.2f} D, cylinder "
              f"{eye.cylinder_D:+.2f} D, axis {eye.axis_deg:g} deg, pupil {eye.pupil_diameter_mm:g} mm")
        print(f"display {display.name} ({display.title}): {display.pixels_per_degree:.1f} pixels per degree, "
              f"transfer {display.transfer}")
        for line in kernel_decisions(kernel):
            print(f"  - {line}")
        shortcut = "grey image: exact achromatic shortcut" if info.achromatic else "colour image"
        print(f"  - forward model: {info.path} path, {shortcut}, {info.convolutions} convolution(s) of "
              f"{image.shape[1]}x{image.shape[0]} px")
        print(f"  - time: kernel {t1 - t0:.2f} s, simulation {t2 - t1:.2f} s")
    print(f"wrote {out}: what the {args.eye} eye sees on {display.title}")
    return 0


def _simulate_clip(args: argparse.Namespace, plan: clips.ClipPlan) -> int:
    """What the eye sees of each frame of a clip, into a folder of frames."""
    folder = clips.output_folder(args, plan)        # checked before any work
    from ..vision.forward import what_the_eye_sees  # on use: start-up time (apps/__init__)

    parse_pupil(args.pupil)
    rx_path, base, age = load_eye_and_age(args)
    display = get_display(args.display)
    print_notes(plan.clip.notes)
    # each source frame through the pupil its light gives
    kernel_for = PupilPerFrame(args, base, display, age,
                               lambda p: build_eye_kernel(args, base.with_changes(pupil_diameter_mm=p), display),
                               design=False)
    last_source, seen, info, eye = -1, None, None, base
    with folder, clips.frames_bar("simulate", plan.count) as bar:
        for index, (source, frame) in enumerate(clips.planned_frames(plan)):
            if source != last_source:               # a repeated source frame is seen the same
                linear = decode(display, frame)
                pupil, kernel = kernel_for(linear, f" (from frame {index})")
                eye = base.with_changes(pupil_diameter_mm=pupil)
                seen, info = what_the_eye_sees(linear, kernel, method=args.method)
                last_source = source
            folder.write(index, encode(display, seen), bits=16 if args.sixteen_bit else 8)
            bar.advance()
        folder.commit()
    if args.explain:
        print(f"prescription {rx_path} ({args.eye} eye): sphere {eye.sphere_D:+.2f} D, cylinder "
              f"{eye.cylinder_D:+.2f} D, axis {eye.axis_deg:g} deg, pupil {eye.pupil_diameter_mm:g} mm")
        for line in kernel_decisions(kernel):
            print(f"  - {line}")
        print(f"  - forward model: {info.path} path, {info.convolutions} convolution(s) of the last frame")
    print(f"wrote {args.output}: {plan.count} frames, what the {args.eye} eye sees on {display.title} ({plan.text})")
    return 0


def _at_pupil(args: argparse.Namespace, eye, display, image_linear, age, where: str = ""):
    """The eye through the pupil ``--pupil`` asks for (``auto``: the image's light), said on one line."""
    pupil, lines = viewing_pupil(args, eye, display, image_linear, age, design=False)   # the eye's own pupil
    for line in lines:
        print(f"vrcorrect: {line}{where}", flush=True)       # stdout: an error stays the one line on stderr
    return eye.with_changes(pupil_diameter_mm=pupil)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="what an eye sees of an image on a display; of each frame of a clip",
                       description="What an eye sees of an image on a display. " + clips.CLIP_HELP + " Each source "
                                   "frame of a clip is simulated once unless --fps asks for another rate.")
    clips.add_input_output(p, "image file (PNG, JPEG, ...; sRGB code values)")
    add_model_options(p)
    add_pupil_options(p, robust=False)
    p.add_argument("--convolution", dest="method", choices=("auto", "fft", "direct"), default="auto",
                   help="how the blur is computed: by FFT, directly, or the faster of the two for the kernel (auto, "
                        "the default); the result is the same to float precision")
    # the flag's earlier name (before 0.2: it read like correct's --method, which picks the solver)
    p.add_argument("--method", dest="method", choices=("auto", "fft", "direct"), help=argparse.SUPPRESS)
    p.add_argument("--explain", action="store_true", help="print every modelling decision")
    p.add_argument("--16bit", dest="sixteen_bit", action="store_true", help="write a 16-bit PNG")
    clips.add_clip_options(p, fps_help="a clip: resample it in time to F frames per second (source frames "
                                       "repeated or dropped by presentation time; default: each source frame once)")
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists (a clip's: replace its folder "
                                                        "of frames)")
    p.set_defaults(func=cmd_simulate)
