"""What the pupil bank's reach costs a dark scene (``runtime/pupil_bank.py``, ``BANK_REACH_STEPS``).

With ``pupil="auto"`` the grids hold the designs up to six bank entries above the first one; a darker
scene's pupil beyond that is designed for at the reach.  This script measures what that gives up: the
held-out photograph (``bench robust``'s ``motorcycle``) dimmed until the light-adapted pupil is wide,
corrected by ``fast`` with the robust design (as ``bench robust``'s default) for the entry nearest the
pupil (what the bank gave before the reach) and for the reach of a first design at 3.125 mm (4.88 mm,
a typical headset start), each seen by the eye of that pupil; JOD gain over no correction (ColorVideoVDP)
and FLIP.

    .venv/bin/python tools/pupil_reach_cost.py              # quest2 and desktop, three dim levels
    .venv/bin/python tools/pupil_reach_cost.py quest2       # one display

About 1.5 min on the dev machine (2-core AMD EPYC, 2026-11-29), which printed (the pupil; the gain of
the entry's design, then the reach's; the share kept): quest2 x0.3 4.17 mm, x0.15 4.82 mm: within the
reach, the same; x0.08 5.30 mm +0.81, +0.70, 87 %; x0.04 5.70 mm +0.61, +0.35, 57 %; desktop x0.3
4.59 mm: the same; x0.15 5.26 mm +0.97, +0.81, 83 %; x0.08 5.72 mm +0.75, +0.49, 65 %; x0.04 6.09 mm
+0.44, +0.23, 51 %.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from vrcorrect.physics.perception import luminance_weights
from vrcorrect.physics.pupil import pupil_from_light
from vrcorrect.physics.robust import design_eye
from vrcorrect.runtime.pupil_bank import bank_reach_mm, nearest_bank_pupil
from vrcorrect.solvers import solve
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.specs.display import decode, get_display
from vrcorrect.studies.bench.robust import EYE, held_out_image
from vrcorrect.vision.metrics import evaluate_seen

FIRST_ENTRY_MM = 3.125
DIM = (0.3, 0.15, 0.08, 0.04)          # the photograph's sRGB code values times this, then decoded


def case(display_name: str, dim: float, kernels: dict) -> dict:
    display = get_display(display_name)
    codes = held_out_image("motorcycle").astype(np.float64) * dim
    target = decode(display, codes).astype(np.float32)
    lum = float(np.mean(target.astype(np.float64) @ luminance_weights(display)))
    pupil = pupil_from_light(lum, display).diameter_mm
    seen = design_eye(EYE, display, pupil, robust=False, kernels=kernels)
    none, _ = evaluate_seen(target, target, seen.nominal, display)
    row = {"display": display_name, "dim": dim, "pupil_mm": pupil, "none_jod": none.jod}
    for name, entry in (("entry", nearest_bank_pupil(pupil)), ("reach", min(bank_reach_mm(FIRST_ENTRY_MM),
                                                                             nearest_bank_pupil(pupil)))):
        design = design_eye(EYE, display, entry, kernels=kernels)
        shown = solve(make_design_problem(target, design), "fast").image
        m, _ = evaluate_seen(shown, target, seen.nominal, display)
        row[name] = {"design_mm": entry, "gain": m.jod - none.jod, "flip": m.flip}
    return row


def main(argv: list[str]) -> int:
    displays = argv or ["quest2", "desktop"]
    kernels: dict = {}
    print("| display | dim | pupil | design at the entry: gain (FLIP) | design at the reach: gain (FLIP) | kept |")
    print("|---|---|---|---|---|---|")
    for d in displays:
        for dim in DIM:
            t0 = time.perf_counter()
            r = case(d, dim, kernels)
            e, c = r["entry"], r["reach"]
            kept = c["gain"] / e["gain"] if e["gain"] > 1e-9 else float("nan")
            print(f"| {d} | {dim} | {r['pupil_mm']:.2f} mm | {e['design_mm']:.2f} mm: {e['gain']:+.2f} ({e['flip']:.3f}) "
                  f"| {c['design_mm']:.2f} mm: {c['gain']:+.2f} ({c['flip']:.3f}) | {100 * kept:.0f} % |  "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
