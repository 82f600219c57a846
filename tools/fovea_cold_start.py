"""Where the foveated default lost to the full field on the held-out sliding colour wheel (issue 45;
docs/realtime.md, "Correct where the eye looks").

``vrcorrect bench fovea --video`` played the wheel clip 0.24 JOD under the full field at the gaze (the
issue's bar: 0.2).  This holds the clip's middle frame still for 60 frames at 90 Hz and judges it as
video (FovVideoVDP fixating the window's centre) twice: frames 0-29, from the first (cold) frame as
the bench plays a clip, and frames 30-59, converged.  It does so for the foveated default with its
cold iterations (``COLD_WINDOW_ITERATIONS``, ``COLD_PERIPHERY_ITERATIONS``) and without them:

    .venv/bin/python tools/fovea_cold_start.py            # sprite (3-4 min on the dev machine)
    .venv/bin/python tools/fovea_cold_start.py cut

What it printed for ``sprite`` (dev machine, 2-core AMD EPYC, 2026-11-29, 10 min beside the bench),
foveated less full field at the gaze, frames 0-29 from cold / 30-59 converged:

    foveated, no cold iterations   -0.214 / -0.135
    foveated (the default)         -0.076 / -0.135

So most of the clip's loss beyond a still's was the cold start, not the motion: the window and its
quarter-resolution periphery, 2 iterations a frame each from the target, took about five frames to
converge (the full field starts from its half-resolution level).  What remains once converged is the
periphery's resolution (at half resolution the same frame, judged as an image, is 0.02 under).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.runtime.strategies.foveated import PERIPHERY_ITERATIONS
from vrcorrect.solvers.foveated import FoveatedFrames, fovea_pixels
from vrcorrect.solvers.realtime import AdmmFrames
from vrcorrect.specs.display import encode, get_display
from vrcorrect.specs.vocabulary import Periphery
from vrcorrect.studies.bench import fovea as F
from vrcorrect.studies.bench.realtime import linear
from vrcorrect.studies.bench.sequences import HELD_OUT, held_out
from vrcorrect.vision.forward import lms_to_display, simulate_lms
from vrcorrect.vision.vdp import foveated_video_jod


def main(argv: list[str]) -> int:
    name = argv[0] if argv else "sprite"
    if name not in HELD_OUT:
        print(f"clip: {name!r} is not a held-out clip (one of {', '.join(HELD_OUT)})", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    display = get_display("quest2")
    ppd = float(display.pixels_per_degree)
    K, R = build_kernel(F.EYE, display), build_reference_kernel(F.EYE, display)
    view = F.VIEW
    centre = (view / 2.0, view / 2.0)
    clip = {c.name: c for c in held_out(view, F.VIDEO_FRAMES)}[name]
    target = linear(clip.frames[len(clip.frames) // 2])

    def seen(kernel, x: np.ndarray) -> np.ndarray:          # what the eye sees, sRGB
        return np.clip(encode("srgb", lms_to_display(simulate_lms(x, kernel)[0], K)), 0.0, 1.0)

    reference = [seen(R, target)] * F.VIDEO_FRAMES
    radius_px, band_px = fovea_pixels(F.CHECK_RADIUS_DEG, ppd)
    quarter = Periphery.QUARTER
    twins = {"full field": lambda: AdmmFrames(K, R, (view, view)),
             "foveated": lambda: FoveatedFrames(K, R, (view, view), radius_px=radius_px, band_px=band_px,
                                                periphery=quarter, periphery_iterations=PERIPHERY_ITERATIONS[quarter]),
             "foveated, no cold iterations": lambda: FoveatedFrames(
                 K, R, (view, view), radius_px=radius_px, band_px=band_px, periphery=quarter,
                 periphery_iterations=PERIPHERY_ITERATIONS[quarter], cold_window_iterations=0,
                 cold_periphery_iterations=0)}
    scores: dict[str, tuple[float, float]] = {}
    for label, make in twins.items():
        twin = make()
        extra = {} if label == "full field" else {"gaze_px": centre}
        shown = [seen(K, np.clip(twin.frame(target, F.DEFAULT_ITERATIONS, **extra).shown, 0.0, 1.0))
                 for _ in range(2 * F.VIDEO_FRAMES)]
        n = F.VIDEO_FRAMES
        scores[label] = (foveated_video_jod(reference, shown[:n], display, centre, F.VIDEO_FPS),
                         foveated_video_jod(reference, shown[n:], display, centre, F.VIDEO_FPS))
    full = scores["full field"]
    print(f"{name}, its middle frame held still, FovVideoVDP at the gaze (frames 0-{F.VIDEO_FRAMES - 1} from cold / "
          f"{F.VIDEO_FRAMES}-{2 * F.VIDEO_FRAMES - 1} converged):")
    for label, (cold, warm) in scores.items():
        diff = "" if label == "full field" else f"   less the full field {cold - full[0]:+.3f} / {warm - full[1]:+.3f}"
        print(f"  {label:30s} {cold:.3f} / {warm:.3f}{diff}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
