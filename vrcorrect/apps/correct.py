"""``vrcorrect correct``: pre-correct an image for an eye with one of the solvers (or the learned model);
a clip frame by frame (the ceiling the real-time path is judged against), into a folder of frames."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import check_readable, check_writable, text_writer, write_together
from ..plumbing.imageio import png_writer, read_image
from ..runtime.model_path import DEFAULT_MODEL
from ..specs.display import decode, encode, get_display
from ..specs.vocabulary import Method, names
from . import clips
from .common import (
    PupilPerFrame,
    add_model_options,
    add_pupil_options,
    build_design,
    picture_band,
    check_memory,
    check_not_input,
    finite_json,
    kernel_decisions,
    kernel_options,
    load_eye_and_age,
    parse_pupil,
    print_notes,
    small_image_note,
    viewing_pupil,
)
from .correct_panel import check_panel, panel_writer
from .progress import duration_text


def cmd_correct(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    check_not_input(args)                                 # never over the input, --force or not
    clip = clips.input_clip(args)                         # a clip is checked before any heavy import
    if clip is not None:
        return _correct_clip(args, clips.plan_frames(clip, args, None))
    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    check_writable(out, force=args.force)
    rho = _check_options(args)
    check_readable(args.input)                      # before the heavy imports: a typo is told at once
    from ..solvers import make_problem, objective, solve  # on use: start-up time (apps/__init__)
    from ..solvers.guard import guard_blend  # on use: start-up time (apps/__init__)
    from ..vision.visibility import ViewingLight  # on use: start-up time (apps/__init__)
    from ..solvers.problem import (
        make_design_problem,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )
    from ..vision.metrics import evaluate_seen  # on use: start-up time (apps/__init__: the parser loads no layer below)

    notes: list[str] = []
    image = read_image(args.input, notes)           # a broken input is the one line, before any other
    learned, rx_path, eye, display, age = _eye_and_model(args)
    print_notes(notes)
    check_memory(args.method, *image.shape[:2])
    target = decode(display, image)
    pupil, pupil_lines = viewing_pupil(args, eye, display, target, age)
    band, band_line = picture_band(args, display, target)
    for line in pupil_lines + ([band_line] if band_line else []):
        print(f"vrcorrect: {line}", flush=True)          # stdout: an error stays the one line on stderr
    t0 = time.perf_counter()
    design = build_design(args, eye, display, pupil, args.reference, band=band)
    guards = _guard_designs(args, eye, display, pupil) if rho is not None else []
    kernel, reference = design.kernel, design.reference
    t1 = time.perf_counter()
    small = small_image_note(image.shape[1], image.shape[0], kernel.size, "the correction")
    if small:
        print_notes([small])
    problem = make_design_problem(target, design, contrast=args.contrast)
    seen_problem = problem if not design.robust else make_problem(target, design.nominal, design.nominal_reference,
                                                                  contrast=args.contrast)
    options = _solver_options(args, learned, eye.with_changes(pupil_diameter_mm=pupil), display, kernel, reference,
                              problem.capped)
    bar = None
    if args.method in (Method.PAPER, Method.FAST, Method.CONVENTIONAL):
        bar = tqdm(desc=f"{args.method}", unit="it", disable=None, leave=False, file=sys.stderr)
    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()
    t2 = time.perf_counter()
    aside = _stands_aside(design, args.method)
    try:
        result = _as_it_is(problem, args.method) if aside else \
            solve(problem, args.method, progress=progress, **options)
    finally:
        if bar is not None:
            bar.close()
    guarded = None
    if rho is not None and not aside:
        guarded = guard_blend(result.image, target, _guard_problems(target, guards, args.contrast), rho,
                              args.guard_measure, ViewingLight.of(display))
        result.image = guarded.image
        result.objective = objective(result.image, problem)
    t3 = time.perf_counter()
    outputs = [(out, png_writer(out, encode(display, result.image), bits=16 if args.sixteen_bit else 8))]
    if args.report or args.panel:
        seen = design.nominal
        corrected, corrected_images = evaluate_seen(result.image, target, seen, display,
                                                    target_lms=seen_problem.target_lms)
        uncorrected, uncorrected_images = evaluate_seen(target, target, seen, display,
                                                        target_lms=seen_problem.target_lms)
    if args.panel:
        outputs.append((Path(args.panel), panel_writer(args, eye, display, pupil, [
            ("no correction", uncorrected, uncorrected_images),
            ("the picture as it is" if aside else f"{result.method} correction", corrected, corrected_images)])))
    if args.report:
        report = {
            "input": str(args.input), "output": str(out), "prescription": str(rx_path), "eye": args.eye,
            "display": display.name, "method": result.method, "reference": problem.reference,
            "contrast": args.contrast, "iterations": result.iterations,
            "pupil_mm": pupil, "pupil": pupil_lines, "robust": design.robust, "band": band_line,
            "light_cap": problem.capped, "design": design.describe(),
            "seconds": {"kernel": t1 - t0, "solve": result.seconds},
            "objective": result.objective, "objective_uncorrected": objective(target, problem),
            "metrics": corrected.__dict__, "metrics_uncorrected": uncorrected.__dict__,
            "settings": result.settings, "kernel_decisions": kernel_decisions(seen),
            "guard": _guard_report(rho, guarded),
        }
        outputs.append((Path(args.report), _report_writer(report, notes)))
    t4 = time.perf_counter()
    # the image and its report appear together or not at all (an interruption leaves neither)
    write_together(outputs, force=args.force)
    design_text = (f"designed for a {pupil:.2f} mm pupil" + (f", robust over {len(design.members)} eyes"
                                                               if design.robust else "")
                   + (" of the page band" if _band_name(design) == "page" else ""))
    parts = [f"eye model {duration_text(t1 - t0)}", "no solve" if aside else
             f"{_solve_text(result.method, result.iterations)} {duration_text(t3 - t2)}"]
    if args.report or args.panel:
        parts.append(f"{'report' if args.report else 'panel'} (what the eye sees, judged) {duration_text(t4 - t3)}")
    rest = time.perf_counter() - started - (t1 - t0) - (t3 - t2) - (t4 - t3 if args.report or args.panel else 0.0)
    parts.append(f"start-up, reading and writing {duration_text(rest)}")
    if aside:
        print(f"wrote {out}: the picture as it is for the {args.eye} eye on {display.title}: {NOTHING_TO_CORRECT}"
              + _also(args))
        print_notes([LAG_NOTE] if eye.accommodative_lag_D == 0.0 and eye.accommodation_D > 0.0 else [])
    else:
        print(f"wrote {out}: {result.method} correction for the {args.eye} eye on {display.title}, {design_text} "
              f"(objective {result.objective:.3g})" + _also(args))
    if guarded is not None:
        print("  " + _guard_text(rho, guarded))
    elif _sphere_alone(eye) and not aside:
        print_notes(_sphere_alone_notes(eye, age))
    print(f"  took {duration_text(time.perf_counter() - started)}: " + ", ".join(parts))
    return 0


#: What ``correct`` says where every eye it designs for sees the display as well as with glasses.
NOTHING_TO_CORRECT = ("this eye sees the display as well as with its glasses (in focus there, after its accommodation), "
                      "so there is nothing to correct")

#: What ``correct`` adds where an eye that focuses on the display states no lag (docs/usage.md).
LAG_NOTE = ("modelled as focusing exactly on the display; most eyes lag behind a near display (0.25-0.75 D at 40 cm): "
            "if yours was measured (MEM retinoscopy), state it as accommodative_lag_D or with rx new --lag")


def _stands_aside(design, method: str) -> bool:
    """Whether the picture is shown as it is: every eye designed for sees as with its glasses (and a method
    other than ``none``, which shows it so anyway)."""
    return design.sees_as_with_glasses and method != Method.NONE


def _as_it_is(problem, method: str):
    """The picture shown as it is (nothing to correct; under ``--contrast``, as that scales it): a result
    of no iterations, the method's name kept."""
    from ..solvers import objective  # on use: start-up time (apps/__init__)
    from ..solvers.problem import SolveResult  # on use: start-up time (apps/__init__)

    image = np.asarray(problem.target, np.float32)
    return SolveResult(image=image, method=method, seconds=0.0, iterations=0, objective=objective(image, problem),
                       settings={"nothing_to_correct": True})


#: What ``correct`` says, without ``--guard``, for an eye of sphere alone (docs/realtime.md, "Eyes of sphere alone").
SPHERE_ALONE_NOTE = ("an eye of sphere alone may see this correction worse than none if it is 0.5 D nearer focus "
                     "than prescribed; --guard 1.1 --guard-measure visibility blends the correction towards the "
                     "picture where it sees that harm (on fresh pictures it spared 13 of 15 such views and kept "
                     "about a third of the gain at 3 mm: docs/realtime.md, 'Eyes of sphere alone')")


#: What ``correct`` adds for such an eye modelled as one that cannot focus, without an age to say otherwise.
NO_AGE_NOTE = ("this eye is modelled as one that cannot focus (accommodation 0, no age_years): if it can, give the "
               "prescription's age_years and leave accommodation_D out (or state its amplitude): an eye that focuses on "
               "the display by itself needs no correction, and one designed for blur it focuses away makes its view "
               "worse")


def _sphere_alone_notes(eye, age: float | None) -> list[str]:
    """The notes for an eye of sphere alone: the guard's, and :data:`NO_AGE_NOTE` where it may apply."""
    return [SPHERE_ALONE_NOTE] + ([NO_AGE_NOTE] if age is None and eye.accommodation_D == 0.0 else [])


def _sphere_alone(eye) -> bool:
    """Whether the eye's correction is sphere alone (a cylinder under 0.25 D): the eyes the default band
    has been seen to fail 0.5 D nearer focus."""
    return abs(float(eye.cylinder_D)) < 0.25


#: The factors ``--guard`` takes: 1 (never worse than none, by the objective) to 10.
GUARD_RANGE = (1.0, 10.0)


def parse_guard(text: str) -> float | None:
    """``--guard``: None (``off``) or the factor RHO, refused outside 1..10 naming the flag."""
    lo, hi = GUARD_RANGE
    allowed = (f"off, or a factor from {lo:g} to {hi:g}: the most error, times none's, the eye with the sphere "
               "0.5 D off may see")
    if str(text).strip().lower() == "off":
        return None
    try:
        rho = float(text)
    except ValueError:
        raise ValidationError("--guard", text, allowed) from None
    if not (lo <= rho <= hi):                        # NaN too
        raise ValidationError("--guard", text, allowed)
    return rho


def _guard_offsets() -> list[float]:
    """The guard eyes' sphere offsets from the prescription, dioptres."""
    from ..solvers.guard import GUARD_SPHERE_D  # on use: start-up time (apps/__init__)

    return [-GUARD_SPHERE_D, GUARD_SPHERE_D]


def _guard_pupils(measure: str) -> list[float]:
    """The pupils (mm) through which the prescribed eye is a guard eye too: the lightness and visibility
    guards'."""
    from ..solvers.guard import GUARD_PUPILS_MM, PUPIL_GUARD_MEASURES  # on use: start-up time (apps/__init__)

    return list(GUARD_PUPILS_MM) if measure in PUPIL_GUARD_MEASURES else []


def _guard_designs(args: argparse.Namespace, eye, display, pupil: float, fixed: list | None = None) -> list:
    """The guard eyes (``--guard``), each a design of one eye: the prescription with the sphere 0.5 D
    off either way, seen at the viewing pupil; then the eyes of :func:`_pupil_guards` (``fixed``: those
    already built, which no viewing pupil changes; a clip builds them once)."""
    return ([build_design(args, eye.with_changes(sphere_D=eye.sphere_D + s), display, pupil, args.reference,
                          robust=False) for s in _guard_offsets()]
            + (fixed if fixed is not None else _pupil_guards(args, eye, display)))


def _pupil_guards(args: argparse.Namespace, eye, display) -> list:
    """With ``--guard-measure lightness`` or ``visibility``, the prescribed eye through each pupil of
    :func:`_guard_pupils`."""
    return [build_design(args, eye, display, q, args.reference, robust=False)
            for q in _guard_pupils(args.guard_measure)]


def _guard_problems(target: np.ndarray, designs: list, contrast: float) -> list:
    from ..solvers import make_problem  # on use: start-up time (apps/__init__)

    return [make_problem(target, d.nominal, d.nominal_reference, contrast=contrast) for d in designs]


def check_guard(args: argparse.Namespace) -> float | None:
    """``--guard`` parsed, and ``--guard-measure`` refused without it."""
    rho = parse_guard(args.guard)
    if rho is None and args.guard_measure != "objective":
        raise ValidationError("--guard-measure", args.guard_measure, "only with --guard RHO (the guard is off)")
    return rho


def _guard_report(rho: float | None, guarded) -> dict | None:
    """The report's ``guard``: null without ``--guard``.  The ratios are each guard eye's, in the order
    of the sphere offsets, then the pupils."""
    if guarded is None:
        return None
    m = guarded.measure
    return {"rho": rho, "measure": m, "sphere_offsets_D": _guard_offsets(), "pupils_mm": _guard_pupils(m),
            "weight": guarded.weight, f"{m}_ratio_before": list(guarded.ratios("before")),
            f"{m}_ratio_after": list(guarded.ratios("after"))}


#: The guard eyes and the error, in words, by ``--guard-measure`` (its choices: the parser loads no solver, so
#: this copies ``solvers.guard.GUARD_MEASURES``; tests/test_guard.py keeps the two in step).
GUARD_WORDS = {"objective": ("the eyes with the sphere 0.5 D off", "by the objective"),
               "lightness": ("the eyes with the sphere 0.5 D off or a pupil of 2.5 to 5.5 mm",
                             "by the lightness-like error"),
               "visibility": ("the eyes with the sphere 0.5 D off or a pupil of 2.5 to 5.5 mm",
                              "by the visibility scale")}


def _guard_text(rho: float, guarded) -> str:
    """The guard in words, for the command's output."""
    eyes, error = GUARD_WORDS[guarded.measure]
    worst = max(guarded.ratios("before"))
    if guarded.weight >= 1.0:
        return (f"guard {rho:g}: the correction shown as designed ({eyes} see at most {worst:.2f} x none's error "
                f"{error})")
    if guarded.weight <= 0.0:
        return (f"guard {rho:g}: the picture shown uncorrected (one of {eyes} would have seen {worst:.2f} x none's "
                f"error {error}, and any part of the correction more than {rho:g} x)")
    return (f"guard {rho:g}: the correction shown {guarded.weight:.2f} of the way from the picture to it (one of "
            f"{eyes} would have seen {worst:.2f} x none's error {error}; now {max(guarded.ratios('after')):.2f} x)")


def _band_name(design) -> str | None:
    """The band a design was made over, for a clip's report: ``page`` (the page band: no light cap),
    ``default``, or None (``--robust off``)."""
    return None if not design.robust else "default" if design.capped else "page"


def _solve_text(method: str, iterations: int) -> str:
    """The solve in words: its iterations where the method iterates (one pass otherwise)."""
    if method in (Method.LEARNED, Method.WIENER) or not iterations:
        return f"{method} (one pass)"
    return f"{method} ({iterations} iterations)"


def _check_options(args: argparse.Namespace) -> float | None:
    """The report path and the solver options, checked before any work; ``--guard``'s factor (None: off)."""
    if args.report:
        if Path(args.report).suffix.lower() != ".json":
            raise ValidationError("--report", args.report, "a path ending in .json")
        check_writable(Path(args.report), force=args.force)
    check_panel(args)
    if args.iterations is not None and not (1 <= args.iterations <= 100000):
        raise ValidationError("--iterations", args.iterations, "1 to 100000")
    if not (0.0 < args.contrast <= 1.0):
        raise ValidationError("--contrast", args.contrast, "a number in (0, 1]")
    if args.tolerance is not None:
        if args.method not in (Method.FAST, Method.CONVENTIONAL):
            raise ValidationError("--tolerance", args.tolerance, "only with --method fast or conventional")
        if not (0.0 <= args.tolerance < 1.0):
            raise ValidationError("--tolerance", args.tolerance, "a number from 0 to 1")
    if args.iterations is not None and args.method in (Method.WIENER, Method.LEARNED):
        raise ValidationError("--iterations", args.iterations, f"nothing: {args.method} is one pass")
    if args.model is not None and args.method != Method.LEARNED:
        raise ValidationError("--model", args.model, "only with --method learned")
    parse_pupil(args.pupil)
    return check_guard(args)


def _eye_and_model(args: argparse.Namespace):
    """The learned model (``--method learned``) and its range checked against the eye and display,
    before any work: ``(learned or None, prescription path, eye, display)``."""
    learned = _learned_model(args) if args.method == Method.LEARNED else None
    rx_path, eye, age = load_eye_and_age(args)
    display = get_display(args.display)
    if learned is not None:                         # the model's range and display, before any work
        learned.check(eye, display, kernel_options(args).optics.viewing_distance_m)
    return learned, rx_path, eye, display, age


def _solver_options(args: argparse.Namespace, learned, eye, display, kernel, reference, capped: bool = False) -> dict:
    options: dict = {}
    if args.iterations is not None:
        options["iterations" if args.method == Method.PAPER else "max_iterations"] = args.iterations
    if args.tolerance is not None:
        options["tolerance"] = args.tolerance
    if learned is not None:
        # refused outside its range; the unrolled model holds the light cap (the older format has none)
        options["model"] = learned.for_eye(eye, display, kernel, reference, capped=capped)
        options["settings"] = {"model": str(learned.path), "providers": list(learned.providers),
                               "ranges": learned.ranges.as_dict(), "version": learned.metadata.get("vrcorrect.version"),
                               "light_cap": options["model"].capped}
    return options


def _also(args: argparse.Namespace) -> str:
    """The other files ``correct`` wrote, for its line."""
    return "".join(f"; {what} {path}" for what, path in (("report", args.report), ("panel", args.panel)) if path)


def _report_writer(report: dict, notes: list[str]):
    """The report as strict JSON (non-finite numbers null, each explained in ``notes``)."""
    report_notes = list(notes)                      # what was said about the input, then the JSON repairs
    report = finite_json(report, "", report_notes)
    if report_notes:
        report["notes"] = report_notes
    return text_writer(json.dumps(report, indent=2, default=float, allow_nan=False) + "\n")


#: A clip's report scores it with ColorVideoVDP in video mode up to this many frame pixels (frames x
#: width x height: 90 frames of 360x360); the seen frames are kept in memory for it.
VIDEO_JOD_MAX_PIXELS = 12_000_000
#: The rate a clip without one is scored at (a headset's).
VIDEO_JOD_DEFAULT_FPS = 90.0


def _correct_clip(args: argparse.Namespace, plan: clips.ClipPlan) -> int:
    """Each frame of a clip solved on its own (the offline ceiling), into a folder of frames."""
    started = time.perf_counter()
    folder = clips.output_folder(args, plan)        # checked before any work
    check_panel(args, clip=True)
    rho = _check_options(args)
    from ..solvers import objective, solve  # on use: start-up time (apps/__init__)
    from ..solvers.problem import (
        make_design_problem,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )
    from ..vision.forward import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
        lms_to_display,
        simulate_lms,
    )

    from ..solvers.guard import guard_blend  # on use: start-up time (apps/__init__)
    from ..vision.visibility import ViewingLight  # on use: start-up time (apps/__init__)

    learned, rx_path, eye, display, age = _eye_and_model(args)
    guards, fixed = {}, None
    viewing = ViewingLight.of(display)                 # the guard's light and pixels per degree, for every frame
    clip = plan.clip
    print_notes(clip.notes)
    check_memory(args.method, clip.size[1], clip.size[0])
    # each source frame designed for its own light
    design_for = PupilPerFrame(args, eye, display, age, lambda p, b: build_design(args, eye, display, p, args.reference,
                                                                                  band=b), bands=True)
    _, design = design_for(decode(display, next(iter(clips.planned_frames(plan)))[1]))
    kernel, reference = design.nominal, design.nominal_reference
    options: dict | None = None
    scored = bool(args.report) and plan.count * clip.size[0] * clip.size[1] <= VIDEO_JOD_MAX_PIXELS
    seen: dict[str, list] = {"target": [], "corrected": [], "uncorrected": []}

    def srgb_seen(lms):
        return encode("srgb", lms_to_display(lms, kernel)).astype(np.float32)

    per_frame: list[dict] = []
    last_source, result, entry, last_design = -1, None, None, None
    bits = 16 if args.sixteen_bit else 8
    with folder, clips.frames_bar(f"correct ({args.method})", plan.count) as bar:
        for index, (source, frame) in enumerate(clips.planned_frames(plan)):
            if source != last_source:               # a repeated source frame has the same correction
                linear = decode(display, frame)
                pupil, design = design_for(linear)
                kernel = design.nominal
                problem = make_design_problem(linear, design, contrast=args.contrast)
                if design is not last_design:      # a new pupil or band (designs are kept per pupil and band)
                    options = _solver_options(args, learned, eye.with_changes(pupil_diameter_mm=pupil), display,
                                              design.kernel, design.reference, problem.capped)
                last_design = design
                aside = _stands_aside(design, args.method)
                result = _as_it_is(problem, args.method) if aside else solve(problem, args.method, **options)
                if rho is not None and not aside:   # the guard eyes at this frame's pupil, built once per pupil
                    if pupil not in guards:
                        if fixed is None:
                            fixed = _pupil_guards(args, eye, display)
                        guards[pupil] = _guard_designs(args, eye, display, pupil, fixed)
                    guarded = guard_blend(result.image, linear, _guard_problems(linear, guards[pupil], args.contrast),
                                          rho, args.guard_measure, viewing)
                    result.image, result.objective = guarded.image, objective(guarded.image, problem)
                entry = {"source_frame": source, "objective": result.objective, "band": _band_name(design),
                         "guard_weight": guarded.weight if rho is not None and not aside else None,
                         "nothing_to_correct": aside,
                         "objective_uncorrected": objective(problem.target, problem) if args.report else None,
                         "iterations": result.iterations, "seconds": result.seconds}
                if scored:
                    seen_target = simulate_lms(problem.target, design.nominal_reference)[0] \
                        if design.nominal_reference is not None else problem.target @ kernel.matrix.T
                    images = (srgb_seen(seen_target), srgb_seen(simulate_lms(result.image, kernel)[0]),
                              srgb_seen(simulate_lms(problem.target, kernel)[0]))
                last_source = source
            folder.write(index, encode(display, result.image), bits=bits)
            per_frame.append({"frame": index, "file": folder.name(index), **entry})
            if scored:
                for name, image in zip(seen, images):
                    seen[name].append(image)
            bar.advance()
        others = []
        if args.report:
            report = _clip_report(args, plan, rx_path, display, result, reference, kernel, per_frame, seen if scored
                                  else None, design_for.seconds, rho)
            others.append((Path(args.report), _report_writer(report, list(clip.notes))))
        folder.commit(others)                       # the frames and the report appear together or not at all
    objectives = [f["objective"] for f in per_frame]
    print(f"wrote {args.output}: {plan.count} frames, {args.method} correction for the {args.eye} eye on "
          f"{display.title} ({plan.text}; median objective {float(np.median(objectives)):.3g})"
          + (f"; report {args.report}" if args.report else ""))
    print(f"  took {duration_text(time.perf_counter() - started)}: eye model {duration_text(design_for.seconds)}, "
          f"{_solve_text(args.method, int(np.median([f['iterations'] for f in per_frame])))} "
          f"{duration_text(sum(f['seconds'] for f in per_frame))} for the frames")
    shown_as_is = sum(f["nothing_to_correct"] for f in per_frame)
    if shown_as_is:
        print(f"  {shown_as_is} of {len(per_frame)} frames shown as they are: {NOTHING_TO_CORRECT}")
    weights = [f["guard_weight"] for f in per_frame if f["guard_weight"] is not None]
    if rho is not None and weights:
        print(f"  guard {rho:g}: {sum(w < 1.0 for w in weights)} of {len(weights)} frames blended towards the "
              f"picture (the least weight {min(weights):.2f})")
    elif rho is None and _sphere_alone(eye) and shown_as_is < len(per_frame):
        print_notes(_sphere_alone_notes(eye, age))
    return 0


def _clip_report(args, plan: clips.ClipPlan, rx_path, display, result, reference, kernel, per_frame: list[dict],
                 seen: dict[str, list] | None, kernel_s: float, rho: float | None) -> dict:
    """The report of a clip: each frame's objective (and uncorrected), a summary, and ColorVideoVDP
    in video mode of what the eye sees, corrected and uncorrected, against the target."""
    objectives = np.array([f["objective"] for f in per_frame], dtype=np.float64)
    uncorrected = np.array([f["objective_uncorrected"] for f in per_frame], dtype=np.float64)
    fraction = objectives / np.where(uncorrected > 0, uncorrected, np.nan)
    fps = plan.frames_per_s or VIDEO_JOD_DEFAULT_FPS
    metrics: dict = {"video_jod": None, "video_jod_uncorrected": None, "frames_per_s": fps}
    if seen is not None:
        from ..vision.vdp import video_jod  # on use: torch and ColorVideoVDP

        metrics["video_jod"] = video_jod(seen["target"], seen["corrected"], display, fps)
        metrics["video_jod_uncorrected"] = video_jod(seen["target"], seen["uncorrected"], display, fps)
    else:
        metrics["why_not_scored"] = (f"the clip has more than {VIDEO_JOD_MAX_PIXELS} frame pixels; score parts of it "
                                     "with vrcorrect.vision.vdp.video_jod")
    return {
        "input": str(args.input), "output": str(args.output), "prescription": str(rx_path), "eye": args.eye,
        "display": display.name, "method": result.method, "reference": "glasses" if reference is not None else "ideal",
        "contrast": args.contrast,
        "clip": {"kind": plan.clip.kind, "source_frames": plan.clip.count, "frames": plan.count,
                 "size": list(plan.clip.size), "frames_per_s": plan.frames_per_s, "plan": plan.text},
        "seconds": {"kernel": kernel_s, "solve": float(sum(f["seconds"] for f in per_frame))},
        "summary": {"objective_median": float(np.median(objectives)), "objective_mean": float(objectives.mean()),
                    "objective_max": float(objectives.max()),
                    "objective_uncorrected_median": float(np.median(uncorrected)),
                    "objective_fraction_median": float(np.nanmedian(fraction)) if np.isfinite(fraction).any()
                    else None,
                    "iterations_median": float(np.median([f["iterations"] for f in per_frame]))},
        "metrics": metrics,
        "frames": per_frame,
        "settings": result.settings, "kernel_decisions": kernel_decisions(kernel),
        "guard": None if rho is None else {"rho": rho, "measure": args.guard_measure,
                                           "sphere_offsets_D": _guard_offsets(),
                                           "pupils_mm": _guard_pupils(args.guard_measure)},
    }


def _learned_model(args: argparse.Namespace):
    """The learned model of ``--model`` (default: the shipped one), its reference checked."""
    from ..runtime.learned import LearnedModel  # on use: start-up time (apps/__init__)
    from ..runtime.unrolled import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
        UnrolledModel,
        is_unrolled_model,
    )

    path = Path(args.model) if args.model else DEFAULT_MODEL
    if args.model is None and not path.is_file():
        raise InputError(f"no default learned model is installed ({path}); pass --model PATH "
                         "(a model exported by tools/export_onnx.py), or use --method wiener or fast")
    model = UnrolledModel(path) if is_unrolled_model(path) else LearnedModel(path)
    if model.reference != args.reference:
        raise ValidationError("--reference", args.reference, f"{model.reference} (the target {path.name} was "
                              "trained for)")
    return model


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("correct", help="pre-correct an image for an eye (the displayed image); a clip frame by frame",
                       description="Pre-correct an image for an eye: the displayed image whose retinal image best "
                                   "matches the target. " + clips.CLIP_HELP + " Each frame of a clip is solved on its "
                                   "own with --method (the offline ceiling of the real-time path), each source frame "
                                   "once unless --fps asks for another rate; --report then holds each frame's "
                                   "objective, a summary, and ColorVideoVDP in video mode of what the eye sees.")
    clips.add_input_output(p, "image file (sRGB code values)")
    add_model_options(p)
    add_pupil_options(p, band=True)
    p.add_argument("--method", choices=names((Method.CONVENTIONAL, Method.PAPER, Method.FAST, Method.WIENER,
                                               Method.LEARNED)), default=Method.FAST.value,
                   help="correction method (default fast)")
    p.add_argument("--model", metavar="MODEL.onnx",
                   help="learned: the exported model (default: models/default.onnx when shipped)")
    p.add_argument("--iterations", type=int, help="iterations (paper) or iteration limit (fast, conventional)")
    p.add_argument("--tolerance", type=float, help="fast, conventional: relative stopping tolerance")
    p.add_argument("--contrast", type=float, default=1.0, help="scale the target's contrast (0, 1] (default 1)")
    p.add_argument("--reference", choices=("glasses", "ideal"), default="glasses",
                   help="target: what the eye sees with glasses (default) or the paper's blur-free A t")
    p.add_argument("--report", metavar="REPORT.json", help="write metrics, timings and settings")
    p.add_argument("--panel", metavar="PANEL.png", help="write a picture of what the eye sees with its glasses, with "
                   "no correction and with this one, side by side, each with its JOD, FLIP and objective and its "
                   "FLIP error map (a still only)")
    p.add_argument("--guard", default="off", metavar="RHO|off",
                   help="blend the correction towards the picture until the eye with the sphere 0.5 D off either "
                        "way sees at most RHO (1 to 10) times the error it sees with no correction, by the "
                        "objective (or --guard-measure); 1.1 with --guard-measure visibility spares most eyes of "
                        "sphere alone that are nearer focus than prescribed (default off: the correction as "
                        "designed)")
    p.add_argument("--guard-measure", choices=tuple(GUARD_WORDS), default="objective",
                   help="with --guard: the error kept within RHO of none's: objective (the default), or lightness, "
                        "the cube roots of each cone's light relative to white's, which sees errors on a dark "
                        "ground; or visibility, each band's contrast against the picture's local light weighted "
                        "by the eye's contrast sensitivity there; lightness and visibility also guard the eye as "
                        "prescribed through pupils of 2.5, 3, 4 and 5.5 mm (with --guard 1 they lift most falls "
                        "below none, at a cost to the gain: docs/realtime.md, 'Eyes of sphere alone')")
    p.add_argument("--16bit", dest="sixteen_bit", action="store_true", help="write a 16-bit PNG")
    clips.add_clip_options(p, fps_help="a clip: resample it in time to F frames per second (source frames "
                                       "repeated or dropped by presentation time; default: each source frame once)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs (a clip's: replace its folder of "
                                                        "frames)")
    p.set_defaults(func=cmd_correct)
