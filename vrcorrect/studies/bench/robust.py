"""``vrcorrect bench robust``: the eye as it is against the eye as modelled.

A correction is designed for an eye as modelled (its pupil, its sphere), and seen by the eye as it
is.  For each display and held-out image (never used to choose the robust band: a photograph and a
page of text, :data:`IMAGES`), the correction is designed as each method designs it and seen through
a sweep of eyes: pupils :data:`SEEN_PUPILS_MM` (2 to 7 mm) at the prescription's sphere, and spheres
:data:`SEEN_SPHERES_D` (+-0.25 and +-0.5 D) off the prescription at the pupil the light gives.  What
each method shows is scored as what that eye sees of it, against the target image itself (the
same reference for every eye): ColorVideoVDP (JOD, on the display's photometry), FLIP and the LMS
objective (against the seen eye's glasses-on view).

Methods (``fast`` unless said):

* ``none``: the target, uncorrected (the floor);
* ``4 mm``: designed for a 4 mm pupil, the prescription's sphere, one eye (every design before the
  pupil came from the light);
* ``default``: ``--pupil auto --robust on``: the pupil from the image's light, the robust band;
* ``real time``: the same design through the real-time default's CPU twin (equal to the GPU,
  ``tests/test_pupil.py``), ten frames of the still (``vrcorrect render``'s default);
* ``ceiling``: designed for exactly the eye seen (its pupil and sphere), one eye.

The issue's checks are summarised: the default and the real time never below ``none`` (JOD, within
0.05) on the sweep's pupils 2.5, 3, 4, 5.5 mm and spheres +-0.5 D; at 3 mm the default's share of
the gain of a correction designed for exactly 3 mm.  A second table measures what the image's
boundary does to the effective kernel (:mod:`vrcorrect.physics.robust`): the expectation the
robust design minimises, for the effective kernel's solution and for the exact expectation's
(:func:`~vrcorrect.solvers.expectation.fast_expectation`, one split per member, to 1e-3).  A plot
draws the pupil sweep.  Layer 6.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from ...physics.perception import luminance_weights
from ...physics.pupil import pupil_from_light
from ...physics.robust import design_eye
from ...solvers import make_problem, objective, solve
from ...solvers.expectation import fast_expectation
from ...solvers.problem import make_design_problem
from ...solvers.realtime import AdmmFrames
from ...specs.display import decode, get_display
from ...specs.prescription import EyeRx
from ...vision.metrics import evaluate_seen
from . import machine_description, markdown_table, publish

__all__ = ["EYE", "IMAGES", "DISPLAYS", "SEEN_PUPILS_MM", "SEEN_SPHERES_D", "run_robust_bench"]

EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
"""The issue's eye (right, -2.00/-1.00 x 120)."""
IMAGES = ("motorcycle", "page")
"""Held out from choosing the band (it was chosen on scikit-image's astronaut and the project's text
chart): scikit-image's stereo_motorcycle (its left view, a colour photograph) and page (a scanned
page of text)."""
DISPLAYS = ("desktop", "quest2")
SEEN_PUPILS_MM = (2.0, 2.5, 3.0, 4.0, 5.5, 7.0)
SEEN_SPHERES_D = (-0.5, -0.25, 0.25, 0.5)
CHECKED_PUPILS_MM = (2.5, 3.0, 4.0, 5.5)
CHECKED_SPHERES_D = (-0.5, 0.5)
SIZE = 256
REALTIME_FRAMES = 10
OLD_PUPIL_MM = 4.0
METHODS = ("none", "4 mm", "default", "real time", "ceiling")


def held_out_image(name: str, size: int = SIZE) -> np.ndarray:
    """A held-out image, sRGB code values ``(size, size, 3)`` float32."""
    from skimage import data  # optional: scikit-image (the metrics and test extras)

    from ...plumbing.images import prepare_image

    if name == "motorcycle":
        raw = data.stereo_motorcycle()[0][..., :3]
    elif name == "page":
        raw = data.page()
    else:
        raw = getattr(data, name)()
    return prepare_image(raw, size, name)


def _realtime(design, target: np.ndarray, frames: int = REALTIME_FRAMES) -> np.ndarray:
    """What the real-time default shows after ``frames`` frames of a still (its CPU twin)."""
    twin = AdmmFrames(design.kernel, design.reference, target.shape[:2])
    shown = None
    for _ in range(frames):
        shown = twin.frame(target, 2).shown
    return shown


def _case(display_name: str, image_name: str, bar, kernels: dict) -> dict[str, Any]:
    display = get_display(display_name)
    codes = held_out_image(image_name)
    target = decode(display, codes).astype(np.float32)
    estimate = pupil_from_light(float(np.mean(target.astype(np.float64) @ luminance_weights(display))), display)
    p = estimate.diameter_mm
    shown: dict[str, np.ndarray] = {"none": target}
    old = design_eye(EYE, display, OLD_PUPIL_MM, robust=False, kernels=kernels)
    shown["4 mm"] = solve(make_problem(target, old.kernel, old.reference), "fast").image
    default = design_eye(EYE, display, p, kernels=kernels)
    problem = make_design_problem(target, default)
    t0 = time.perf_counter()
    shown["default"] = solve(problem, "fast").image
    default_s = time.perf_counter() - t0
    shown["real time"] = _realtime(default, target)
    seen_eyes = [(q, 0.0) for q in SEEN_PUPILS_MM] + [(p, s) for s in SEEN_SPHERES_D]
    rows = []
    for q, s in seen_eyes:
        eye = EYE.with_changes(sphere_D=EYE.sphere_D + s)
        exact = design_eye(eye, display, q, robust=False, kernels=kernels)
        ceiling = solve(make_problem(target, exact.kernel, exact.reference), "fast").image
        scores = {}
        seen_target = make_problem(target, exact.nominal, exact.nominal_reference)
        for method, image in {**shown, "ceiling": ceiling}.items():
            m, _ = evaluate_seen(image, target, exact.nominal, display)
            scores[method] = {"jod": m.jod, "flip": m.flip, "objective": objective(image, seen_target)}
            bar.update(1)
        rows.append({"pupil_mm": q, "sphere_offset_D": s, "scores": scores})
    return {"display": display_name, "image": image_name, "pupil_mm": p, "pupil": estimate.describe(),
            "design": default.describe()[0], "default_seconds": default_s, "rows": rows,
            "_problem": problem, "_default": default, "_target": target}


def _gain(row: dict, method: str) -> float:
    return row["scores"][method]["jod"] - row["scores"]["none"]["jod"]


def _checks(case: dict) -> dict[str, Any]:
    """The issue's checks on one case: the least JOD gain of the default and the real time over the
    checked eyes, and at 3 mm the default's share of the gain designed for exactly 3 mm."""
    p = case["pupil_mm"]
    checked = [r for r in case["rows"] if (r["sphere_offset_D"] == 0.0 and r["pupil_mm"] in CHECKED_PUPILS_MM)
               or (r["pupil_mm"] == p and r["sphere_offset_D"] in CHECKED_SPHERES_D)]
    at3 = next(r for r in case["rows"] if r["pupil_mm"] == 3.0 and r["sphere_offset_D"] == 0.0)
    ceiling = _gain(at3, "ceiling")
    return {"least_default": min(_gain(r, "default") for r in checked),
            "least_realtime": min(_gain(r, "real time") for r in checked),
            "least_4mm": min(_gain(r, "4 mm") for r in checked),
            "share_at_3mm": _gain(at3, "default") / ceiling if ceiling > 0 else None,
            "share_at_3mm_realtime": _gain(at3, "real time") / ceiling if ceiling > 0 else None}


def _boundary(case: dict) -> dict[str, Any]:
    """The expectation for the effective kernel's solution and the exact expectation's."""
    problem, design = case["_problem"], case["_default"]
    effective = solve(problem, "fast", tolerance=1e-3).image
    t0 = time.perf_counter()
    exact, iterations, _, _ = fast_expectation(problem.target, problem.members, design.kernel, problem.target_lms,
                                               tolerance=1e-3, max_iterations=60)
    seconds = time.perf_counter() - t0
    none = objective(problem.target, problem)
    return {"display": case["display"], "image": case["image"], "none": none,
            "effective": objective(effective, problem), "exact": objective(exact, problem),
            "exact_iterations": iterations, "exact_seconds": seconds}


def _plot(cases: list[dict], path: Path) -> None:
    from ..plots import pyplot, save_figure

    plt = pyplot()
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 3.6), squeeze=False)
    styles = {"4 mm": ("tab:red", "--"), "default": ("tab:blue", "-"), "real time": ("tab:cyan", ":"),
              "ceiling": ("0.4", "-.")}
    for ax, case in zip(axes[0], cases):
        rows = [r for r in case["rows"] if r["sphere_offset_D"] == 0.0]
        x = [r["pupil_mm"] for r in rows]
        ax.axhline(0.0, color="k", lw=0.8)
        for method, (colour, ls) in styles.items():
            ax.plot(x, [_gain(r, method) for r in rows], color=colour, ls=ls, marker="o", ms=3, label=method)
        ax.axvline(case["pupil_mm"], color="tab:blue", lw=0.6, alpha=0.5)
        ax.set_title(f"{case['display']}, {case['image']} (light: {case['pupil_mm']:.2f} mm)", fontsize=9)
        ax.set_xlabel("pupil of the eye as it is (mm)")
        ax.set_ylabel("JOD gain over no correction")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def run_robust_bench(out: Path, write: bool = True, plot: Path | None = None, displays: Sequence[str] = DISPLAYS,
                     images: Sequence[str] = IMAGES, json_out: Path | None = None, force: bool = False,
                     boundary: bool = True) -> dict[str, Any]:
    """Run the sweep (module docstring); returns the report (``markdown`` and the figures)."""
    kernels: dict = {}
    per_case = (len(SEEN_PUPILS_MM) + len(SEEN_SPHERES_D)) * (len(METHODS) + 1)
    cases = []
    t0 = time.perf_counter()
    with tqdm(total=per_case * len(displays) * len(images), desc="bench robust", unit="score") as bar:
        for d in displays:
            for name in images:
                cases.append(_case(d, name, bar, kernels))
    bounds = [_boundary(c) for c in cases] if boundary else []
    seconds = time.perf_counter() - t0
    lines = ["## The eye as it is: a correction against the eye it meets (`vrcorrect bench robust`)", "",
             f"Machine: {machine_description()}. {len(cases)} cases in {seconds / 60:.0f} min. The eye: right "
             f"{EYE.sphere_D:+.2f}/{EYE.cylinder_D:+.2f} x {EYE.axis_deg:g}; images at {SIZE} px, held out from "
             "choosing the robust band (scikit-image's stereo_motorcycle, a colour photograph, and page, a scanned "
             "page of text). Each correction is seen by the eye as it is: pupils 2 to 7 mm at the prescription's "
             "sphere, and the sphere off by -0.5 to +0.5 D at the pupil the light gives. JOD (ColorVideoVDP) of "
             "what that eye sees against the target image; gains are over no correction. `4 mm`: designed for a "
             "4 mm pupil, as every correction was before; `default`: `--pupil auto --robust on` (`fast`); `real "
             "time`: the same design through the real-time default's CPU twin, 10 frames of the still; `ceiling`: "
             "designed for exactly the eye seen.", ""]
    summary = []
    for c in cases:
        k = _checks(c)
        share = "-" if k["share_at_3mm"] is None else f"{100 * k['share_at_3mm']:.0f} %"
        share_rt = "-" if k["share_at_3mm_realtime"] is None else f"{100 * k['share_at_3mm_realtime']:.0f} %"
        summary.append([c["display"], c["image"], f"{c['pupil_mm']:.2f}", f"{k['least_4mm']:+.2f}",
                        f"{k['least_default']:+.2f}", f"{k['least_realtime']:+.2f}", share, share_rt])
        c["checks"] = k
    lines += ["### The checks", "",
              "Least JOD gain over the eyes seen through pupils 2.5, 3, 4, 5.5 mm and with the sphere 0.5 D off "
              "either way (the default must stay at or above -0.05), and at 3 mm the default's share of the gain of "
              "a correction designed for exactly 3 mm (`--pupil 3 --robust off`; the issue asks 80 %).", "",
              markdown_table(["display", "image", "pupil from the light (mm)", "least gain, 4 mm design",
                              "least gain, default", "least gain, real time", "share at 3 mm, default",
                              "share at 3 mm, real time"], summary), ""]
    for c in cases:
        rows = []
        for r in c["rows"]:
            sc = r["scores"]
            rows.append([f"{r['pupil_mm']:.2f}", f"{r['sphere_offset_D']:+.2f}", f"{sc['none']['jod']:.2f}",
                         *(f"{_gain(r, m):+.2f}" for m in METHODS[1:]), f"{_gain(r, 'ceiling'):+.2f}",
                         f"{sc['none']['flip']:.3f} / {sc['default']['flip']:.3f} / {sc['ceiling']['flip']:.3f}",
                         f"{sc['default']['objective'] / sc['none']['objective']:.3f}"])
        lines += [f"### {c['display']}, {c['image']}: {c['pupil']}", "", c["design"] + ".", "",
                  markdown_table(["pupil seen (mm)", "sphere off (D)", "JOD none", "4 mm", "default", "real time",
                                  "ceiling", "FLIP none / default / ceiling", "objective default / none"], rows), ""]
    if bounds:
        rows = [[b["display"], b["image"], f"{b['none']:.4g}", f"{b['effective']:.4g}", f"{b['exact']:.4g}",
                 f"{100 * (b['effective'] - b['exact']) / max(b['none'] - b['exact'], 1e-30):.1f} %",
                 f"{b['exact_iterations']}", f"{b['exact_seconds']:.1f}"] for b in bounds]
        lines += ["### What the image's boundary does to the effective kernel", "",
                  "The robust design minimises the expectation of the objective over its band's eyes, each cropped to "
                  "the image; the effective kernel (one 3x3 solve a frequency, the cost of one kernel) crops its own "
                  "retina instead. The expectation of the effective kernel's solution (`fast`, to 1e-3) against the "
                  "exact expectation's (one split per member, to 1e-3): the gap as a share of the exact gain over no "
                  "correction.", "",
                  markdown_table(["display", "image", "none", "effective kernel", "exact expectation", "gap left",
                                  "exact: iterations", "exact: s"], rows), ""]
    if plot is not None:
        _plot(cases, plot)
        lines += [f"![JOD gain over no correction against the pupil of the eye as it is]({plot.name})", ""]
    report = {"markdown": "\n".join(lines), "seconds": seconds,
              "cases": [{k: v for k, v in c.items() if not k.startswith("_")} for c in cases], "boundary": bounds}
    return publish(report, "robust", out, write, json_out, force)
