"""The guard's trade (issue 44): how many falls below no correction each guard lifts, against how much
of the exact 3 mm gain it keeps, for a range of factors RHO.

For the bench's eye (-2.00/-1.00 x 120) and each ``--rx`` eye, on desktop and quest2, and each
``--image`` (256 px), the default correction (``fast``, the default band, the pupil from the picture's
light at the pupil bank's nearest entry) is seen by the six eyes of issue 44's floor (pupils 2.5, 3, 4,
5.5 mm; the sphere 0.5 D off either way at the light's pupil) and judged with ColorVideoVDP against
none, as ``tools/robust_band_choice.py`` does.  Then each ``--measure`` guards it over those six eyes
(``--guard RHO --guard-measure M`` of ``vrcorrect correct``, with the pupil guards) at each ``--rho``.
Printed per (measure, RHO): the (eye, display, picture) views whose least gain was below -0.05 and
how many the guard lifts to -0.05 or above; the median and least share of the exact 3 mm gain kept
(cases whose exact gain is at least 0.1 JOD); the bench eye's least share on each display; and beside
the JOD, the other two judges: the views some seen eye sees worse than none by FLIP (by more than
0.005) and by the objective (each against the ideal view, as the JOD), with the worst of each.  ``--plot``
draws falls lifted against the median share kept, a line per measure.

    .venv/bin/python tools/guard_tradeoff.py --image a.png --image b.png --rx rx.json --plot trade.png

A study, not a judge: the pictures it is run on are spent for choosing a guard.  Slow: about a minute
per (eye, display, picture) on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from skimage import data as skimage_data

import robust_band_choice as rb  # tools/: this script's folder
from vrcorrect.apps.common import load_eye_and_age
from vrcorrect.physics.robust import design_eye
from vrcorrect.plumbing.errors import VrcorrectError
from vrcorrect.runtime.pupil_bank import nearest_bank_pupil
from vrcorrect.solvers import make_problem, solve
from vrcorrect.solvers.guard import GUARD_MEASURES, guard_blend
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.vision.visibility import ViewingLight

FALL = -0.05          # issue 44's floor: a view below none by more than this falls
SHARE_FROM = 0.1      # a 3 mm share is read only where the exact 3 mm gain is at least this (JOD)
FLIP_FALL = 0.005     # a seen eye's FLIP above none's by more than this counts as worse than none


def picture_arguments(ap: argparse.ArgumentParser) -> None:
    """``--image`` and ``--rx``, as :func:`eyes_and_pictures` reads them."""
    ap.add_argument("--image", action="append", default=[], required=True,
                    help="a picture file, or a scikit-image picture by name (repeatable)")
    ap.add_argument("--rx", action="append", default=[], help="a prescription whose right eye is swept too, at its "
                                                              "age_years (repeatable)")


def _arguments(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="guard_tradeoff", description=__doc__.split("\n\n")[0])
    picture_arguments(ap)
    ap.add_argument("--measure", action="append", choices=GUARD_MEASURES, help="a guard measure (repeatable; "
                                                                               "default visibility and lightness)")
    ap.add_argument("--rho", type=float, nargs="+", default=[1.0, 1.1, 1.25, 1.5, 2.0], help="the guard factors")
    ap.add_argument("--plot", type=Path, help="write the trade as a PNG here")
    ap.add_argument("--force", action="store_true", help="overwrite --plot")
    return ap.parse_args(argv)


def each_case(eyes: list[tuple[str, object, float | None]], names: list[str], displays=rb.DISPLAYS):
    """Each (eye, display, picture) in turn, as robust_band_choice's case: (tag, eye, display name, picture
    name, display, target, the light's pupil, the six seen eyes)."""
    for tag, eye, age in eyes:
        rb._eye.update(eye=eye, age=age)
        rb._cases.clear()
        rb._exact_shown.clear()
        for display_name in displays:
            for name in names:
                yield (tag, eye, display_name, name, *rb._case(display_name, name))


def default_design(eye, display, light_pupil_mm: float):
    """The default's design for the light's pupil: the default band at the pupil bank's nearest entry."""
    return design_eye(eye, display, nearest_bank_pupil(light_pupil_mm), band=None, kernels=rb._kernels, robust=True)


def _cases(images: list[str], eyes: list[tuple[str, object, float | None]]):
    """Each (eye, display, picture): the unguarded correction, the target, the six seen eyes' problems,
    none's JOD, FLIP and objective for each, the exact 3 mm gain, and the unguarded scores."""
    t0 = time.perf_counter()
    for tag, eye, display_name, name, display, target, p, seen in each_case(eyes, images):
        shown = solve(make_design_problem(target, default_design(eye, display, p)), "fast").image
        problems = [make_problem(target, e.nominal, e.nominal_reference) for e, _, _ in seen]
        case = dict(eye=tag, display=display, display_name=display_name, picture=name, shown=shown,
                    target=target, seen=seen, problems=problems, viewing=ViewingLight.of(display),
                    none=rb.seen_metrics(target, target, seen, display, with_jod=False),
                    ceiling=rb.ceiling_of(seen))
        case["scores"] = _scores(shown, case)
        print(f"  {tag:10s} {display_name:8s} {name:20s} least {min(case['scores']['jod']):+.2f}  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        yield case
        t0 = time.perf_counter()


def _scores(image: np.ndarray, case: dict) -> dict[str, list[float]]:
    """What each seen eye sees of ``image`` against none: the JOD gain, the FLIP change (above 0: worse)
    and the objective over none's (each against the ideal view, as the JOD)."""
    seen = rb.seen_metrics(image, case["target"], case["seen"], case["display"])
    return dict(jod=[m.jod - none for m, (_, none, _) in zip(seen, case["seen"])],
                flip=[m.flip - n.flip for m, n in zip(seen, case["none"])],
                objective=[m.objective / n.objective if n.objective > 0 else 1.0 for m, n in zip(seen, case["none"])])


def _guarded_scores(case: dict, measure: str, rho: float, memo: dict) -> tuple[float, dict[str, list[float]]]:
    """The guard's weight and each seen eye's :func:`_scores` of the guarded image (memoised by weight)."""
    done = guard_blend(case["shown"], case["target"], case["problems"], rho, measure, case["viewing"])
    if done.weight >= 1.0:
        return 1.0, case["scores"]
    key = (id(case), round(done.weight, 6))
    if key not in memo:
        memo[key] = _scores(done.image, case)
    return done.weight, memo[key]


def _summary(cases: list[dict], scores_of) -> dict:
    """Falls below -0.05 JOD and how many are lifted, shares of the exact 3 mm gain kept (3 mm is the
    second seen eye), the bench eye's least share per display; beside the JOD, the cases some seen eye
    sees worse than none by FLIP (more than :data:`FLIP_FALL`) and by the objective, with the worst of each."""
    falls = lifted = flip_falls = objective_falls = 0
    shares, bench = [], {}
    worst, flip_worst, objective_worst = np.inf, -np.inf, 0.0
    for case in cases:
        scores = scores_of(case)
        gains = scores["jod"]
        worst = min(worst, min(gains))
        flip_worst = max(flip_worst, max(scores["flip"]))
        flip_falls += max(scores["flip"]) > FLIP_FALL
        objective_worst = max(objective_worst, max(scores["objective"]))
        objective_falls += max(scores["objective"]) > 1.0
        if min(case["scores"]["jod"]) < FALL:
            falls += 1
            lifted += min(gains) >= FALL
        if case["ceiling"] >= SHARE_FROM:
            share = gains[1] / case["ceiling"]
            shares.append(share)
            if case["eye"] == "bench":
                bench[case["display_name"]] = min(bench.get(case["display_name"], np.inf), share)
    return dict(falls=falls, lifted=lifted, median=float(np.median(shares)) if shares else np.nan,
                least=float(min(shares)) if shares else np.nan, bench=bench, worst=float(worst),
                flip_falls=int(flip_falls), flip_worst=float(flip_worst), objective_falls=int(objective_falls),
                objective_worst=float(objective_worst))


def _line(label: str, s: dict) -> str:
    bench = "  ".join(f"{d} {v:4.0%}" for d, v in sorted(s["bench"].items()))
    return (f"{label:24s} falls lifted {s['lifted']:2d} of {s['falls']:2d}  worst {s['worst']:+.2f}  3 mm share kept: "
            f"median {s['median']:4.0%}, least {s['least']:5.0%}  bench eye's least: {bench}  worse than none by "
            f"FLIP {s['flip_falls']} (worst {s['flip_worst']:+.3f}), by the objective {s['objective_falls']} "
            f"(worst x{s['objective_worst']:.2f})")


def eyes_and_pictures(args: argparse.Namespace, prog: str) -> tuple[list, list[str]] | None:
    """The bench's eye and each ``--rx`` file's right eye (tag, eye, age), and each ``--image``'s name (a
    file's stem, registered with robust_band_choice, or a scikit-image picture's); None (said on standard
    error) for a file that cannot be read, a picture that does not exist or is held out, or a ``--plot``
    that exists without ``--force``."""
    plot = getattr(args, "plot", None)
    if plot is not None and plot.exists() and not args.force:
        print(f"{prog}: --plot {plot}: exists (--force to overwrite)", file=sys.stderr)
        return None
    eyes = [("bench", rb.EYE, None)]
    for path in args.rx:
        try:
            _, eye, age = load_eye_and_age(argparse.Namespace(rx=path, eye="right"))
        except (VrcorrectError, OSError) as e:
            print(f"{prog}: --rx {path}: {e}", file=sys.stderr)
            return None
        eyes.append((f"{eye.sphere_D:+.2f}/{eye.accommodation_D:g}D", eye, age))      # sphere / accommodation
    names = []
    for path in args.image:
        name = Path(path).stem
        if name in rb.HELD_OUT:
            print(f"{prog}: --image {path}: held out for vrcorrect bench robust", file=sys.stderr)
            return None
        if Path(path).exists() or Path(path).suffix:
            rb._files[name] = path                          # a picture file
        elif not hasattr(skimage_data, path):               # else a scikit-image picture by name
            print(f"{prog}: --image {path}: no such file, nor a scikit-image picture", file=sys.stderr)
            return None
        try:
            rb.choice_image(name)
        except (VrcorrectError, OSError) as e:
            print(f"{prog}: --image {path}: {e}", file=sys.stderr)
            return None
        names.append(name)
    return eyes, names


def main(argv: list[str]) -> int:
    args = _arguments(argv)
    measures = args.measure or ["visibility", "lightness"]
    if any(not (1.0 <= r <= 10.0) for r in args.rho):
        print("guard_tradeoff: --rho: factors from 1 to 10", file=sys.stderr)
        return 2
    parsed = eyes_and_pictures(args, "guard_tradeoff")
    if parsed is None:
        return 2
    eyes, names = parsed
    print(f"{len(eyes)} eyes x 2 displays x {len(names)} pictures; the default correction, unguarded:", flush=True)
    cases = list(_cases(names, eyes))
    rows = {("none", 0.0): _summary(cases, lambda c: c["scores"])}
    print(_line("unguarded", rows[("none", 0.0)]), flush=True)
    memo: dict = {}
    for measure in measures:
        for rho in args.rho:
            rows[(measure, rho)] = _summary(cases, lambda c: _guarded_scores(c, measure, rho, memo)[1])
            print(_line(f"{measure} {rho:g}", rows[(measure, rho)]), flush=True)
    if args.plot is not None:
        _plot(rows, measures, args.rho, args.plot)
        print(f"wrote {args.plot}")
    return 0


def _plot(rows: dict, measures: list[str], rhos: list[float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    base = rows[("none", 0.0)]
    ax.plot([100 * base["median"]], [base["lifted"]], "ks", label="no guard")
    for measure in measures:
        xs = [100 * rows[(measure, r)]["median"] for r in rhos]
        ys = [rows[(measure, r)]["lifted"] for r in rhos]
        ax.plot(xs, ys, "o-", label=f"--guard-measure {measure}")
        for x, y, r in zip(xs, ys, rhos):
            ax.annotate(f"{r:g}", (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.axhline(base["falls"], color="0.6", ls=":", lw=1)
    ax.set_xlabel("median share of the exact 3 mm gain kept (%)")
    ax.set_ylabel(f"falls lifted to {FALL} JOD or above (of {base['falls']})")
    ax.set_title("The guard's trade: falls lifted against gain kept (labels: RHO)", fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig, path: Path) -> None:
    """Write ``fig`` to ``path`` whole or not at all (through a file beside it), and close it."""
    import matplotlib.pyplot as plt

    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
