"""``vrcorrect acuity``: which line of an eye chart this eye reads, uncorrected and with each
correction. The measurement, its table and its panel are :mod:`vrcorrect.studies.acuity_chart`;
this module parses the options, prints and writes."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import check_writable, text_writer, write_together
from ..plumbing.imageio import png_writer
from ..specs.display import get_display
from ..studies.acuity_chart import (METHODS, acuity_panel, check_methods, line_table, measure_acuity, method_label,
                                     summary_line)
from .common import add_model_options, kernel_options, load_eye


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``acuity`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "acuity", help="which line of an eye chart the eye reads, uncorrected and with each correction",
        description=("Simulate reading a logMAR chart of Sloan letters (Watson & Ahumada 2008: the eye's optics, "
                     "internal noise, an ideal observer; a line is read at 60% correct), uncorrected and with "
                     "each correction method, and print the acuity in logMAR and Snellen."))
    add_model_options(p)
    p.add_argument("--methods", nargs="+", default=["fast"], metavar="METHOD",
                   help="corrections to read with: some of " + ", ".join(METHODS) + " (default fast); "
                        "uncorrected is always read")
    p.add_argument("--json", metavar="OUT.json", nargs="?", const="-",
                   help="write the readings as JSON to OUT.json, or print them when no file (or '-') is given")
    p.add_argument("--png", metavar="OUT.png", help="draw the chart as the eye sees it, a column per method")
    p.add_argument("--trials", type=int, default=400, help="noisy trials per letter (default 400)")
    p.add_argument("--seed", type=int, default=0, help="seed of the observer's noise (default 0)")
    p.add_argument("--top-logmar", type=float, default=1.0, help="top line (default 1.0, 20/200)")
    p.add_argument("--bottom-logmar", type=float, default=-0.3, help="bottom line (default -0.3, 20/10)")
    p.add_argument("--contrast", type=float, default=1.0,
                   help="scale the corrections' target contrast (0, 1] (default 1)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_acuity)
    return p


def _check_outputs(args: argparse.Namespace) -> None:
    if args.json is not None and args.json != "-":
        if Path(args.json).suffix.lower() != ".json":
            raise ValidationError("--json", args.json, "a path ending in .json, or '-'")
        check_writable(Path(args.json), force=args.force)
    if args.png is not None:
        if Path(args.png).suffix.lower() != ".png":
            raise ValidationError("--png", args.png, "a path ending in .png")
        check_writable(Path(args.png), force=args.force)


def cmd_acuity(args: argparse.Namespace) -> int:
    """``vrcorrect acuity``: read the chart, print the table, write the JSON and the panel."""
    from ..vision.acuity import Observer, chart_lines  # on use: start-up time (apps/__init__)

    methods = check_methods(args.methods)
    _check_outputs(args)
    if not (0.0 < args.contrast <= 1.0):
        raise ValidationError("--contrast", args.contrast, "a number in (0, 1]")
    observer = Observer(trials_per_letter=args.trials, seed=args.seed)
    options = kernel_options(args)
    rx_path, eye = load_eye(args)
    display = get_display(args.display)
    chart_lines(display, args.top_logmar, args.bottom_logmar)          # bad chart limits: fail before the work
    bar = tqdm(desc="acuity", unit="step", disable=None, leave=False, file=sys.stderr)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        result = measure_acuity(eye, display, methods, options, observer=observer, top_logmar=args.top_logmar,
                                bottom_logmar=args.bottom_logmar, contrast=args.contrast, progress=progress)
    finally:
        bar.close()
    report = result.as_dict()
    report["prescription"] = str(rx_path)
    report["eye"]["which"] = args.eye
    out = sys.stderr if args.json == "-" else sys.stdout
    distance = result.kernel.report.viewing.distance_m
    where = "optical infinity" if math.isinf(distance) else f"{distance:.2f} m"
    print(f"{args.eye} eye {eye.sphere_D:+.2f} / {eye.cylinder_D:+.2f} x {eye.axis_deg:g}, pupil "
          f"{eye.pupil_diameter_mm:g} mm, on {display.title} ({display.pixels_per_degree:.1f} ppd, seen at {where})",
          file=out)
    for row in line_table(result):
        print(row, file=out)
    timing = ", ".join(f"{method_label(k)} {v:.1f} s" for k, v in result.seconds.items())
    print(f"(* = read: at least {observer.criterion:.0%} correct; - = below the display's pixels; "
          f"noise {observer.noise_contrast_arcmin:g} contrast x arcmin; {timing})", file=out)
    print("ideal observer (templates seen through the same eye and correction):", file=out)
    print("  " + summary_line(result), file=out)
    print("sharp-template observer (knows the letters as they look with glasses):", file=out)
    print("  " + summary_line(result, "sharp"), file=out)
    outputs = []
    if args.png:
        title = (f"{args.eye} eye {eye.sphere_D:+.2f} / {eye.cylinder_D:+.2f} x {eye.axis_deg:g} on "
                 f"{display.title}, seen at {where}")
        outputs.append((Path(args.png), png_writer(args.png, acuity_panel(result, title).astype(np.float64) / 255.0)))
    text = json.dumps(report, indent=2) + "\n"
    if args.json and args.json != "-":
        outputs.append((Path(args.json), text_writer(text)))
    write_together(outputs, force=args.force)   # the files: all or nothing
    for path, _ in outputs:
        print(f"wrote {path}", file=out)
    if args.json == "-":
        sys.stdout.write(text)
    return 0
