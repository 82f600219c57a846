"""``vrcorrect correct``: pre-correct an image for an eye with one of the solvers (or the learned model)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from tqdm import tqdm

from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import check_readable, check_writable, text_writer, write_together
from ..plumbing.imageio import png_writer, read_image
from ..runtime.model_path import DEFAULT_MODEL
from ..specs.display import decode, encode, get_display
from .common import (
    add_model_options,
    build_eye_kernel,
    check_memory,
    finite_json,
    kernel_options,
    load_eye,
    print_notes,
)


def cmd_correct(args: argparse.Namespace) -> int:
    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    check_writable(out, force=args.force)
    if args.report:
        if Path(args.report).suffix.lower() != ".json":
            raise ValidationError("--report", args.report, "a path ending in .json")
        check_writable(Path(args.report), force=args.force)
    if args.iterations is not None and not (1 <= args.iterations <= 100000):
        raise ValidationError("--iterations", args.iterations, "1 to 100000")
    if not (0.0 < args.contrast <= 1.0):
        raise ValidationError("--contrast", args.contrast, "a number in (0, 1]")
    if args.tolerance is not None:
        if args.method not in ("fast", "conventional"):
            raise ValidationError("--tolerance", args.tolerance, "only with --method fast or conventional")
        if not (0.0 <= args.tolerance < 1.0):
            raise ValidationError("--tolerance", args.tolerance, "a number from 0 to 1")
    if args.iterations is not None and args.method in ("wiener", "learned"):
        raise ValidationError("--iterations", args.iterations, f"nothing: {args.method} is one pass")
    if args.model is not None and args.method != "learned":
        raise ValidationError("--model", args.model, "only with --method learned")
    check_readable(args.input)                      # before the heavy imports: a typo is told at once
    from ..physics.kernel import build_reference_kernel  # on use: start-up time (apps/__init__)
    from ..solvers import make_problem, solve
    from ..vision.metrics import evaluate_seen

    learned = _learned_model(args) if args.method == "learned" else None
    rx_path, eye = load_eye(args)
    display = get_display(args.display)
    if learned is not None:                         # the model's range and display, before any work
        learned.check(eye, display)
    notes: list[str] = []
    image = read_image(args.input, notes)
    print_notes(notes)
    check_memory(args.method, *image.shape[:2])
    target = decode(display, image)
    t0 = time.perf_counter()
    kernel = build_eye_kernel(args, eye, display)
    reference = build_reference_kernel(eye, display, kernel_options(args)) if args.reference == "glasses" else None
    t1 = time.perf_counter()
    problem = make_problem(target, kernel, reference, contrast=args.contrast)
    options: dict = {}
    if args.iterations is not None:
        options["iterations" if args.method == "paper" else "max_iterations"] = args.iterations
    if args.tolerance is not None:
        options["tolerance"] = args.tolerance
    bar = None
    if args.method in ("paper", "fast", "conventional"):
        bar = tqdm(desc=f"{args.method}", unit="it", disable=None, leave=False, file=sys.stderr)
    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()
    try:
        if learned is not None:
            options["model"] = learned.for_eye(eye, display, kernel, reference)   # refused outside its range
            options["settings"] = {"model": str(learned.path), "providers": list(learned.providers),
                                   "ranges": learned.ranges.as_dict(), "version": learned.metadata.get("vrcorrect.version")}
        result = solve(problem, args.method, progress=progress, **options)
    finally:
        if bar is not None:
            bar.close()
    outputs = [(out, png_writer(out, encode(display, result.image), bits=16 if args.sixteen_bit else 8))]
    if args.report:
        corrected, _ = evaluate_seen(result.image, target, kernel, display, target_lms=problem.target_lms)
        uncorrected, _ = evaluate_seen(target, target, kernel, display, target_lms=problem.target_lms)
        report = {
            "input": str(args.input), "output": str(out), "prescription": str(rx_path), "eye": args.eye,
            "display": display.name, "method": result.method, "reference": problem.reference,
            "contrast": args.contrast, "iterations": result.iterations,
            "seconds": {"kernel": t1 - t0, "solve": result.seconds},
            "objective": result.objective, "objective_uncorrected": uncorrected.objective,
            "metrics": corrected.__dict__, "metrics_uncorrected": uncorrected.__dict__,
            "settings": result.settings, "kernel_decisions": list(kernel.decisions),
        }
        report_notes = list(notes)                  # what was said about the input, then the JSON repairs
        report = finite_json(report, "", report_notes)
        if report_notes:
            report["notes"] = report_notes
        text = json.dumps(report, indent=2, default=float, allow_nan=False) + "\n"
        outputs.append((Path(args.report), text_writer(text)))
    # the image and its report appear together or not at all (an interruption leaves neither)
    write_together(outputs, force=args.force)
    print(f"wrote {out}: {result.method} correction for the {args.eye} eye on {display.title} "
          f"(objective {result.objective:.3g}, {result.iterations} iterations, {result.seconds:.2f} s)"
          + (f"; report {args.report}" if args.report else ""))
    return 0


def _learned_model(args: argparse.Namespace):
    """The learned model of ``--model`` (default: the shipped one), its reference checked."""
    from ..runtime.learned import LearnedModel  # on use: start-up time (apps/__init__)

    path = Path(args.model) if args.model else DEFAULT_MODEL
    if args.model is None and not path.is_file():
        raise InputError(f"no default learned model is installed ({path}); pass --model PATH "
                         "(a model exported by tools/export_onnx.py), or use --method wiener or fast")
    model = LearnedModel(path)
    if model.reference != args.reference:
        raise ValidationError("--reference", args.reference, f"{model.reference} (the target {path.name} was "
                              "trained for)")
    return model


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("correct", help="pre-correct an image for an eye (the displayed image)")
    p.add_argument("input", metavar="IN", help="image file (sRGB code values)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.png")
    add_model_options(p)
    p.add_argument("--method", choices=("conventional", "paper", "fast", "wiener", "learned"), default="fast",
                   help="correction method (default fast)")
    p.add_argument("--model", metavar="MODEL.onnx",
                   help="learned: the exported model (default: models/default.onnx when shipped)")
    p.add_argument("--iterations", type=int, help="iterations (paper) or iteration limit (fast, conventional)")
    p.add_argument("--tolerance", type=float, help="fast, conventional: relative stopping tolerance")
    p.add_argument("--contrast", type=float, default=1.0, help="scale the target's contrast (0, 1] (default 1)")
    p.add_argument("--reference", choices=("glasses", "ideal"), default="glasses",
                   help="target: what the eye sees with glasses (default) or the paper's blur-free A t")
    p.add_argument("--report", metavar="REPORT.json", help="write metrics, timings and settings")
    p.add_argument("--16bit", dest="sixteen_bit", action="store_true", help="write a 16-bit PNG")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_correct)
