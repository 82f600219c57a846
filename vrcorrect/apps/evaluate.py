"""``vrcorrect evaluate``: the paper's evaluation, every correction method on five refractive
problems. The run, its panels and tables are :mod:`vrcorrect.studies.evaluation`; this module
parses the options and prints the summary."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..plumbing.images import bundled_images, check_size, folder_images
from ..specs.display import get_display
from ..specs.vocabulary import Method, names
from ..studies.evaluation import DEFAULT_METHODS, PRESCRIPTIONS, check_methods, run_evaluation


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``evaluate`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "evaluate", help="the paper's evaluation: every method on five refractive problems, by JOD and acuity",
        description=("Run the correction methods on five refractive problems at +-1.5 D (myopia, hyperopia, "
                     "myopic, hyperopic and mixed astigmatism; 4 mm pupil, display at optical infinity) and "
                     "score what the eye sees (JOD, the primary score; FLIP, SSIM, PSNR) and the eye-chart "
                     "acuity of each problem's eye: results.csv, results.md and panels/*.png in --out."))
    p.add_argument("--images", metavar="DIR",
                   help="folder of PNG/JPEG images (default: scikit-image's colour photos and the charts)")
    p.add_argument("--out", default="evaluation", metavar="DIR", help="output folder (default ./evaluation)")
    p.add_argument("--size", type=int, default=256, metavar="N",
                   help="centre-crop and resize each image to N x N pixels (default 256)")
    p.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), metavar="METHOD",
                   choices=names((Method.CONVENTIONAL, Method.PAPER, Method.FAST, Method.WIENER)),
                   help="methods to compare, some of conventional paper fast wiener (default: paper fast); the "
                        "uncorrected image is always scored. "
                        "conventional (Montalto et al. 2015) runs only when named, e.g. --methods conventional "
                        "paper fast: it is by far the slowest, tens of minutes (41 of a 47-minute run at 512x512 "
                        "on 2 cores)")
    p.add_argument("--display", default="desktop", metavar="PRESET",
                   help="display preset or profile .json (default desktop; list: vrcorrect displays)")
    p.add_argument("--no-acuity", dest="acuity", action="store_false",
                   help="skip the eye-chart acuity of each problem's eye (about 10-60 s per problem)")
    p.add_argument("--force", action="store_true", help="overwrite earlier results in --out")
    p.set_defaults(func=cmd_evaluate)
    return p


def cmd_evaluate(args: argparse.Namespace) -> int:
    """``vrcorrect evaluate``: run :func:`run_evaluation` and print where the outputs are and the summary."""
    size = check_size(args.size)
    methods = check_methods(args.methods)
    display = get_display(args.display)
    images = folder_images(args.images, size) if args.images else bundled_images(size)
    result = run_evaluation(Path(args.out), images, display, methods=methods, size=size,
                            progress=True, force=args.force, acuity=args.acuity)
    files = result["files"]
    print(f"wrote {files['csv']}, {files['markdown']} and {len(files['panels'])} panels in "
          f"{Path(args.out) / 'panels'} ({len(images)} images x {len(PRESCRIPTIONS)} prescriptions x "
          f"{len(methods) + 1} methods, {result['seconds']:.1f} s)")
    print()
    print(result["summary_markdown"])
    if result["wins"]:
        print()
        for line in result["wins"]:
            print(line)
    if result["verdicts"]:
        print()
        for line in result["verdicts"]:
            print(line)
    return 0
