"""What modelling an eye's accommodative lag buys, and what it risks (``accommodative_lag_D``).

For eyes that focus (age 30: 9.5 D of amplitude, Hofstetter's mean) with a stated lag, on desktop and
quest2 and each picture (256 px), the picture's light gives the pupil (the pupil bank's nearest entry
for the designs) and:

* ``none``: the JOD of the picture as it is, seen by the eye with its lag, against what it sees with
  its glasses;
* ``lag modelled``: the JOD gain over none of the default correction (``fast``, the default band)
  designed for the eye with its lag;
* ``lag ignored``: the same for the eye designed without its lag (what vrcorrect did before the
  field: for an eye that focuses on the display, the picture as it is);
* ``lag off by -0.25 / +0.25``: the gain of ``lag modelled`` seen by the eye whose real lag is 0.25 D
  less or more than stated (the lag's measurement error), the risk of stating one.

    .venv/bin/python tools/lag_gain.py --image astronaut --image words --lag 0.5 0.75 1.0

A study, not a judge; about a minute per (eye, display, picture) on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import robust_band_choice as rb  # tools/: this script's folder
from guard_tradeoff import default_design
from vrcorrect.physics.perception import luminance_weights
from vrcorrect.physics.pupil import pupil_from_light
from vrcorrect.physics.robust import design_eye
from vrcorrect.solvers import solve
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx, accommodation_from_age
from vrcorrect.vision.metrics import evaluate_seen

AGE = 30.0
SPHERES = (0.0, -1.0, 1.0)
MEASUREMENT_D = 0.25


def _shown(eye: EyeRx, display, target: np.ndarray, pupil_mm: float) -> np.ndarray:
    """What the default shows for ``eye`` (the picture as it is where the eye needs nothing)."""
    design = default_design(eye, display, pupil_mm)
    if design.sees_as_with_glasses:
        return target
    return solve(make_design_problem(target, design), "fast").image


def _seen(eye: EyeRx, display, pupil_mm: float):
    """The kernel of ``eye`` as it is, through exactly the light's pupil (its kernels kept in ``rb``'s cache)."""
    return design_eye(eye, display, pupil_mm, robust=False, kernels=rb._kernels).nominal


def _jod(shown: np.ndarray, target: np.ndarray, eye: EyeRx, display, pupil_mm: float) -> float:
    """The JOD of what ``eye`` sees of ``shown`` against its view of ``target`` with its glasses."""
    return evaluate_seen(shown, target, _seen(eye, display, pupil_mm), display)[0].jod


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="lag_gain", description=__doc__.split("\n\n")[0])
    ap.add_argument("--image", action="append", default=None, help="a scikit-image name or tools' choice picture "
                    "(repeatable; default astronaut and words)")
    ap.add_argument("--lag", type=float, nargs="+", default=[0.5, 0.75, 1.0], help="the stated lags, D at 40 cm")
    ap.add_argument("--sphere", type=float, nargs="+", default=list(SPHERES), help="the eyes' spheres, D")
    args = ap.parse_args(argv)
    images = args.image or ["astronaut", "words"]
    amplitude = accommodation_from_age(AGE)
    print(f"age {AGE:g} ({amplitude:.1f} D of amplitude); JOD of none, and each correction's gain over none", flush=True)
    print(f"{'sphere':>6s} {'lag':>5s} {'display':8s} {'picture':12s} {'pupil':>6s} {'residual':>8s} {'none':>6s} "
          f"{'modelled':>9s} {'ignored':>8s} {'-0.25':>6s} {'+0.25':>6s}", flush=True)
    for display_name in rb.DISPLAYS:
        display = get_display(display_name)
        for name in images:
            target = decode(display, rb.choice_image(name)).astype(np.float32)
            light = float(np.mean(target.astype(np.float64) @ luminance_weights(display)))
            p = pupil_from_light(light, display, AGE).diameter_mm
            for sphere in args.sphere:
                plain = EyeRx(sphere, 0.0, 0.0, 4.0, accommodation_D=amplitude)
                ignored = _shown(plain, display, target, p)
                for lag in args.lag:
                    t0 = time.perf_counter()
                    eye = plain.with_changes(accommodative_lag_D=lag)
                    modelled = _shown(eye, display, target, p)
                    none = _jod(target, target, eye, display, p)
                    gains = [_jod(modelled, target, eye, display, p) - none, _jod(ignored, target, eye, display, p) - none]
                    for d in (-MEASUREMENT_D, MEASUREMENT_D):
                        off = eye.with_changes(accommodative_lag_D=min(max(lag + d, 0.0), 2.0))
                        gains.append(_jod(modelled, target, off, display, p) - _jod(target, target, off, display, p))
                    residual = _seen(eye, display, p).state.residual.M_D
                    print(f"{sphere:+6.2f} {lag:5.2f} {display_name:8s} {name:12s} {p:4.2f}mm {residual:+8.2f} "
                          f"{none:6.2f} " + " ".join(f"{g:+{w}.2f}" for g, w in zip(gains, (9, 8, 6, 6)))
                          + f"   ({time.perf_counter() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
