"""The held-out clips of ``vrcorrect bench fovea --video`` with another periphery than the default
(issue 45; docs/realtime.md, "Correct where the eye looks").

The default window (15 deg, the periphery a quarter-resolution correction, 2 iterations a frame) is
0.24 JOD under the full field at the gaze on the sliding colour wheel (``sprite``), more than the
issue's 0.2.  This plays a clip with the periphery given and prints the same figures as the bench's
video table (FovVideoVDP fixating the window's centre and 10 deg off):

    .venv/bin/python tools/fovea_clip_periphery.py                  # sprite, half resolution
    .venv/bin/python tools/fovea_clip_periphery.py sprite quarter   # the bench's own setting

About 7-12 min a clip on the dev machine (2-core AMD EPYC, 2026-11-29, beside a CI run), which printed
for ``sprite`` with the periphery at half resolution (1 iteration a frame, 0.70 GB a Quest 2 eye
frame): none 9.14, full 9.77, foveated 9.59 at the gaze (-0.18); 10 deg off 74 % of the full field's
gain.  With the default quarter (the bench): -0.24 and 62 %.  Those runs predate the foveated cold
frames' own iterations: most of the loss beyond a still's was the cold start's first five frames,
which the periphery's resolution does not touch (``tools/fovea_cold_start.py``).
"""

from __future__ import annotations

import sys
import time

from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.specs.display import get_display
from vrcorrect.studies.bench import fovea as F


def main(argv: list[str]) -> int:
    clip = argv[0] if argv else "sprite"
    periphery = argv[1] if len(argv) > 1 else "half"
    display = get_display("quest2")
    K, R = build_kernel(F.EYE, display), build_reference_kernel(F.EYE, display)
    t0 = time.perf_counter()
    for v in F.video_cases(display, K, R, F.VIEW, F.VIDEO_FRAMES, clips=(clip,), periphery=periphery):
        n, full, fov = v["none"], v["full"], v["foveated"]
        gain = full["off"] - n["off"]
        share = f"{100 * (fov['off'] - n['off']) / gain:.0f} %" if gain > 1e-9 else "-"
        print(f"{v['clip']}, periphery {periphery}: none {n['centre']:.2f}, full {full['centre']:.2f}, foveated "
              f"{fov['centre']:.2f} at the gaze ({fov['centre'] - full['centre']:+.2f}); {F.OFF_DEG:g} deg off "
              f"{share} of the full field's gain; FLIP {n['flip']:.3f} / {full['flip']:.3f} / {fov['flip']:.3f} "
              f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
