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

    .venv/bin/python tools/bars_frontier.py --image rocket --image retina --rx rx.json --plot frontier.png

``--plot`` draws each case's two paths as the 3 mm share against the least seen gain, one panel a case,
with the region where both bars hold shaded.

A study, not a judge; the pictures it is run on should be spent ones (it chooses nothing).  About a
minute and a half per (eye, display, picture) on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import robust_band_choice as rb  # tools/: this script's folder
from guard_tradeoff import default_design, each_case, eyes_and_pictures, picture_arguments, save_figure
from vrcorrect.solvers import solve
from vrcorrect.solvers.problem import make_design_problem

BETAS = tuple(round(b, 2) for b in np.linspace(0.1, 1.0, 10))
SHARE = 0.8           # issue 44: at 3 mm at least 80 % of the exact 3 mm design's gain
FALL = -0.05          # issue 44's floor


def _path(x: np.ndarray, target: np.ndarray, seen, display) -> list[tuple[float, list[float]]]:
    """Each blend's seen gains, from the smallest blend up."""
    return [(b, rb.seen_gains(target + np.float32(b) * (x - target), target, seen, display)) for b in BETAS]


def _keeping(path, ceiling: float) -> list[tuple[float, list[float]]]:
    """The blends of ``path`` that keep :data:`SHARE` of the exact gain at 3 mm (the second seen eye)."""
    return [(b, g) for b, g in path if g[1] >= SHARE * ceiling]


def _verdict(path, ceiling: float) -> str:
    keeping = _keeping(path, ceiling)
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
    ap.add_argument("--plot", type=Path, help="write the paths as a PNG here")
    ap.add_argument("--force", action="store_true", help="overwrite --plot")
    args = ap.parse_args(argv)
    parsed = eyes_and_pictures(args, "bars_frontier")
    if parsed is None:
        return 2
    eyes, names = parsed
    if args.no_bench:
        eyes = eyes[1:]
    conflicts = cases = 0
    panels = []
    for tag, eye, display_name, name, display, target, p, seen in each_case(eyes, names, args.display or rb.DISPLAYS):
        ceiling = rb.ceiling_of(seen)
        if ceiling < 0.1:
            print(f"  {tag:12s} {display_name:8s} {name:22s} exact 3 mm gain {ceiling:+.2f}: no share worth "
                  "reading", flush=True)
            continue
        best = rb.exact_shown(display_name, name)
        default = solve(make_design_problem(target, default_design(eye, display, p)), "fast").image
        exact_path = _path(best, target, seen, display)
        default_path = _path(default, target, seen, display)
        cases += 1
        keeping = _keeping(exact_path, ceiling)
        conflicts += bool(keeping) and min(keeping[0][1]) < FALL
        print(f"  {tag:12s} {display_name:8s} {name:22s} exact 3 mm gain {ceiling:+.2f}", flush=True)
        print(f"      exact 3 mm design: {_verdict(exact_path, ceiling)}", flush=True)
        print(f"      default:           {_verdict(default_path, ceiling)}", flush=True)
        panels.append((f"{tag} {display_name} {name}", ceiling, exact_path, default_path))
    print(f"{conflicts} of {cases} cases: the exact design's blend that keeps 80 % at 3 mm makes a seen eye fall")
    if args.plot is not None and panels:
        _plot(panels, args.plot)
        print(f"wrote {args.plot}")
    return 0


def _plot(panels: list, path: Path) -> None:
    """One panel a case: each path's blends as (3 mm share, least seen gain), the region of both bars shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = min(4, len(panels))
    rows = (len(panels) + columns - 1) // columns
    fig, axes = plt.subplots(rows, columns, figsize=(3.0 * columns, 2.5 * rows), dpi=110, squeeze=False)
    for ax, (title, ceiling, exact_path, default_path) in zip(axes.flat, panels):
        ax.axhline(FALL, color="0.5", lw=0.8, ls=":")
        ax.axvline(100 * SHARE, color="0.5", lw=0.8, ls=":")
        for label, blends, style in (("exact 3 mm design", exact_path, "o-"), ("default", default_path, "s-")):
            xs = [100 * g[1] / ceiling for _, g in blends]
            ys = [min(g) for _, g in blends]
            ax.plot(xs, ys, style, ms=3, lw=1, label=label)
        low, high = ax.get_ylim()
        high = max(high, 0.05)
        ax.fill_between([100 * SHARE, 130], FALL, high, color="0.88", zorder=0)     # both bars hold here
        ax.set_ylim(min(low, FALL - 0.05), high)
        ax.set_title(title, fontsize=8)
        ax.set_xlim(-5, 130)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(panels):]:
        ax.set_axis_off()
    for ax in axes[:, 0]:
        ax.set_ylabel("least seen gain (JOD)", fontsize=7)
    for ax in axes[-1, :]:
        ax.set_xlabel("3 mm share of the exact gain (%)", fontsize=7)
    axes.flat[0].legend(fontsize=6, loc="lower left")
    fig.suptitle("Blends of the picture with each correction, 0.1 to 1 of it;\n shaded: both bars hold "
                 f"(80 % of the exact gain at 3 mm, every seen eye at {FALL} JOD or above)", fontsize=9)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.35 / fig.get_figheight()))      # room for the two-line title
    save_figure(fig, path)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
