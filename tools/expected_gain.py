"""The robust design's own expected gain beside what the eyes of issue 44's floor see (a lead of
2026-12-05, docs/realtime.md, "Standing aside where the correction gains little"): for the bench's eye
and each ``--rx`` eye, on desktop and quest2, and each ``--image`` (256 px), the default correction
(``fast``, the default band, the pupil from the picture's light at the pupil bank's nearest entry), and:

* ``ratio``: its expected error over none's by the band's own objective;
* ``ceiling``: the JOD gain over none of a correction designed for exactly 3 mm (``--pupil 3 --robust off``);
* each of the six seen eyes' JOD gain over none (pupils 2.5, 3, 4, 5.5 mm; the sphere 0.5 D off either
  way at the light's pupil), and the least.

    .venv/bin/python tools/expected_gain.py --image a.png --image hubble_deep_field --rx rx.json

A study, not a judge; about 40 s per (eye, display, picture) on 2 cores.
"""

from __future__ import annotations

import argparse
import sys

import robust_band_choice as rb  # tools/: this script's folder
from guard_tradeoff import default_design, each_case, eyes_and_pictures, picture_arguments
from vrcorrect.solvers import solve
from vrcorrect.solvers.problem import make_design_problem, objective


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="expected_gain", description=__doc__.split("\n\n")[0])
    picture_arguments(ap)
    args = ap.parse_args(argv)
    parsed = eyes_and_pictures(args, "expected_gain")
    if parsed is None:
        return 2
    eyes, names = parsed
    print("ratio: fast's expected error over none's; ceiling: the exact 3 mm design's JOD gain; the six seen "
          "eyes' JOD gains", flush=True)
    for tag, eye, display_name, name, display, target, p, seen in each_case(eyes, names):
        design = default_design(eye, display, p)
        if design.sees_as_with_glasses:
            print(f"  {tag:12s} {display_name:8s} {name:22s} in focus: shown as it is", flush=True)
            continue
        problem = make_design_problem(target, design)
        shown = solve(problem, "fast").image
        ratio = objective(shown, problem) / max(objective(target, problem), 1e-30)
        gains = rb.seen_gains(shown, target, seen, display)
        ceiling = rb.ceiling_of(seen)
        print(f"  {tag:12s} {display_name:8s} {name:22s} light {p:.2f} mm  ratio {ratio:.3f}"
              f"  ceiling {ceiling:+.2f}  least {min(gains):+.2f}"
              "  gains " + " ".join(f"{g:+.2f}" for g in gains), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
