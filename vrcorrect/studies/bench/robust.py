"""``vrcorrect bench robust``: the eye as it is against the eye as modelled.

A correction is designed for an eye as modelled (its pupil, its sphere), and seen by the eye as it
is.  For each display and held-out image (never used to choose the robust band: a photograph, a
scanned page of text and light text on dark blue, :data:`IMAGES`), the correction is designed as each method designs it and seen through
a sweep of eyes: pupils :data:`SEEN_PUPILS_MM` (2 to 7 mm) at the prescription's sphere, and spheres
:data:`SEEN_SPHERES_D` (+-0.25 and +-0.5 D) off the prescription at the pupil the light gives.  What
each method shows is scored as what that eye sees of it, against the target image itself (the
same reference for every eye): ColorVideoVDP (JOD, on the display's photometry), FLIP and the LMS
objective (against the seen eye's glasses-on view).

Methods (``fast`` unless said):

* ``none``: the target, uncorrected (the floor);
* ``4 mm``: designed for a 4 mm pupil, the prescription's sphere, one eye (every design before the
  pupil came from the light);
* ``default``: ``--pupil auto --robust on --band auto``: the pupil from the image's light (designed for
  the pupil bank's nearest entry, as every command does; the eye as it is sees through the light's own
  pupil) and the band by the picture (:func:`~vrcorrect.physics.page.choose_band`): a page on white
  paper the page band, anything else the robust band and its light cap
  (:func:`~vrcorrect.solvers.problem.light_cap`);
* ``real time``: the real-time default's CPU twin (equal to the GPU, ``tests/test_pupil.py``), ten
  frames of the still (``vrcorrect render``'s default): the band by the picture as the real-time path
  looks at it (at most :data:`~vrcorrect.physics.page.REALTIME_LOOK_SIDE` a side; the same band as the
  default's on every picture here), its light cap where the band has one;
* ``learned``: the shipped learned model (``models/default.onnx``) given the default's design;
* ``ceiling``: designed for exactly the eye seen (its pupil and sphere), one eye (the box [0, 1], as
  ``--robust off``).

The issue's checks are summarised: the default and the real time never below ``none`` (JOD, within
0.05) on the sweep's pupils 2.5, 3, 4, 5.5 mm and spheres +-0.5 D; at 3 mm the default's share of
the gain of a correction designed for exactly 3 mm.  A second table measures what the image's
boundary does to the effective kernel (:mod:`vrcorrect.physics.robust`): the expectation the
robust design minimises, for the effective kernel's solution and for the exact expectation's
(:func:`~vrcorrect.solvers.expectation.fast_expectation`, one split per member, to 1e-3).  A plot
draws the pupil sweep.  ``--image PATH`` runs the sweep on pictures of one's own instead of the
held-out images (the checked band by the picture: rendered pages, docs/realtime.md).  Layer 6.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from ...physics.page import PAGE_BAND, REALTIME_LOOK_SIDE, choose_band, page_verdict
from ...physics.perception import luminance_weights
from ...physics.pupil import pupil_from_light
from ...physics.robust import design_eye
from ...plumbing.errors import ValidationError
from ...solvers import make_problem, objective, solve
from ...solvers.problem import make_design_problem
from ...solvers.realtime import AdmmFrames
from ...specs.display import decode, get_display
from ...specs.prescription import EyeRx
from ...vision.metrics import evaluate_seen
from . import machine_description, markdown_table, publish
from .robust_boundary import boundary_case, gap_left

__all__ = ["EYE", "IMAGES", "DISPLAYS", "SEEN_PUPILS_MM", "SEEN_SPHERES_D", "run_robust_bench"]

EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
"""The issue's eye (right, -2.00/-1.00 x 120)."""
IMAGES = ("motorcycle", "page", "darktext")
"""Held out from choosing the band (it was chosen on scikit-image's astronaut, coffee and text and the
project's text chart, ``tools/robust_band_choice.py``): scikit-image's stereo_motorcycle (its left view, a colour photograph), page (a scanned
page of text) and darktext (light words on dark blue, 18 px: the held-out text clip's page, :func:`~.sequences.dark_text_page`;
added after the band was chosen, 2026-11-29, when the clip showed the correction below none there)."""
DISPLAYS = ("desktop", "quest2")
SEEN_PUPILS_MM = (2.0, 2.5, 3.0, 4.0, 5.5, 7.0)
SEEN_SPHERES_D = (-0.5, -0.25, 0.25, 0.5)
CHECKED_PUPILS_MM = (2.5, 3.0, 4.0, 5.5)
CHECKED_SPHERES_D = (-0.5, 0.5)
SIZE = 256
REALTIME_FRAMES = 10
OLD_PUPIL_MM = 4.0
METHODS = ("none", "4 mm", "default", "real time", "learned", "ceiling")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
"""An image name ending so is a file of one's own (``--image``), not a held-out image."""


def held_out_image(name: str, size: int = SIZE) -> np.ndarray:
    """A held-out image, sRGB code values ``(size, size, 3)`` float32."""
    from skimage import data  # optional: scikit-image (the metrics and test extras)

    from ...plumbing.images import (
        prepare_image,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    if Path(name).suffix.lower() in IMAGE_SUFFIXES:       # a picture of your own (``bench robust --image``)
        from ...plumbing.imageio import read_image  # on use: start-up time (as above)

        return prepare_image(read_image(name, []), size, Path(name).stem)
    if name == "motorcycle":
        raw = data.stereo_motorcycle()[0][..., :3]
    elif name == "page":
        raw = data.page()
    elif name == "darktext":
        from .sequences import dark_text_page  # on use: Pillow (start-up time)

        raw = dark_text_page(size, size)
    else:
        raw = getattr(data, name)()
    return prepare_image(raw, size, name)


def realtime_still(design, target: np.ndarray, frames: int = REALTIME_FRAMES, cap: bool | None = None) -> np.ndarray:
    """What the real-time default shows after ``frames`` frames of a still (its CPU twin), under the
    light cap where ``cap`` (None: where the design's band has one)."""
    twin = AdmmFrames(design.kernel, design.reference, target.shape[:2], cap=design.capped if cap is None else cap)
    shown = None
    for _ in range(frames):
        shown = twin.frame(target, 2).shown
    return shown


def _learned(design, display, target: np.ndarray, problem, eye: EyeRx = EYE) -> np.ndarray | str:
    """The shipped learned model (``models/default.onnx``) on the same design, or why it refuses the eye."""
    from ...runtime.model_path import DEFAULT_MODEL  # on use: start-up time (the CLI imports the studies to build its parser)
    from ...runtime.unrolled import UnrolledModel  # on use: start-up time (as above)

    try:
        bound = UnrolledModel(DEFAULT_MODEL).for_eye(eye.with_changes(pupil_diameter_mm=design.pupil_mm), display,
                                                     design.kernel, design.reference, capped=problem.capped)
    except ValidationError as e:                  # an eye outside what the model was trained on: no column
        return str(e)
    return solve(problem, "learned", model=bound).image


def _case(display_name: str, image_name: str, bar, kernels: dict, size: int = SIZE,
          seen_pupils: Sequence[float] = SEEN_PUPILS_MM, seen_spheres: Sequence[float] = SEEN_SPHERES_D,
          eye: EyeRx = EYE, age_years: float | None = None) -> dict[str, Any]:
    display = get_display(display_name)
    codes = held_out_image(image_name, size)
    target = decode(display, codes).astype(np.float32)
    estimate = pupil_from_light(float(np.mean(target.astype(np.float64) @ luminance_weights(display))), display, age_years)
    p = estimate.diameter_mm                      # the eye as it is sees through this pupil
    from ...runtime.pupil_bank import (
        nearest_bank_pupil,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    entry = nearest_bank_pupil(p)                 # the default designs for the pupil bank's nearest entry
    shown: dict[str, np.ndarray] = {"none": target}
    old = design_eye(eye, display, OLD_PUPIL_MM, robust=False, kernels=kernels)
    shown["4 mm"] = solve(make_problem(target, old.kernel, old.reference), "fast").image
    choice = choose_band(target, display)         # --band auto: the band by the picture
    default = design_eye(eye, display, entry, band=choice.band, kernels=kernels)
    problem = make_design_problem(target, default)
    t0 = time.perf_counter()
    shown["default"] = solve(problem, "fast").image
    default_s = time.perf_counter() - t0
    seen_rt = choose_band(target, display, REALTIME_LOOK_SIDE)       # as the real-time path looks
    realtime = default if seen_rt.page_band == choice.page_band else \
        design_eye(eye, display, entry, band=seen_rt.band, kernels=kernels)
    shown["real time"] = realtime_still(realtime, target)
    learned = _learned(default, display, target, problem, eye)
    shown.update({} if isinstance(learned, str) else {"learned": learned})
    seen_eyes = [(q, 0.0) for q in seen_pupils] + [(p, s) for s in seen_spheres]
    rows = []
    for q, s in seen_eyes:
        exact = design_eye(eye.with_changes(sphere_D=eye.sphere_D + s), display, q, robust=False, kernels=kernels)
        ceiling = solve(make_problem(target, exact.kernel, exact.reference), "fast").image
        scores = {}
        seen_target = make_problem(target, exact.nominal, exact.nominal_reference)
        for method, image in {**shown, "ceiling": ceiling}.items():
            m, _ = evaluate_seen(image, target, exact.nominal, display)
            scores[method] = {"jod": m.jod, "flip": m.flip, "objective": objective(image, seen_target)}
            bar.update(1)
        rows.append({"pupil_mm": q, "sphere_offset_D": s, "scores": scores})
    return {"display": display_name, "image": Path(image_name).stem, "pupil_mm": p, "design_pupil_mm": entry,
            "band": choice.describe(), "page_band": choice.page_band,
            "pupil": estimate.describe() + f"; the default designed for {entry:.2f} mm, the pupil bank's nearest entry",
            "design": default.describe()[0] + (f"; learned: not run ({learned})" if isinstance(learned, str) else ""),
            "default_seconds": default_s, "rows": rows,
            "_problem": problem, "_default": default, "_target": target}


def _gain(row: dict, method: str) -> float:
    """JOD gain of ``method`` over none (NaN for a method not run: the learned model refused the eye)."""
    return row["scores"][method]["jod"] - row["scores"]["none"]["jod"] if method in row["scores"] else float("nan")


def _signed(v: float | None) -> str:
    return "-" if v is None or v != v else f"{v:+.2f}"                           # - : not run


def _checks(case: dict) -> dict[str, Any]:
    """The issue's checks on one case: the least JOD gain of the default and the real time over the
    checked eyes, and at 3 mm the default's share of the gain designed for exactly 3 mm."""
    p = case["pupil_mm"]
    checked = [r for r in case["rows"] if (r["sphere_offset_D"] == 0.0 and r["pupil_mm"] in CHECKED_PUPILS_MM)
               or (r["pupil_mm"] == p and r["sphere_offset_D"] in CHECKED_SPHERES_D)]
    at3 = next((r for r in case["rows"] if r["pupil_mm"] == 3.0 and r["sphere_offset_D"] == 0.0), None)
    ceiling = _gain(at3, "ceiling") if at3 is not None else 0.0
    return {"least_default": min((_gain(r, "default") for r in checked), default=float("nan")),
            "least_realtime": min((_gain(r, "real time") for r in checked), default=float("nan")),
            "least_learned": min((g for g in (_gain(r, "learned") for r in checked) if g == g), default=None),
            "least_4mm": min((_gain(r, "4 mm") for r in checked), default=float("nan")),
            "share_at_3mm": _gain(at3, "default") / ceiling if ceiling > 0 else None,
            "share_at_3mm_realtime": _gain(at3, "real time") / ceiling if ceiling > 0 else None,
            "share_at_3mm_learned": _gain(at3, "learned") / ceiling if ceiling > 0 and "learned" in at3["scores"] else None}


VIDEO_DISPLAY = "desktop"
VIDEO_SIZE = 128
VIDEO_PUPIL_MM = 3.125
"""The motion suite's design pupil (a bank entry; the suite's photographs give about 3.1-3.3 mm)."""
DARK = 0.08
"""The dark clip's scale of the photograph's code values (about 0.1 cd/m^2 on the desktop preset)."""


def _twin_run(design, frames: Sequence[np.ndarray], motions: Sequence[Any]) -> list[np.ndarray]:
    """The real-time default's CPU twin over linear frames with the motion ``vrcorrect render``
    estimates (a cold start at a cut)."""
    twin = AdmmFrames(design.kernel, design.reference, frames[0].shape[:2], cap=design.capped)
    shown = []
    for i, frame in enumerate(frames):
        m = None if i == 0 else motions[i - 1]
        cut = m == "cut"
        shown.append(twin.frame(frame, 2, shift=None if (cut or m is None) else m, cold=cut).shown)
    return shown


def _seen(kernel, shown: Sequence[np.ndarray]) -> np.ndarray:
    from ...specs.display import encode  # on use: start-up time (the CLI imports the studies to build its parser)
    from ...vision.forward import (  # on use: start-up time (the CLI imports the studies to build its parser)
        lms_to_display,
        simulate_lms,
    )

    return np.stack([encode("srgb", lms_to_display(simulate_lms(x, kernel)[0], kernel)) for x in shown])


def motion_suite(kernels: dict, size: int = VIDEO_SIZE, frames: int = 90) -> list[dict[str, Any]]:
    """The real-time default's share of per-frame ``fast``'s video JOD gain on the motion suite, the
    robust design and the one eye's at the same pupil (what the eye as modelled sees, against its view
    with glasses)."""
    from ...vision.vdp import video_jod  # on use: start-up time (the CLI imports the studies to build its parser)
    from .realtime import _motions, linear  # on use: start-up time (the CLI imports the studies to build its parser)
    from .sequences import suite  # on use: start-up time (the CLI imports the studies to build its parser)

    display = get_display(VIDEO_DISPLAY)
    designs = {"robust": design_eye(EYE, display, VIDEO_PUPIL_MM, kernels=kernels),
               "one eye": design_eye(EYE, display, VIDEO_PUPIL_MM, robust=False, kernels=kernels)}
    seen_k, seen_r = designs["one eye"].nominal, designs["one eye"].nominal_reference
    out = []
    for clip in suite(size, frames):
        lin = [linear(f) for f in clip.frames]
        motions = _motions(clip.frames)
        ref = np.stack([_ref_frame(seen_k, seen_r, x) for x in lin])
        none = video_jod(ref, _seen(seen_k, lin), display, 90.0)
        row = {"clip": clip.name, "none": none}
        for name, d in designs.items():
            fast = [solve(make_design_problem(x, d), "fast").image for x in lin]
            rt = _twin_run(d, lin, motions)
            jf, jr = video_jod(ref, _seen(seen_k, fast), display, 90.0), video_jod(ref, _seen(seen_k, rt), display, 90.0)
            row[name] = {"fast": jf, "real time": jr, "share": (jr - none) / (jf - none) if jf - none > 1e-9 else None}
        out.append(row)
    return out


def _ref_frame(kernel, reference, x: np.ndarray) -> np.ndarray:
    from ...specs.display import encode  # on use: start-up time (the CLI imports the studies to build its parser)
    from ...vision.forward import (  # on use: start-up time (the CLI imports the studies to build its parser)
        lms_to_display,
        simulate_lms,
    )

    return encode("srgb", lms_to_display(simulate_lms(x, reference)[0], kernel))


def dark_to_bright(kernels: dict, size: int = VIDEO_SIZE, dark_frames: int = 30, bright_frames: int = 60
                   ) -> dict[str, Any]:
    """A dark clip cut to a bright one, the real-time default with the pupil from the light (the
    follower and the bank's entries, each switch through ``AdmmFrames.set_design``, as the GPU's
    ``swap_model``), against the same with the design held at the bright scene's final entry.  The eye
    itself follows the light (:class:`~vrcorrect.physics.pupil.PupilDynamics`, no delay) and sees each
    frame through its pupil of the moment (the nearest bank entry's kernel).  Judged as video after
    the cut (ColorVideoVDP against its glasses-on view), with each frame's largest change of code
    values from the last: at the switches and elsewhere after the cut."""
    from ...physics.pupil import (
        PupilDynamics,  # on use: start-up time (the CLI imports the studies to build its parser)
    )
    from ...runtime.pupil_bank import (  # on use: start-up time (the CLI imports the studies to build its parser)
        PupilFollower,
        nearest_bank_pupil,
    )
    from ...specs.display import encode  # on use: start-up time (the CLI imports the studies to build its parser)
    from ...vision.vdp import video_jod  # on use: start-up time (the CLI imports the studies to build its parser)
    from .realtime import linear  # on use: start-up time (the CLI imports the studies to build its parser)
    from .sequences import photo  # on use: start-up time (the CLI imports the studies to build its parser)

    display = get_display(VIDEO_DISPLAY)
    bright = photo("astronaut", size)
    dark = np.round(bright.astype(np.float32) * DARK).astype(np.uint8)
    frames = [dark] * dark_frames + [bright] * bright_frames
    lin = [linear(f) for f in frames]
    lum = [float(np.mean(x.astype(np.float64) @ luminance_weights(display))) for x in lin]
    designs: dict[float, Any] = {}

    def design(p: float):
        if p not in designs:
            designs[p] = design_eye(EYE, display, p, kernels=kernels)
        return designs[p]

    follower = PupilFollower(display, entry_mm=nearest_bank_pupil(pupil_from_light(lum[0], display).diameter_mm))
    eye_pupil = PupilDynamics()
    current = follower.entry_mm
    first = design(current)                              # the dark scene's: the widest kernels of the clip
    twin = AdmmFrames(first.kernel, first.reference, (size, size),
                      grid_kernel_size=max(first.kernel.size, first.reference.size), cap=first.capped)
    shown, switches, seen_pupils = [], [], []
    for i, x in enumerate(lin):
        if i >= 2:
            entry = follower.update(lum[i - 2], 1 / 90)
            if entry != current:
                current = entry
                twin.set_design(design(current).kernel, design(current).reference)
                switches.append(i)
        if i == dark_frames:
            twin.reset()                                 # the cut, as render detects it
        shown.append(twin.frame(x, 2).shown)
        seen_pupils.append(nearest_bank_pupil(eye_pupil.update(pupil_from_light(lum[i], display).diameter_mm, 1 / 90)))
    held = AdmmFrames(design(current).kernel, design(current).reference, (size, size),
                      grid_kernel_size=twin.grid[0] - size + 1, cap=first.capped)
    held_shown = []
    for i, x in enumerate(lin):
        if i == dark_frames:
            held.reset()
        held_shown.append(held.frame(x, 2).shown)
    after = slice(dark_frames, len(lin))

    def seen_video(images):
        out = []
        for x, p in zip(images[after], seen_pupils[after]):
            k = design_eye(EYE, display, p, robust=False, kernels=kernels).nominal
            out.append(_seen(k, [x])[0])
        return np.stack(out)

    ref = np.stack([_ref_frame(design_eye(EYE, display, p, robust=False, kernels=kernels).nominal,
                               design_eye(EYE, display, p, robust=False, kernels=kernels).nominal_reference, x)
                    for x, p in zip(lin[after], seen_pupils[after])])
    jod = {"none": video_jod(ref, seen_video(lin), display, 90.0),
           "following the light": video_jod(ref, seen_video(shown), display, 90.0),
           "held at the final design": video_jod(ref, seen_video(held_shown), display, 90.0)}
    codes = [np.round(encode(display, np.clip(x, 0, 1)) * 255) for x in shown]
    change = [float(np.abs(codes[i] - codes[i - 1]).mean()) for i in range(1, len(codes))]
    at_switch = [change[i - 1] for i in switches if i > dark_frames]
    elsewhere = [change[i - 1] for i in range(dark_frames + 1, len(codes)) if i not in switches]
    return {"switches": switches, "designs_mm": sorted(designs), "jod": jod,
            "mean_change_at_switches": float(np.mean(at_switch)) if at_switch else None,
            "mean_change_at_the_cut": change[dark_frames - 1],
            "largest_change_elsewhere_after_the_cut": float(max(elsewhere[5:])) if len(elsewhere) > 5 else None,
            "pupil_mm_first_last": (seen_pupils[dark_frames], seen_pupils[-1])}


def photo_to_page(kernels: dict, size: int = VIDEO_SIZE, photo_frames: int = 30, page_frames: int = 60
                  ) -> dict[str, Any]:
    """A photograph cut to a page of text on white paper, the real-time default choosing the band as
    :class:`~vrcorrect.runtime.pupil_state.PupilState` does (a look every ``LOOK_EVERY`` frames, read
    ``LOOK_LATE`` later, ``BAND_HOLD`` verdicts in a row; the switch through ``AdmmFrames.set_design``
    with the cap), at the design pupil :data:`VIDEO_PUPIL_MM`, against the default band held throughout
    and the page band from the cut.  Judged as video after the cut by the eye as modelled, with each
    frame's mean change of code values from the last at the switch and elsewhere."""
    from ...runtime.pupil_state import BandFollower  # on use: start-up time (as above)
    from ...specs.display import encode  # on use: start-up time (the CLI imports the studies to build its parser)
    from ...vision.vdp import video_jod  # on use: start-up time (the CLI imports the studies to build its parser)
    from .realtime import linear  # on use: start-up time (the CLI imports the studies to build its parser)
    from .sequences import photo, text_page  # on use: start-up time (the CLI imports the studies to build its parser)

    display = get_display(VIDEO_DISPLAY)
    lin = [linear(f) for f in [photo("astronaut", size)] * photo_frames + [text_page(size, size)] * page_frames]
    bands = {"default": design_eye(EYE, display, VIDEO_PUPIL_MM, kernels=kernels),
             "page": design_eye(EYE, display, VIDEO_PUPIL_MM, band=PAGE_BAND, kernels=kernels)}
    grid = max(d.kernel.size for d in bands.values())

    def run(choose: bool, band: str, clip: Sequence[np.ndarray], cut: int | None) -> tuple[list[np.ndarray], list[int]]:
        """The twin over ``clip`` from ``band``, following the band by the picture where ``choose``
        (the real-time path's :class:`BandFollower`), reset at frame ``cut`` (as render detects it)."""
        twin = AdmmFrames(bands[band].kernel, bands[band].reference, (size, size), grid_kernel_size=grid,
                          cap=bands[band].capped)
        follower, looked, switches, shown = BandFollower(band), None, [], []
        for i, x in enumerate(clip):
            if i == cut:
                twin.reset()
                follower.cut()
            action = follower.tick() if choose else None
            if action == "look":
                looked = x
            elif action == "read":
                if follower.judge(page_verdict(looked, display, REALTIME_LOOK_SIDE)) != band:
                    band = follower.band
                    twin.set_design(bands[band].kernel, bands[band].reference, cap=bands[band].capped)
                    switches.append(i)
            shown.append(twin.frame(x, 2).shown)
        return shown, switches

    following, switches = run(True, "default", lin, photo_frames)
    held = {"default band held": run(False, "default", lin, photo_frames)[0],
            "page band from the cut": run(False, "page", lin[photo_frames:], None)[0]}
    after = slice(photo_frames, len(lin))
    eye = bands["default"].nominal, bands["default"].nominal_reference
    ref = np.stack([_ref_frame(eye[0], eye[1], x) for x in lin[after]])
    jod = {"none": video_jod(ref, _seen(eye[0], lin[after]), display, 90.0),
           "choosing by the picture": video_jod(ref, _seen(eye[0], following[after]), display, 90.0),
           **{k: video_jod(ref, _seen(eye[0], v[-len(ref):]), display, 90.0) for k, v in held.items()}}
    codes = [np.round(encode(display, np.clip(x, 0, 1)) * 255) for x in following]
    change = [float(np.abs(codes[i] - codes[i - 1]).mean()) for i in range(1, len(codes))]
    at_switch = [change[i - 1] for i in switches if i > photo_frames]
    elsewhere = [change[i - 1] for i in range(photo_frames + 6, len(codes)) if i not in switches]
    return {"switches": switches, "jod": jod, "mean_change_at_switches": float(np.mean(at_switch)) if at_switch else None,
            "mean_change_at_the_cut": change[photo_frames - 1],
            "changes_after_the_cut": [round(c, 2) for c in change[photo_frames - 1:photo_frames + 7]],
            "largest_change_elsewhere_after_the_cut": float(max(elsewhere)) if elsewhere else None}


def _plot(cases: list[dict], path: Path) -> None:
    from ..plots import pyplot, save_figure  # on use: start-up time (the CLI imports the studies to build its parser)

    plt = pyplot()
    displays = list(dict.fromkeys(c["display"] for c in cases))
    images = list(dict.fromkeys(c["image"] for c in cases))
    fig, axes = plt.subplots(len(displays), len(images), figsize=(4.2 * len(images), 3.4 * len(displays)),
                             squeeze=False)
    styles = {"4 mm": ("tab:red", "--"), "default": ("tab:blue", "-"), "real time": ("tab:cyan", ":"),
              "ceiling": ("0.4", "-.")}
    for case in cases:
        ax = axes[displays.index(case["display"])][images.index(case["image"])]
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
                     boundary: bool = True, video: bool = False, size: int = SIZE,
                     seen_pupils: Sequence[float] = SEEN_PUPILS_MM, seen_spheres: Sequence[float] = SEEN_SPHERES_D,
                     eye: EyeRx = EYE, age_years: float | None = None) -> dict[str, Any]:
    """Run the sweep (module docstring) for ``eye`` (of a viewer ``age_years`` old, for the pupil from
    the light; the video parts keep :data:`EYE`); with ``video`` also the motion suite and the dark clip
    cut to a bright one (:func:`motion_suite`, :func:`dark_to_bright`); returns the report."""
    kernels: dict = {}
    if video:
        t_video = time.perf_counter()
        suite_rows = motion_suite(kernels)
        light = dark_to_bright(kernels)
        to_page = photo_to_page(kernels)
        video_s = time.perf_counter() - t_video
    per_case = (len(seen_pupils) + len(seen_spheres)) * len(METHODS)
    cases = []
    t0 = time.perf_counter()
    with tqdm(total=per_case * len(displays) * len(images), desc="bench robust", unit="score") as bar:
        for d in displays:
            for name in images:
                cases.append(_case(d, name, bar, kernels, size, seen_pupils, seen_spheres, eye, age_years))
    bounds = [boundary_case(c) for c in cases] if boundary else []
    seconds = time.perf_counter() - t0
    lines = ["## The eye as it is: a correction against the eye it meets (`vrcorrect bench robust`)", "",
             f"Machine: {machine_description()}. {len(cases)} cases in {seconds / 60:.0f} min. The eye: right "
             f"{eye.sphere_D:+.2f}/{eye.cylinder_D:+.2f} x {eye.axis_deg:g}"
             + (f", age {age_years:g}" if age_years is not None else "") + f"; images at {size} px, "
             + (f"pictures given with --image ({', '.join(Path(n).name for n in images)}). "
                if any(Path(n).suffix.lower() in IMAGE_SUFFIXES for n in images) else
                "held out from choosing the robust band (scikit-image's stereo_motorcycle, a colour photograph; page, "
                "a scanned page of text; darktext, light words on dark blue, 18 px, added after the band was "
                "chosen). ")
             + "Each correction is seen by the eye as it is: pupils 2 to 7 mm at the prescription's "
             "sphere, and the sphere off by -0.5 to +0.5 D at the pupil the light gives. JOD (ColorVideoVDP) of "
             "what that eye sees against the target image; gains are over no correction. `4 mm`: designed for a "
             "4 mm pupil, as every correction was before; `default`: `--pupil auto --robust on --band auto` "
             "(`fast`; the band by the picture: a page on white paper the page band, without the light cap; "
             "anything else the robust band and its light cap, each primary at most twice the target's light plus "
             "0.02); `real time`: the real-time default's CPU twin, 10 frames of the still, its band by the picture "
             "as the GPU's look sees it (`render --band auto`); `learned`: "
             "the shipped learned model (models/default.onnx) on the default's design, under its light cap (if any) "
             "at every stage; `ceiling`: designed for exactly the eye seen (`--robust off`: one eye, the box [0, 1]).", ""]
    summary = []
    for c in cases:
        k = _checks(c)
        def pct(v):
            return "-" if v is None else f"{100 * v:.0f} %"

        summary.append([c["display"], c["image"], f"{c['pupil_mm']:.2f}", f"{k['least_4mm']:+.2f}",
                        f"{k['least_default']:+.2f} / {k['least_realtime']:+.2f} / " + _signed(k['least_learned']),
                        f"{pct(k['share_at_3mm'])} / {pct(k['share_at_3mm_realtime'])} / "
                        f"{pct(k['share_at_3mm_learned'])}"])
        c["checks"] = k
    lines += ["### The checks", "",
              "Least JOD gain over the eyes seen through pupils 2.5, 3, 4, 5.5 mm and with the sphere 0.5 D off "
              "either way (the default must stay at or above -0.05), and at 3 mm the default's share of the gain of "
              "a correction designed for exactly 3 mm (`--pupil 3 --robust off`; the issue asks 80 %).", "",
              markdown_table(["display", "image", "pupil from the light (mm)", "least gain, 4 mm design",
                              "least gain: default / real time / learned",
                              "share at 3 mm: default / real time / learned"], summary), ""]
    for c in cases:
        rows = []
        for r in c["rows"]:
            sc = r["scores"]
            rows.append([f"{r['pupil_mm']:.2f}", f"{r['sphere_offset_D']:+.2f}", f"{sc['none']['jod']:.2f}",
                         *(_signed(_gain(r, m)) for m in METHODS[1:]),
                         f"{sc['none']['flip']:.3f} / {sc['default']['flip']:.3f} / {sc['ceiling']['flip']:.3f}",
                         f"{sc['default']['objective'] / sc['none']['objective']:.3f}" if sc['none']['objective'] > 0
                         else "- (in focus)"])
        lines += [f"### {c['display']}, {c['image']}: {c['pupil']}", "", f"{c['band'][0].upper()}{c['band'][1:]}. "
                  f"{c['design']}.", "",
                  markdown_table(["pupil seen (mm)", "sphere off (D)", "JOD none", "4 mm", "default", "real time",
                                  "learned", "ceiling", "FLIP none / default / ceiling", "objective default / none"],
                                 rows), ""]
    if bounds:
        rows = [[b["display"], b["image"], f"{b['none']:.4g}", f"{b['effective']:.4g}", f"{b['exact']:.4g}",
                 gap_left(b), f"{b['exact_iterations']}", f"{b['exact_seconds']:.1f}"] for b in bounds]
        lines += ["### What the image's boundary does to the effective kernel", "",
                  "The robust design minimises the expectation of the objective over its band's eyes, each cropped to "
                  "the image; the effective kernel (one 3x3 solve a frequency, the cost of one kernel) crops its own "
                  "retina instead. The expectation of the effective kernel's solution (`fast`, to 1e-3) against the "
                  "exact expectation's (one split per member, to 1e-3): the gap as a share of the exact gain over no "
                  "correction. The page band's pull towards the target is in the effective kernel only, so on a page "
                  "the gap holds its cost too.", "",
                  markdown_table(["display", "image", "none", "effective kernel", "exact expectation", "gap left",
                                  "exact: iterations", "exact: s"], rows), ""]
    if video:
        rows = [[r["clip"], f"{r['none']:.2f}", f"{r['robust']['fast']:.2f}", f"{r['robust']['real time']:.2f}",
                 "-" if r["robust"]["share"] is None else f"{100 * r['robust']['share']:.0f} %",
                 "-" if r["one eye"]["share"] is None else f"{100 * r['one eye']['share']:.0f} %"]
                for r in suite_rows]
        lines += ["### As video: the motion suite, and a dark clip cut to a bright one", "",
                  f"The real-time default's CPU twin at {VIDEO_SIZE} px on {VIDEO_DISPLAY}, the design at "
                  f"{VIDEO_PUPIL_MM} mm: its share of per-frame `fast`'s video JOD gain with the robust design and "
                  f"with the one eye's (what the eye as modelled sees; {video_s / 60:.0f} min with the clip below).",
                  "", markdown_table(["clip", "JOD none", "robust: fast", "robust: real time", "share, robust",
                                      "share, one eye"], [row for row in rows]), ""]
        j = light["jod"]
        lines += [f"A photograph at {DARK:g} of its code values for 30 frames, cut to it at full brightness for 60 "
                  f"(90 Hz): the pupil from the light went through {len(light['switches'])} designs' switches "
                  f"(frames {', '.join(map(str, light['switches']))}; designs {', '.join(f'{p:.2f}' for p in light['designs_mm'])} "
                  f"mm), the eye's own pupil from {light['pupil_mm_first_last'][0]:.2f} to "
                  f"{light['pupil_mm_first_last'][1]:.2f} mm. Video JOD after the cut: none {j['none']:.2f}, following "
                  f"the light {j['following the light']:.2f}, held at the final design {j['held at the final design']:.2f}. "
                  "Mean change of code values from the frame before: at the cut "
                  f"{light['mean_change_at_the_cut']:.2f}, at a switch "
                  + ("-" if light["mean_change_at_switches"] is None else f"{light['mean_change_at_switches']:.2f}")
                  + "; the largest elsewhere after the first five frames past the cut: "
                  + ("-" if light["largest_change_elsewhere_after_the_cut"] is None
                     else f"{light['largest_change_elsewhere_after_the_cut']:.2f}") + ".", ""]
        from ...runtime.pupil_state import (  # on use: start-up time (the CLI imports the studies to build its parser)
            BAND_HOLD,
            LOOK_EVERY,
            LOOK_LATE,
        )

        j, p = to_page["jod"], to_page
        lines += [f"The photograph for 30 frames cut to a page of text on white paper for 60, the band chosen as the "
                  f"real-time path chooses it (a look every {LOOK_EVERY} frames, read {LOOK_LATE} later, "
                  f"{BAND_HOLD} verdicts in a row; the cut, reported as `render` reports it, looked at at once and "
                  "deciding alone): switched to the page band at frame(s) "
                  f"{', '.join(map(str, p['switches'])) or '-'}. Video JOD after the cut: none {j['none']:.2f}, "
                  f"choosing by the picture {j['choosing by the picture']:.2f}, the default band held "
                  f"{j['default band held']:.2f}, the page band from the cut {j['page band from the cut']:.2f}. "
                  f"Mean change of code values from the frame before: at the cut {p['mean_change_at_the_cut']:.2f}, "
                  "at the switch " + ("-" if p["mean_change_at_switches"] is None else f"{p['mean_change_at_switches']:.2f}")
                  + " (the first frames from the cut on: " + ", ".join(f"{c:.1f}" for c in p["changes_after_the_cut"])
                  + "); the largest elsewhere after the first five frames past the cut: "
                  + ("-" if p["largest_change_elsewhere_after_the_cut"] is None
                     else f"{p['largest_change_elsewhere_after_the_cut']:.2f}") + ".", ""]
    if plot is not None and write:                  # --no-write writes nothing: the plot neither
        _plot(cases, plot)
        lines += [f"![JOD gain over no correction against the pupil of the eye as it is]({plot.name})", ""]
    report = {"markdown": "\n".join(lines), "seconds": seconds,
              "cases": [{k: v for k, v in c.items() if not k.startswith("_")} for c in cases], "boundary": bounds}
    if video:
        report.update(motion_suite=suite_rows, dark_to_bright=light, photo_to_page=to_page)
    return publish(report, "robust", out, write, json_out, force)
