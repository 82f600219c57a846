"""Can any blend meet issue 44's two bars at once?  For each (eye, display, picture): the blends
``t + beta (x - t)`` of the picture ``t`` with a correction ``x``, for ``x`` the correction designed for
exactly 3 mm (``--pupil 3 --robust off``, whose gain at 3 mm is the share's 100 %) and the default
(``fast``, the default band, the pupil from the light at the bank's nearest entry), seen by the six eyes
of the floor (pupils 2.5, 3, 4, 5.5 mm; the sphere 0.5 D off either way at the light's pupil) and
judged with ColorVideoVDP against none.

Printed per path: the least blend that keeps 80 % of the exact 3 mm gain at 3 mm, and the least gain
over the six seen eyes there (the floor: -0.05 or above); and the largest blend whose least gain is at
or above -0.05, with its 3 mm share.  Where even the exact design's blend that keeps 80 % makes some
seen eye fall, the two bars cannot both be met by blending that correction, and a design chosen by
the eye's blur alone (the exact one is the best any design does at 3 mm) has no room between them.

    .venv/bin/python tools/bars_frontier.py --image rocket --image retina --rx rx.json

A study, not a judge; the pictures it is run on should be spent ones (it chooses nothing).  About a
minute and a half per (eye, display, picture) on 2 cores.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import robust_band_choice as rb  # tools/: this script's folder
from guard_tradeoff import eyes_and_pictures, picture_arguments
from vrcorrect.physics.robust import design_eye
from vrcorrect.runtime.pupil_bank import nearest_bank_pupil
from vrcorrect.solvers import make_problem, solve
from vrcorrect.solvers.problem import make_design_problem

BETAS = tuple(round(b, 2) for b in np.linspace(0.1, 1.0, 10))
SHARE = 0.8           # issue 44: at 3 mm at least 80 % of the exact 3 mm design's gain
FALL = -0.05          # issue 44's floor


def _path(x: np.ndarray, target: np.ndarray, seen, display) -> list[tuple[float, list[float]]]:
    """Each blend's seen gains, from the smallest blend up."""
    return [(b, rb.seen_gains(target + np.float32(b) * (x - target), target, seen, display)) for b in BETAS]


def _verdict(path, ceiling: float) -> str:
    keeping = [(b, g) for b, g in path if g[1] >= SHARE * ceiling]
    safe = [(b, g) for b, g in path if min(g) >= FALL]
    first = (f"80 % from blend {keeping[0][0]:.1f}, least there {min(keeping[0][1]):+.2f}" if keeping
             else "never 80 %")
    last = (f"safe up to {safe[-1][0]:.1f}, 3 mm share there {safe[-1][1][1] / ceiling:4.0%}" if safe
            else "never safe")
    return f"{first:38s} {last}"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bars_frontier", description=__doc__.split("\n\n")[0])
    picture_arguments(ap)
    ap.add_argument("--no-bench", action="store_true", help="leave out the bench's eye")
    ap.add_argument("--display", choices=rb.DISPLAYS, action="append", help="the displays (default both)")
    args = ap.parse_args(argv)
    parsed = eyes_and_pictures(args, "bars_frontier")
    if parsed is None:
        return 2
    eyes, names = parsed
    if args.no_bench:
        eyes = eyes[1:]
    conflicts = cases = 0
    for tag, eye, age in eyes:
        rb._eye.update(eye=eye, age=age)
        rb._cases.clear()
        for display_name in args.display or rb.DISPLAYS:
            for name in names:
                display, target, p, seen = rb._case(display_name, name)
                ceiling = next(c for _, _, c in seen if c is not None)
                if ceiling < 0.1:
                    print(f"  {tag:12s} {display_name:8s} {name:22s} exact 3 mm gain {ceiling:+.2f}: no share worth "
                          "reading", flush=True)
                    continue
                exact3 = next(e for (e, _, c) in seen if c is not None)
                best = solve(make_problem(target, exact3.kernel, exact3.reference), "fast").image
                design = design_eye(eye, display, nearest_bank_pupil(p), band=None, kernels=rb._kernels, robust=True)
                default = solve(make_design_problem(target, design), "fast").image
                exact_path = _path(best, target, seen, display)
                cases += 1
                keeping = [g for b, g in exact_path if g[1] >= SHARE * ceiling]
                conflicts += bool(keeping) and min(keeping[0]) < FALL
                print(f"  {tag:12s} {display_name:8s} {name:22s} exact 3 mm gain {ceiling:+.2f}", flush=True)
                print(f"      exact 3 mm design: {_verdict(exact_path, ceiling)}", flush=True)
                print(f"      default:           {_verdict(_path(default, target, seen, display), ceiling)}",
                      flush=True)
    print(f"{conflicts} of {cases} cases: the exact design's blend that keeps 80 % at 3 mm makes a seen eye fall")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
