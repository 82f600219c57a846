"""Two remedies for light text on a dark ground, tried and not adopted (issue 44; docs/realtime.md,
"The eye as it is").

On ``vrcorrect bench robust``'s dark-mode still (``darktext``) the robust default falls below no
correction for eyes that see better than modelled.  This script reproduces what was tried against
``fast`` (the default's design, ``--pupil auto --robust on``), seen by the eyes the issue checks
(pupils 2.5, 3, 4, 5.5 mm; the sphere 0.5 D off either way at the light's pupil), JOD gain over no
correction:

* ``half``: half of the correction shown, ``t + 0.5 (x - t)``;
* ``cube root``: the design's expectation with each cone image encoded by ``cbrt(y + 0.01)`` (a
  perceptual, compressive encoding) instead of linear, minimised from ``fast``'s solution by
  L-BFGS-B in [0, 1] with torch's gradient (float64; the forward model, the learned model's
  :func:`vrcorrect.learn.train.retina`, is checked against :func:`vrcorrect.vision.forward.simulate_lms`
  first).

    .venv/bin/python tools/dark_text_remedies.py                    # darktext, page, motorcycle on quest2 and desktop
    .venv/bin/python tools/dark_text_remedies.py quest2 darktext    # one case

28-62 s a case, 4.6 min in all, on the dev machine (2-core AMD EPYC, 2026-11-29), which printed
(the least JOD gain over the six eyes; the gain at 3 mm; quest2 / desktop):

* darktext: ``fast`` -0.15 / -0.10, at 3 mm +0.14 / +0.21; ``half`` +0.00 / +0.05, at 3 mm +0.13 /
  +0.18; ``cube root`` -0.41 / -0.24, at 3 mm -0.01 / +0.16;
* page: ``fast`` +0.04 / +0.07, at 3 mm +0.77 / +0.78; ``half`` +0.02 / +0.04, +0.38 / +0.39;
  ``cube root`` +0.10 / +0.07, +0.95 / +0.92;
* motorcycle: ``fast`` +0.08 / -0.00, at 3 mm +0.93 / +0.97; ``half`` +0.04 / +0.07, +0.51 / +0.55;
  ``cube root`` +0.10 / -0.04, +1.13 / +1.12.

So half the correction keeps dark text above none and nearly all of its small gain, and halves the
gain elsewhere; the cube root gains more on the page and the photograph and loses more on dark text.

Run with the box [0, 1] (``Problem.capped`` off, the twin uncapped): the default before the light
cap, which these figures describe; ``tools/light_cap_choice.py`` compares the two.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
import scipy.optimize
import torch

from vrcorrect.learn.train import retina
from vrcorrect.physics.perception import luminance_weights
from vrcorrect.physics.pupil import pupil_from_light
from vrcorrect.physics.robust import design_eye
from vrcorrect.runtime.pupil_bank import nearest_bank_pupil
from vrcorrect.solvers import solve
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.specs.display import decode, get_display
from vrcorrect.studies.bench.robust import EYE, held_out_image
from vrcorrect.vision.forward import simulate_lms
from vrcorrect.vision.metrics import evaluate_seen

SEEN = ((2.5, 0.0), (3.0, 0.0), (4.0, 0.0), (5.5, 0.0), (None, -0.5), (None, 0.5))   # None: the light's pupil
Y0 = 0.01
ITERATIONS = 300


def seen(x: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """A kernel's ``(3, H, W)`` cone image of ``(3, H, W)`` linear RGB: the learned model's forward
    model (:func:`vrcorrect.learn.train.retina`, which ``simulate_lms`` equals)."""
    return retina(x[None], kernel[None])[0]


def encode(y: torch.Tensor) -> torch.Tensor:
    return torch.pow(torch.clamp(y, min=0.0) + Y0, 1.0 / 3.0)


def check_forward(design) -> float:
    """The largest difference between :func:`seen` and ``simulate_lms`` on noise, over the design's kernels."""
    x = np.random.default_rng(0).random((48, 40, 3), dtype=np.float32)
    worst = 0.0
    for m in design.members:
        for k in design.member_kernels(m):
            if k is None or k.size == 1:
                continue
            got = seen(torch.as_tensor(np.moveaxis(x, 2, 0).astype(np.float64)),
                       torch.as_tensor(k.kernel, dtype=torch.float64)).numpy()
            worst = max(worst, float(np.max(np.abs(np.moveaxis(got, 0, 2) - simulate_lms(x, k)[0]))))
    return worst


def cube_root_solution(problem, start: np.ndarray) -> np.ndarray:
    h, w, _ = start.shape
    members = [(torch.as_tensor(m.kernel.kernel, dtype=torch.float64),
                encode(torch.as_tensor(np.moveaxis(m.target_lms, 2, 0).astype(np.float64))), m.weight)
               for m in problem.members]
    total = sum(weight for _, _, weight in members)
    scale: list[float] = []

    def objective(v: np.ndarray) -> tuple[float, np.ndarray]:
        x = torch.as_tensor(v.reshape(3, h, w)).requires_grad_(True)
        loss = sum(weight * torch.mean((encode(seen(x, kernel)) - target) ** 2) for kernel, target, weight in members) / total
        if not scale:                      # relative, so that L-BFGS-B's tolerance means the same on every image
            scale.append(float(loss.detach()))
        (loss / scale[0]).backward()
        return float(loss.detach()) / scale[0], x.grad.numpy().ravel()

    v0 = np.moveaxis(start, 2, 0).astype(np.float64).ravel()
    result = scipy.optimize.minimize(objective, v0, jac=True, method="L-BFGS-B", bounds=[(0.0, 1.0)] * v0.size,
                                     options={"maxiter": ITERATIONS, "ftol": 1e-10, "gtol": 1e-12})
    return np.moveaxis(result.x.reshape(3, h, w), 0, 2).astype(np.float32)


def run(display_name: str, image: str, kernels: dict) -> None:
    t0 = time.perf_counter()
    display = get_display(display_name)
    target = decode(display, held_out_image(image)).astype(np.float32)
    p = pupil_from_light(float(np.mean(target.astype(np.float64) @ luminance_weights(display))), display).diameter_mm
    design = design_eye(EYE, display, nearest_bank_pupil(p), kernels=kernels)
    mismatch = check_forward(design)
    if mismatch > 1e-4:
        raise SystemExit(f"the torch forward model differs from simulate_lms by {mismatch:.2g}")
    problem = replace(make_design_problem(target, design), capped=False)     # the box [0, 1] (module docstring)
    x = solve(problem, "fast").image
    shown = {"fast": x, "half": target + 0.5 * (x - target), "cube root": cube_root_solution(problem, x)}
    gains: dict[str, list[float]] = {name: [] for name in shown}
    at_3mm = {}
    for q, s in SEEN:
        seen = design_eye(EYE.with_changes(sphere_D=EYE.sphere_D + s), display, p if q is None else q, robust=False,
                          kernels=kernels).nominal
        none = evaluate_seen(target, target, seen, display)[0].jod
        for name, image_shown in shown.items():
            gain = evaluate_seen(np.clip(image_shown, 0, 1), target, seen, display)[0].jod - none
            gains[name].append(gain)
            if q == 3.0:
                at_3mm[name] = gain
    print(f"{display_name:8s} {image:10s} light {p:.2f} mm  " + "  ".join(
        f"{name}: least {min(g):+.2f}, 3 mm {at_3mm[name]:+.2f}" for name, g in gains.items())
        + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    displays = argv[0].split(",") if argv else ["quest2", "desktop"]
    images = argv[1].split(",") if len(argv) > 1 else ["darktext", "page", "motorcycle"]
    kernels: dict = {}
    for d in displays:
        for image in images:
            run(d, image, kernels)


if __name__ == "__main__":
    main(sys.argv[1:])
