"""The paper's evaluation: every correction method on every refractive problem.

``vrcorrect evaluate`` (the command: :mod:`vrcorrect.apps.evaluate`) reproduces the comparison of ChromaCorrect (Güzel et
al. 2023, Sec. 4 and Fig. 6): five refractive problems at ±1.5 D, several
images, the conventional method (Montalto et al. 2015), the paper's
optimisation and the product's ``fast`` solver, scored by ColorVideoVDP (JOD,
the primary score), FLIP, SSIM and PSNR of what the eye sees, and by the
eye-chart acuity of each problem's eye (``vrcorrect acuity``).

Layer 6, a study.  Imports numpy, Pillow, matplotlib (its
colour map only), scikit-image and tqdm, each inside the function that needs
it; torch only indirectly, through :func:`vrcorrect.solvers.solve`.

The refractive problems
-----------------------
Minus-cylinder form; pupil 4 mm; the display at optical infinity (no
vergence, the paper's setting); accommodation 0; the eye's longitudinal
chromatic aberration on; the prescription holds at 555 nm.  Principal
meridian powers are ``M ± sqrt(J0² + J45²)`` of the power vector (Thibos
1997): the correcting lens's power in its two principal meridians (negative:
that meridian of the eye is myopic, positive: hyperopic).

=====================  ===========================  ======  ========  ====  ========================
key                    problem                      sphere  cylinder  axis  principal meridians
=====================  ===========================  ======  ========  ====  ========================
``myopia``             myopia                       -1.50   0.00      0     -1.50 and -1.50 D
``hyperopia``          hyperopia                    +1.50   0.00      0     +1.50 and +1.50 D
``myopic_astig``       myopic astigmatism           0.00    -1.50     90    0.00 (90°), -1.50 (180°)
``hyperopic_astig``    hyperopic astigmatism        +1.50   -1.50     90    +1.50 (90°), 0.00 (180°)
``mixed_astig``        myopia with hyperopic        +0.75   -1.50     90    +0.75 (90°), -0.75 (180°)
                       astigmatism (mixed)
=====================  ===========================  ======  ========  ====  ========================

The target is the paper's ideal ``A t`` (the target's cone image with no
blur at all: ``make_problem(target, kernel, reference_kernel=None)``).

Outputs (in ``out_dir``; nothing is overwritten without ``force``, which is
checked before any work; all files are written together at the end, so an interrupted or
failed run leaves none of them):

* ``results.csv``: one row per image x prescription x method (``none`` is
  the uncorrected image), columns :data:`CSV_COLUMNS`;
* ``results.md``: the machine, the per-row table, the mean per prescription
  x method and, per prescription, whether ``paper`` and ``fast`` beat
  ``conventional`` on mean FLIP (lower is better), SSIM and PSNR (higher)
  when ``conventional`` was run (not by default: it is by far the slowest);
* ``panels/<image>_<rx>.png``: columns target | uncorrected | each method,
  each as the eye sees it (the target column: the target as a sharp eye sees
  it), the FLIP error map (magma, 0..1) under each, captions with the
  method and its FLIP/SSIM/PSNR.
"""

from __future__ import annotations

import csv
import io
import math
import time
from pathlib import Path
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np
from tqdm import tqdm

from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import check_writable, text_writer, write_together
from ..plumbing.images import check_size, prepare_image, safe_name
from ..specs.display import DisplayProfile, decode, get_display
from ..specs.prescription import EyeRx
from ..specs.vocabulary import Method, names
from .acuity_chart import measure_acuity
from .bench import machine_description, markdown_table
from .eval_panels import compose_panel, legend, magma, panel_size, score_lines

__all__ = [
    "EvalPrescription",
    "PRESCRIPTIONS",
    "PUPIL_DIAMETER_MM",
    "DEFAULT_METHODS",
    "CSV_COLUMNS",
    "principal_meridians_D",
    "prescription_eye",
    "panel_size",
    "check_methods",
    "output_paths",
    "run_evaluation",
]


class EvalPrescription(NamedTuple):
    """One refractive problem of the evaluation (minus-cylinder form)."""

    key: str
    title: str
    sphere_D: float
    cylinder_D: float
    axis_deg: float


#: The paper's five refractive problems at ±1.5 D (see the module docstring's table).
PRESCRIPTIONS: tuple[EvalPrescription, ...] = (
    EvalPrescription("myopia", "myopia", -1.5, 0.0, 0.0),
    EvalPrescription("hyperopia", "hyperopia", 1.5, 0.0, 0.0),
    EvalPrescription("myopic_astig", "myopic astigmatism", 0.0, -1.5, 90.0),
    EvalPrescription("hyperopic_astig", "hyperopic astigmatism", 1.5, -1.5, 90.0),
    EvalPrescription("mixed_astig", "myopia with hyperopic astigmatism (mixed)", 0.75, -1.5, 90.0),
)

#: Pupil diameter of every evaluated eye (mm).
PUPIL_DIAMETER_MM = 4.0
#: Methods run by default (``none``, the uncorrected image, is always scored as well).  ``conventional``
#: runs only when asked for: its L-BFGS is by far the slowest (41 of a 47-minute run at 512x512 on 2 cores).
DEFAULT_METHODS: tuple[str, ...] = names((Method.PAPER, Method.FAST))
#: Columns of ``results.csv``.
CSV_COLUMNS: tuple[str, ...] = ("image", "prescription", "method", "jod", "flip", "ssim", "psnr", "objective",
                                "flip_lms", "ssim_lms", "psnr_lms", "seconds", "iterations")

_LABELS = {"target": "target", "none": "uncorrected"}


# --------------------------------------------------------------------------
# Prescriptions
# --------------------------------------------------------------------------


def prescription_eye(rx: EvalPrescription):
    """The :class:`vrcorrect.specs.prescription.EyeRx` of ``rx``: 4 mm pupil, no accommodation."""
    return EyeRx(sphere_D=rx.sphere_D, cylinder_D=rx.cylinder_D, axis_deg=rx.axis_deg,
                 pupil_diameter_mm=PUPIL_DIAMETER_MM, accommodation_D=0.0)


def principal_meridians_D(rx: EvalPrescription) -> tuple[float, float]:
    """Powers of the two principal meridians, ``M ± sqrt(J0² + J45²)`` (D), larger first."""
    pv = prescription_eye(rx).power_vector()
    j = math.hypot(pv.J0_D, pv.J45_D)
    return pv.M_D + j, pv.M_D - j


def _rx_label(rx: EvalPrescription) -> str:
    return f"{rx.sphere_D:+.2f} / {rx.cylinder_D:+.2f} x {rx.axis_deg:g}"


# --------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------


def _fmt(value: float, spec: str) -> str:
    return "inf" if math.isinf(value) else format(value, spec)


def _summarise(rows: Sequence[Mapping[str, Any]], methods: Sequence[str]) -> list[dict[str, Any]]:
    """Mean FLIP/SSIM/PSNR/objective/seconds per prescription x method (in run order)."""
    out = []
    for rx in PRESCRIPTIONS:
        for method in methods:
            sel = [r for r in rows if r["prescription"] == rx.key and r["method"] == method]
            if not sel:
                continue
            mean = {k: float(np.mean([r[k] for r in sel]))
                    for k in ("jod", "flip", "ssim", "psnr", "objective", "seconds")}
            out.append({"prescription": rx.key, "method": method, "images": len(sel), **mean})
    return out


def _beats_uncorrected(rows: Sequence[Mapping[str, Any]], methods: Sequence[str],
                       acuity: Mapping[str, Mapping[str, Any]] | None = None) -> list[str]:
    """Per prescription and method: on how many images it beats no correction by JOD (and FLIP), and acuity.

    A method beats no correction on an image when what the eye sees of it
    scores a higher JOD than what the eye sees of the uncorrected image (for
    FLIP: a lower error).  ``acuity`` maps a prescription key to
    :func:`vrcorrect.studies.acuity_chart.measure_acuity`'s logMAR per method.
    """
    lines = []
    for rx in PRESCRIPTIONS:
        base = {r["image"]: r for r in rows if r["prescription"] == rx.key and r["method"] == Method.NONE}
        if not base:
            continue
        parts = []
        for m in methods:
            if m == Method.NONE:
                continue
            sel = [r for r in rows if r["prescription"] == rx.key and r["method"] == m and r["image"] in base]
            if not sel:
                continue
            gains = [r["jod"] - base[r["image"]]["jod"] for r in sel]
            jod_wins = sum(g > 0 for g in gains)
            flip_wins = sum(r["flip"] < base[r["image"]]["flip"] for r in sel)
            text = (f"{m} beats it by JOD on {jod_wins}/{len(sel)} images (mean {np.mean(gains):+.2f} JOD, "
                    f"range {min(gains):+.2f} to {max(gains):+.2f}; by FLIP on {flip_wins}/{len(sel)})")
            if acuity and rx.key in acuity:
                a = acuity[rx.key]
                text += (f", eye-chart acuity logMAR {_logmar_text(a.get('none'))} -> {_logmar_text(a.get(m))}")
                if "none:sharp" in a:
                    text += (f" (sharp-template observer {_logmar_text(a.get('none:sharp'))} -> "
                             f"{_logmar_text(a.get(f'{m}:sharp'))})")
            parts.append(text)
        if parts:
            lines.append(f"- **{rx.key}**: " + "; ".join(parts) + ".")
    return lines


def disagreements(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Cases where JOD and FLIP disagree on whether a method beats no correction.

    One dict per image x prescription x method where one score says the
    corrected view is better than the uncorrected one and the other says it
    is worse: ``image``, ``prescription``, ``method``, ``jod_gain`` (JOD of the
    method less the uncorrected one's) and ``flip_gain`` (the uncorrected FLIP
    less the method's: positive means FLIP prefers the correction); the
    largest disagreements first.
    """
    base = {(r["image"], r["prescription"]): r for r in rows if r["method"] == Method.NONE}
    out = []
    for r in rows:
        b = base.get((r["image"], r["prescription"]))
        if r["method"] == Method.NONE or b is None:
            continue
        jod_gain, flip_gain = r["jod"] - b["jod"], b["flip"] - r["flip"]
        if jod_gain * flip_gain < 0:
            out.append({"image": r["image"], "prescription": r["prescription"], "method": r["method"],
                        "jod_gain": jod_gain, "flip_gain": flip_gain})
    return sorted(out, key=lambda d: -abs(d["jod_gain"]))


def _disagreement_lines(rows: Sequence[Mapping[str, Any]], methods: Sequence[str]) -> list[str]:
    found = disagreements(rows)
    if not found:
        return []
    lines = []
    for m in methods:
        mine = [d for d in found if d["method"] == m]
        if not mine:
            continue
        jod_says = sum(d["jod_gain"] > 0 for d in mine)
        cases = ", ".join(f"{d['image']}/{d['prescription']} ({d['jod_gain']:+.2f} JOD, FLIP "
                          f"{-d['flip_gain']:+.3f})" for d in mine[:4])
        lines.append(f"- {m}: {len(mine)} cases; JOD says better than uncorrected in {jod_says} of them, FLIP in "
                     f"{len(mine) - jod_says}; largest: {cases}{' ...' if len(mine) > 4 else ''}")
    return lines


def _verdicts(summary: Sequence[Mapping[str, Any]]) -> list[str]:
    """Per prescription: do ``paper`` and ``fast`` beat ``conventional`` on mean FLIP, SSIM, PSNR?"""
    lines = []
    for rx in PRESCRIPTIONS:
        by = {s["method"]: s for s in summary if s["prescription"] == rx.key}
        base = by.get("conventional")
        rivals = [m for m in ("paper", "fast") if m in by]
        if base is None or not rivals:
            continue
        parts = []
        for m in rivals:
            s = by[m]
            wins = {"FLIP": s["flip"] < base["flip"], "SSIM": s["ssim"] > base["ssim"],
                    "PSNR": s["psnr"] > base["psnr"]}
            n = sum(wins.values())
            if n == 3:
                verdict = "beats conventional on FLIP, SSIM and PSNR"
            elif n == 0:
                verdict = "does not beat conventional on FLIP, SSIM or PSNR"
            else:
                won = [k for k, v in wins.items() if v]
                lost = [k for k, v in wins.items() if not v]
                verdict = f"beats conventional on {', '.join(won)}, not on {', '.join(lost)}"
            parts.append(f"{m} {verdict} (FLIP {s['flip']:.4f} vs {base['flip']:.4f}, SSIM {s['ssim']:.4f} vs "
                         f"{base['ssim']:.4f}, PSNR {_fmt(s['psnr'], '.2f')} vs {_fmt(base['psnr'], '.2f')} dB)")
        lines.append(f"- **{rx.key}**: " + "; ".join(parts) + ".")
    return lines


def summary_table(summary: Sequence[Mapping[str, Any]]) -> str:
    """The Markdown table of :func:`run_evaluation`'s ``summary``."""
    has_acuity = any("acuity_logmar" in s for s in summary)
    head = ["prescription", "method", "JOD ↑"] + (["acuity logMAR ↓", "acuity, sharp templates ↓"]
                                                  if has_acuity else [])
    return markdown_table(
        head + ["FLIP ↓", "SSIM ↑", "PSNR dB ↑", "objective ↓", "seconds"],
        [[s["prescription"], s["method"], f"{s['jod']:.3f}"]
         + ([_logmar_text(s.get("acuity_logmar")), _logmar_text(s.get("acuity_logmar_sharp"))]
            if has_acuity else [])
         + [f"{s['flip']:.4f}", f"{s['ssim']:.4f}", _fmt(s["psnr"], ".2f"),
            f"{s['objective']:.3e}", f"{s['seconds']:.2f}"] for s in summary])


def _logmar_text(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def _rows_table(rows: Sequence[Mapping[str, Any]]) -> str:
    return markdown_table(
        ["image", "prescription", "method", "JOD", "FLIP", "SSIM", "PSNR dB", "objective", "FLIP (LMS)",
         "SSIM (LMS)", "PSNR (LMS) dB", "seconds", "iterations"],
        [[r["image"], r["prescription"], r["method"], f"{r['jod']:.3f}", f"{r['flip']:.4f}", f"{r['ssim']:.4f}",
          _fmt(r["psnr"], ".2f"), f"{r['objective']:.3e}", f"{r['flip_lms']:.4f}", f"{r['ssim_lms']:.4f}",
          _fmt(r["psnr_lms"], ".2f"), f"{r['seconds']:.2f}", r["iterations"]] for r in rows])


def _csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS), lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (repr(float(r[k])) if isinstance(r[k], float) else r[k]) for k in CSV_COLUMNS})
    return buf.getvalue()


def _markdown(rows, summary, verdicts, display, size, images, methods, seconds_total,
              wins: Sequence[str] = ()) -> str:
    rx_table = markdown_table(
        ["key", "problem", "sphere D", "cylinder D", "axis deg", "principal meridians D"],
        [[rx.key, rx.title, f"{rx.sphere_D:+.2f}", f"{rx.cylinder_D:+.2f}", f"{rx.axis_deg:g}",
          " / ".join(f"{p:+.2f}" for p in principal_meridians_D(rx))] for rx in PRESCRIPTIONS])
    parts = [
        "# vrcorrect evaluation",
        "",
        f"Machine: {machine_description()}.",
        "",
        f"Display `{display.name}` ({display.title}, {display.pixels_per_degree:.1f} pixels per degree); "
        f"{len(images)} images of {size}x{size} px ({', '.join(n for n, _ in images)}); methods: "
        f"{', '.join(methods)} (`none` is the uncorrected image). Eyes: {PUPIL_DIAMETER_MM:g} mm pupil, "
        "display at optical infinity, no accommodation, chromatic aberration on. Target: the paper's ideal "
        "`A t` (the target's cone image without blur). Scores compare what the eye sees with the target, "
        "both rendered to display sRGB. **JOD** (ColorVideoVDP, calibrated on human judgements; 10 = "
        "identical, higher is better, one JOD ~ 75 % of observers prefer the better image) is the primary "
        f"score, on this display's viewing conditions ({display.photometry.describe()}); FLIP (at the "
        "display's pixels per degree), SSIM and PSNR are secondary; the `(LMS)` columns score the cone "
        "images directly, as the paper reported. **Acuity** (when run): the smallest line of a logMAR chart "
        "of Sloan letters the problem's eye reads on this display (simulated observer after Watson & "
        "Ahumada 2008, `vrcorrect acuity`), uncorrected and with each method, whose target there is what "
        "the eye sees with its glasses on; by the ideal observer, whose templates pass through the same eye "
        "and correction, and by the sharp-template observer, who knows the letters as they look with "
        "glasses; `-` means no line was read. "
        f"Total time {seconds_total:.1f} s.",
        "",
        "## Refractive problems (minus-cylinder form)",
        "",
        rx_table,
        "",
        "## Mean per prescription and method",
        "",
        summary_table(summary),
        "",
    ]
    if wins:
        parts += ["Against no correction (what the eye sees of the uncorrected image), per image:", "", *wins, ""]
    split = _disagreement_lines(rows, methods)
    if split:
        parts += ["Where JOD and FLIP disagree on whether a method beats no correction (believe JOD: it is "
                  "calibrated on human judgements of such images; FLIP's panels below each case show why it "
                  "differs; FLIP changes in error units, lower is better):", "", *split, ""]
    if verdicts:
        parts += ["Against the conventional method (mean over the images; FLIP lower is better, SSIM and "
                  "PSNR higher):", "", *verdicts, ""]
    parts += ["## Every image", "", _rows_table(rows), ""]
    return "\n".join(parts)


# --------------------------------------------------------------------------
# The evaluation
# --------------------------------------------------------------------------


def check_methods(methods: Iterable[str]) -> tuple[str, ...]:
    from ..solvers import METHODS  # on use: start-up time (apps/__init__)

    allowed = names(m for m in METHODS if m != Method.NONE)
    if isinstance(methods, str):
        methods = (methods,)
    out: list[str] = []
    for m in methods:
        if m not in allowed:
            raise ValidationError("methods", m, "one of " + ", ".join(allowed))
        if m not in out:
            out.append(m)
    if not out:
        raise ValidationError("methods", list(methods), "at least one of " + ", ".join(allowed))
    return tuple(out)


def _check_images(images: Sequence[tuple[str, np.ndarray]], size: int | None) -> list[tuple[str, np.ndarray]]:
    if not images:
        raise ValidationError("images", "none", "at least one (name, image) pair")
    out, seen = [], set()
    for item in images:
        try:
            name, image = item
        except (TypeError, ValueError):
            raise ValidationError("images", type(item).__name__, "(name, image) pairs") from None
        if not isinstance(name, str) or safe_name(name) != name:
            raise ValidationError("image name", name, "letters, digits, '-', '_' or '.' (a file-name-safe name)")
        if name in seen:
            raise ValidationError("image name", name, "names that differ from one another")
        seen.add(name)
        if size is not None:
            img = prepare_image(image, size, name)
        else:
            img = np.asarray(image)
            if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1:
                raise ValidationError(f"{name}.shape", img.shape, "(height, width, 3)")
            img = np.clip(img.astype(np.float32), 0.0, 1.0)
            if not np.all(np.isfinite(img)):
                raise ValidationError(name, "NaN/inf values", "finite sRGB code values in [0, 1]")
        out.append((name, img))
    return out


def output_paths(out_dir: str | Path, image_names: Sequence[str]) -> dict[str, Any]:
    """Where :func:`run_evaluation` writes: ``csv``, ``markdown`` and ``panels`` (a list)."""
    out = Path(out_dir)
    return {"csv": out / "results.csv", "markdown": out / "results.md",
            "panels": [out / "panels" / f"{name}_{rx.key}.png" for name in image_names for rx in PRESCRIPTIONS]}


def run_evaluation(out_dir: str | Path, images: Sequence[tuple[str, np.ndarray]], display,
                   methods: Sequence[str] = DEFAULT_METHODS, size: int | None = 256, progress: bool = True,
                   force: bool = False, solver_options: Mapping[str, Mapping[str, Any]] | None = None,
                   acuity: bool = True) -> dict[str, Any]:
    """Run every method on every image for every prescription and write the results.

    Parameters
    ----------
    out_dir
        Output folder (created if missing).
    images
        ``(name, image)`` pairs: file-name-safe unique names and sRGB code
        values in [0, 1] ``(H, W, 3)`` (e.g. :func:`vrcorrect.plumbing.images.bundled_images`).
    display
        A :class:`vrcorrect.specs.display.DisplayProfile` or a preset name / profile path.
    methods
        Correction methods to run, in panel order (any of
        :data:`vrcorrect.solvers.METHODS` except ``none``, which is always
        scored as "uncorrected").
    size
        Centre-crop and resize every image to ``size x size`` first (no-op
        when it already is); ``None`` uses the images as given.
    progress
        Show a tqdm bar over the image x prescription cases (only on a terminal).
    force
        Overwrite earlier outputs; otherwise any existing output file makes
        this refuse before any work.
    solver_options
        Optional per-method keyword options for :func:`vrcorrect.solvers.solve`,
        e.g. ``{"conventional": {"max_iterations": 40}}``.
    acuity
        Also read an eye chart with each problem's eye, uncorrected and with
        each method (:func:`vrcorrect.studies.acuity_chart.measure_acuity`; its target
        is what the eye sees with glasses, the product's default), and
        report the logMAR per prescription x method.

    Returns
    -------
    dict
        ``rows`` (one dict per image x prescription x method with the
        :data:`CSV_COLUMNS`), ``summary`` (means per prescription x method),
        ``summary_markdown`` (that as a table), ``verdicts`` (the lines
        comparing with ``conventional``), ``files`` (see :func:`output_paths`)
        and ``seconds`` (total wall time).

    Raises
    ------
    ValidationError
        A bad method, size, image or display.
    InputError
        An output exists (without ``force``) or cannot be written.
    """
    from ..physics.kernel import KernelOptions, build_kernel  # on use: start-up time (apps/__init__)
    from ..physics.options import (
        OpticsOptions,  # on use: start-up time (the CLI imports the studies to build its parser)
    )
    from ..solvers import make_problem, solve  # on use: start-up time (the CLI imports the studies to build its parser)
    from ..vision.metrics import (
        evaluate_seen,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    t_start = time.perf_counter()
    methods = check_methods(methods)
    options = {m: dict(o) for m, o in (solver_options or {}).items()}
    for m in options:
        if m not in methods:
            raise ValidationError("solver_options", m, "options only for methods being run: " + ", ".join(methods))
    if size is not None:
        size = check_size(size)
    if not isinstance(display, DisplayProfile):
        display = get_display(display)
    images = _check_images(images, size)

    # Every output is checked before any work.
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    files = output_paths(out, [n for n, _ in images])
    panel_dir = out / "panels"
    if panel_dir.exists() and not panel_dir.is_dir():
        raise InputError(f"{panel_dir}: exists and is not a folder")
    targets = [files["csv"], files["markdown"], *files["panels"]]
    if not force:
        existing = [p for p in targets if p.exists()]
        if existing:
            more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
            raise InputError(f"{existing[0]}: file exists{more}; pass --force to overwrite earlier results")
    panel_dir.mkdir(parents=True, exist_ok=True)
    for p in targets:
        check_writable(p, force=force)
    outputs: list[tuple[Path, Any]] = []             # (path, writer of a temporary path), written together

    kernel_options = KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf))
    scored = ("none", *methods)
    rows: list[dict[str, Any]] = []
    cases = [(rx, name, img) for rx in PRESCRIPTIONS for name, img in images]
    bar = tqdm(total=len(cases), desc="evaluate", unit="case", disable=None if progress else True, leave=False)
    kernel = None
    kernel_rx = None
    try:
        for rx, name, img in cases:
            bar.set_postfix_str(f"{rx.key} / {name}", refresh=False)
            if kernel_rx is not rx:                       # one kernel per prescription
                kernel = build_kernel(prescription_eye(rx), display, kernel_options)
                kernel_rx = rx
            target = decode(display, img)
            problem = make_problem(target, kernel, reference_kernel=None)
            columns = []
            for method in scored:
                result = solve(problem, method, **options.get(method, {}))
                metrics, seen = evaluate_seen(result.image, target, kernel, display, target_lms=problem.target_lms)
                rows.append({"image": name, "prescription": rx.key, "method": method, "jod": metrics.jod,
                             "flip": metrics.flip, "ssim": metrics.ssim, "psnr": metrics.psnr,
                             "objective": metrics.objective, "flip_lms": metrics.flip_lms,
                             "ssim_lms": metrics.ssim_lms, "psnr_lms": metrics.psnr_lms,
                             "seconds": float(result.seconds), "iterations": int(result.iterations)})
                if not columns:
                    columns.append(([_LABELS["target"], "ideal A t (no blur)"],
                                    seen["target_srgb"], legend(*img.shape[:2])))
                columns.append((score_lines(_LABELS.get(method, method), metrics), seen["seen_srgb"],
                                magma(seen["flip_map"])))
            title = (f"{name}: {rx.title} {_rx_label(rx)} (pupil {PUPIL_DIAMETER_MM:g} mm, at infinity), "
                     f"as the eye sees it on {display.name}")
            panel = compose_panel(title, columns)
            path = panel_dir / f"{name}_{rx.key}.png"
            outputs.append((path, lambda tmp, im=panel: im.save(tmp, format="PNG")))   # written at the end
            bar.update(1)
    finally:
        bar.close()

    acuity_logmar: dict[str, dict[str, float | None]] = {}
    if acuity:
        bar = tqdm(total=len(PRESCRIPTIONS), desc="acuity", unit="eye", disable=None if progress else True,
                   leave=False)
        try:
            for rx in PRESCRIPTIONS:
                read = measure_acuity(prescription_eye(rx), display, methods, kernel_options)
                acuity_logmar[rx.key] = {m: read.logmar(m) for m in scored}
                acuity_logmar[rx.key].update({f"{m}:sharp": read.logmar(m, "sharp") for m in scored})
                bar.update(1)
        finally:
            bar.close()
    summary = _summarise(rows, scored)
    for s in summary:
        if s["prescription"] in acuity_logmar:
            s["acuity_logmar"] = acuity_logmar[s["prescription"]].get(s["method"])
            s["acuity_logmar_sharp"] = acuity_logmar[s["prescription"]].get(f"{s['method']}:sharp")
    verdicts = _verdicts(summary)
    wins = _beats_uncorrected(rows, scored, acuity_logmar)
    seconds_total = time.perf_counter() - t_start
    csv_text = _csv_text(rows)
    markdown = _markdown(rows, summary, verdicts, display, size if size is not None else "as given", images, scored,
                         seconds_total, wins)
    outputs.append((files["csv"], text_writer(csv_text)))
    outputs.append((files["markdown"], text_writer(markdown)))
    # every panel and both tables appear together, or (interrupted, failed) none of them
    write_together(outputs, force=force)
    return {"rows": rows, "summary": summary, "summary_markdown": summary_table(summary), "verdicts": verdicts,
            "wins": wins, "acuity": acuity_logmar, "files": files, "seconds": seconds_total}
