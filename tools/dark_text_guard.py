"""A third remedy for light text on a dark ground, tried and not adopted (issue 44): a guard that
weighs the eye's errors by Weber's law (docs/realtime.md, "The eye as it is").

Every correction is shown through a guard, ``t + beta (x - t)`` with the ``beta`` in [0, 1] that
minimises the objective, so that no frame is worse than uncorrected *by the objective*.  On a dark
ground the linear objective calls a correction better than none that the eye sees worse.  Weber's law
says the eye sees an error relative to the light around it, so this script weighs each pixel's
squared cone-image error by ``1 / (Y + c)^2``, with ``Y`` the target's cone image there (the mean of
L and M; white is about 1) and a dark floor ``c``.  The weighted objective is still quadratic in
``beta``, so the guard keeps its closed form: ``beta = clip(-<w r0, Kd> / <w Kd, Kd>, 0, 1)``.

Judged on the *choice* images only (the band's, ``tools/robust_band_choice.py``: scikit-image's
astronaut, coffee and text, the project's text chart) and three dark ones made for this
(``darkwords``: the tuning words light grey on near black, 16 px; ``invtext`` and ``darkchart``:
scikit-image's text and the chart inverted); the held-out images of ``bench robust`` are not used.
For ``fast`` (the robust default's design) and the real-time default's CPU twin (10 frames of the
still), three guards:

* ``linear``: today's (``fast`` shows its solution as it is; the twin's guard, through the effective
  kernel, gave ``beta`` 1.00 on every case here);
* ``weber``: the Weber-weighted expectation over the band's eyes (their kernels, ``c = 0.01``);
* ``weber, eff``: the same through the effective kernel and its target, which the GPU's guard
  already transforms (free on the GPU).

Printed: the least JOD gain over no correction over the eyes the issue checks (pupils 2.5, 3, 4,
5.5 mm; the sphere 0.5 D off either way at the light's pupil) and the gain at 3 mm.

    .venv/bin/python tools/dark_text_guard.py                       # all 14 cases (2.5 min)
    .venv/bin/python tools/dark_text_guard.py desktop darkwords     # one

Dev machine (2-core AMD EPYC), 2026-11-29; least gain / gain at 3 mm, linear guard -> weber (its beta):

* ``fast``: quest2 darkwords -0.03 / +0.14 -> +0.00 / +0.00 (0.00), darkchart -0.11 / -0.02 -> +0.00 /
  +0.00 (0.00); desktop darkwords +0.04 / +0.21 -> +0.10 / +0.20 (0.68), darkchart -0.75 / -0.55 ->
  -0.10 / -0.01 (0.49), invtext -0.16 / +1.37 -> -0.13 / +1.37 (0.98).  Elsewhere beta 1.00, except
  quest2's coffee 0.88 (3 mm +0.71 -> +0.67).  Desktop astronaut (-0.03) and coffee (-0.02) unchanged.
* the real-time twin: quest2 darkwords -0.27 / -0.03 -> -0.22 / +0.00 (0.92), darkchart -0.24 / -0.12 ->
  +0.00 / +0.00 (0.00); desktop darkchart -1.03 / -0.82 -> -0.27 / -0.15 (0.62); desktop darkwords
  (-0.06) and invtext (-0.09) unchanged (beta 0.99-1.00).
* ``weber, eff``: beta 1.00 everywhere but quest2's darkchart (0.00 in both: mended) and ``fast`` on
  quest2's darkwords (0.77: +0.02 / +0.15).

So weighing by Weber's law makes the guard refuse a correction that is bad for every eye (the
inverted chart, whose small letters no eye here resolves), but it does not see what is wrong with
the real-time default's dimmed strokes and lifted ground on dark text (quest2 darkwords stays at
-0.22), and where it helps most it needs the band's eyes' kernels: on the GPU three more transforms a
frame, since the effective kernel's view is not an eye's.  Not adopted.

Run with the box [0, 1] (``Problem.capped`` off, the twin uncapped): the default before the light
cap, which these figures describe; ``tools/light_cap_choice.py`` compares the two.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from robust_band_choice import EYE, SEEN, _kernels, choice_image
from vrcorrect.physics.perception import luminance_weights
from vrcorrect.physics.pupil import pupil_from_light
from vrcorrect.physics.robust import design_eye
from vrcorrect.plumbing.images import prepare_image
from vrcorrect.runtime.pupil_bank import nearest_bank_pupil
from vrcorrect.solvers import solve
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.solvers.realtime import AdmmFrames
from vrcorrect.specs.display import decode, get_display
from vrcorrect.studies.bench.sequences import WORDS, text_page
from vrcorrect.vision.forward import simulate_lms
from vrcorrect.vision.metrics import evaluate_seen

IMAGES = ("darkwords", "invtext", "darkchart", "astronaut", "coffee", "sktext", "chart")
DISPLAYS = ("quest2", "desktop")
FLOOR = 0.01
FRAMES = 10


def image(name: str) -> np.ndarray:
    if name == "darkwords":
        return prepare_image(text_page(256, 256, WORDS, font_px=16, ink=(225, 225, 225), paper=(18, 18, 18)), 256, name)
    if name == "invtext":
        return 1.0 - choice_image("sktext")
    if name == "darkchart":
        return 1.0 - choice_image("chart")
    return choice_image(name)


def weber_beta(eyes, target: np.ndarray, shown: np.ndarray) -> float:
    """The Weber-weighted guard's weight of ``shown`` over ``(weight, kernel, target cone image)`` eyes."""
    s_rk = s_kk = 0.0
    for weight, kernel, target_lms in eyes:
        Kt = simulate_lms(target, kernel)[0].astype(np.float64)
        kd = simulate_lms(shown, kernel)[0].astype(np.float64) - Kt
        T = target_lms.astype(np.float64)
        Y = np.clip(0.5 * (T[..., 0] + T[..., 1]), 0.0, None)[..., None]
        w = 1.0 / (Y + FLOOR) ** 2
        s_rk += weight * float(np.sum(w * (Kt - T) * kd))
        s_kk += weight * float(np.sum(w * kd * kd))
    return min(max(-s_rk / s_kk, 0.0), 1.0) if s_kk > 0 else 0.0


def default_design(display_name: str, name: str):
    """The case as ``--pupil auto --robust on`` designs it: the display, the linear target, the light's
    pupil, the design (the pupil bank's nearest entry) and its problem."""
    display = get_display(display_name)
    target = decode(display, image(name)).astype(np.float32)
    p = pupil_from_light(float(np.mean(target.astype(np.float64) @ luminance_weights(display))), display).diameter_mm
    design = design_eye(EYE, display, nearest_bank_pupil(p), kernels=_kernels)
    return display, target, p, design, make_design_problem(target, design)


def seen_gains(display, target: np.ndarray, p: float, shown: dict) -> dict:
    """Each image's JOD gain over no correction through the eyes of ``SEEN`` (``None``: the light's pupil ``p``)."""
    gains: dict = {key: [] for key in shown}
    for q, s in SEEN:
        seen = design_eye(EYE.with_changes(sphere_D=EYE.sphere_D + s), display, p if q is None else q, robust=False,
                          kernels=_kernels).nominal
        none = evaluate_seen(target, target, seen, display)[0].jod
        for key, img in shown.items():
            gains[key].append(evaluate_seen(np.clip(img, 0.0, 1.0), target, seen, display)[0].jod - none)
    return gains


def run(display_name: str, name: str) -> None:
    t0 = time.perf_counter()
    display, target, p, design, problem = default_design(display_name, name)
    members = [(m.weight, m.kernel, m.target_lms) for m in problem.members]
    effective = [(1.0, design.kernel, problem.target_lms)]
    twin = AdmmFrames(design.kernel, design.reference, target.shape[:2])
    for _ in range(FRAMES):
        frame = twin.frame(target, 2)
    solutions = {"fast": solve(replace(problem, capped=False), "fast").image, "real time": np.clip(frame.solution, 0.0, 1.0)}
    shown, betas = {}, {}
    for method, x in solutions.items():
        linear = 1.0 if method == "fast" else frame.beta
        for guard, beta in (("linear", linear), ("weber", weber_beta(members, target, x)),
                            ("weber, eff", weber_beta(effective, target, x))):
            shown[(method, guard)] = target + np.float32(beta) * (x - target)
            betas[(method, guard)] = beta
    gains = seen_gains(display, target, p, shown)
    print(f"{display_name} {name} (light {p:.2f} mm, {time.perf_counter() - t0:.0f} s)", flush=True)
    for key, g in gains.items():
        print(f"    {key[0]:9s} {key[1]:10s} beta {betas[key]:.2f}  least {min(g):+.2f}  3 mm {g[1]:+.2f}", flush=True)


def main(argv: list[str], case=None) -> None:
    """``case(display, image)`` (default: this script's :func:`run`) on the displays and images named by
    ``argv`` (comma-separated; default all); ``tools/light_cap_choice.py`` runs its own."""
    for d in (argv[0].split(",") if argv else DISPLAYS):
        for name in (argv[1].split(",") if len(argv) > 1 else IMAGES):
            (case or run)(d, name)


if __name__ == "__main__":
    main(sys.argv[1:])
