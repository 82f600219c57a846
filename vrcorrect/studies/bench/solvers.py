"""``vrcorrect bench solvers``: the speed-accuracy trade of the correction methods.

Each case runs in its own process so that its peak memory (max RSS, less the
same process's RSS before solving) is its own.  The objective gap is measured
against the best known optimum for that image and eye: ``fast`` run to a tight
tolerance.  Solutions computed with a cheaper kernel (smaller energy fraction,
coarser wavelength step) are scored with the default kernel, so the gap shows
what the cheaper model costs.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from statistics import median

from tqdm import tqdm

from ..plots import pyplot, save_figure
from ...specs.vocabulary import Method
from . import machine_description, markdown_table, write_section

RESOLUTIONS = {"256": (256, 256), "512": (512, 512), "1024": (1024, 1024), "1832x1920": (1920, 1832)}

_WORKER = r"""
import json, math, resource, sys, time
import numpy as np
from skimage import data, transform
from vrcorrect.specs.display import decode, get_display
from vrcorrect.physics.kernel import KernelOptions, build_kernel
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.specs.prescription import EyeRx
from vrcorrect.solvers import make_problem, objective, solve
case = json.loads(sys.argv[1])
d = get_display(case["display"])
eye = EyeRx(sphere_D=case["sphere_D"], cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0)
inf = OpticsOptions(viewing_distance_m=math.inf)
k_true = build_kernel(eye, d, KernelOptions(optics=inf))
k_solve = build_kernel(eye, d, KernelOptions(optics=inf, energy_fraction=case.get("energy_fraction", 0.995),
                                             wavelength_step_nm=case.get("wavelength_step_nm")))
h, w = case["shape"]
img = data.astronaut()
img = transform.resize(img, (h, w), anti_aliasing=True).astype(np.float32)
target = decode(d, img)
p_true = make_problem(target, k_true)
p_solve = make_problem(target, k_solve)
if case["method"] in ("fast", "paper", "conventional"):
    import torch  # imported before the baseline so it is not counted as the method's memory
    torch.set_num_threads(2)
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
r = solve(p_solve, case["method"], **case.get("options", {}))
rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
from vrcorrect.vision.metrics import evaluate_seen
seen, _ = evaluate_seen(r.image, target, k_true, d, target_lms=p_true.target_lms)
print(json.dumps({"jod": seen.jod, "flip": seen.flip, "seconds": r.seconds, "iterations": r.iterations, "objective": objective(r.image, p_true),
                  "objective_none": objective(target, p_true), "kernel_size": k_solve.size,
                  "wavelength_step_nm": k_solve.wavelength_step_nm, "peak_mib": (rss1 - rss0) / 1024}))
"""


def _run(case: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", _WORKER, json.dumps(case)], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"benchmark case {case} failed: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _cases(resolutions: list[str]) -> list[tuple[str, str, dict]]:
    """(group, label, case) for every measured setting."""
    base = {"display": "desktop", "sphere_D": -1.5}
    cases = []
    for res in resolutions:
        shape = RESOLUTIONS[res]
        for method, label, options in (("none", "uncorrected", {}), ("wiener", "wiener", {}),
                                       ("fast", "fast (default)", {}),
                                       ("paper", "paper (100 it)", {}),
                                       ("conventional", "conventional", {})):
            if method == "conventional" and res == "1832x1920":
                options = {"max_iterations": 100}
                label = "conventional (100 it)"
            cases.append((f"resolution {res}", label, {**base, "shape": shape, "method": method, "options": options}))
    shape = RESOLUTIONS["512"]
    for n in (10, 25, 50, 200):
        cases.append(("iterations", f"paper ({n} it)", {**base, "shape": shape, "method": "paper",
                                                        "options": {"iterations": n}}))
    for tol in (3e-3, 1e-3, 1e-4):
        cases.append(("iterations", f"fast (tol {tol:g})", {**base, "shape": shape, "method": "fast",
                                                            "options": {"tolerance": tol}}))
    cases.append(("iterations", "fast (no coarse start)", {**base, "shape": shape, "method": "fast",
                                                           "options": {"levels": 0}}))
    for frac in (0.95, 0.99, 0.999):
        cases.append(("kernel energy", f"fast, {frac * 100:g}% energy", {**base, "shape": shape, "method": "fast",
                                                                           "energy_fraction": frac}))
    for step in (40, 20, 5):
        cases.append(("wavelength step", f"fast, {step} nm step", {**base, "shape": shape, "method": "fast",
                                                                     "wavelength_step_nm": step}))
    return cases


def run_solver_bench(out: Path = Path("docs/benchmarks.md"), plot: Path = Path("docs/solver_tradeoff.png"),
                     resolutions: list[str] | None = None, repeats: int = 3, write: bool = True,
                     progress: bool = True) -> str:
    """Measure every case (median of ``repeats`` runs for the timings) and return the Markdown."""

    resolutions = resolutions or list(RESOLUTIONS)
    best: dict[tuple, float] = {}
    rows, points = [], []
    cases = _cases(resolutions)
    bar = tqdm(total=len(cases), desc="bench solvers", unit="case", disable=None if progress else True,
               file=sys.stderr)
    for group, label, case in cases:
        key = (tuple(case["shape"]), case["display"], case["sphere_D"])
        if key not in best:
            ref = _run({**case, "method": "fast", "options": {"tolerance": 1e-6, "max_iterations": 300},
                        "energy_fraction": 0.995, "wavelength_step_nm": None})
            best[key] = ref["objective"]
        big = case["shape"][0] * case["shape"][1] > 600_000
        runs = [_run(case) for _ in range(1 if case["method"] == Method.NONE or big else repeats)]
        res = runs[-1]
        secs = median(r["seconds"] for r in runs)
        gap = (res["objective"] - best[key]) / best[key]
        rows.append([group, label, f"{case['shape'][1]}x{case['shape'][0]}", f"{secs:.3f}", str(res["iterations"]),
                     f"{res['peak_mib']:.0f}", f"{res['jod']:.3f}", f"{res['flip']:.4f}", f"{res['objective']:.6f}",
                     f"{gap:.2e}", str(res["kernel_size"]),
                     f"{res['wavelength_step_nm']} nm"])
        points.append((group, label, case, secs, gap, res))
        bar.update(1)
    bar.close()

    # headline ratios at 512^2
    at512 = {p[1]: p for p in points if p[0] == "resolution 512"}
    lines = []
    if "paper (100 it)" in at512 and "fast (default)" in at512:
        fp, pp = at512["fast (default)"], at512["paper (100 it)"]
        lines.append(f"- fast vs paper at 512x512: objective {fp[5]['objective']:.6f} vs {pp[5]['objective']:.6f} "
                     f"({'lower or equal' if fp[5]['objective'] <= pp[5]['objective'] else 'HIGHER'}), time "
                     f"{fp[3]:.3f} s vs {pp[3]:.3f} s: **{pp[3] / fp[3]:.1f}x faster** (target >= 10x, aim 50x)")
    if "uncorrected" in at512:
        none = at512["uncorrected"][5]
        for label in ("wiener", "fast (default)", "paper (100 it)", "conventional"):
            if label in at512:
                r = at512[label][5]
                lines.append(f"- {label} vs uncorrected at 512x512: JOD {r['jod']:.3f} vs {none['jod']:.3f} "
                             f"({r['jod'] - none['jod']:+.3f}), FLIP {r['flip']:.4f} vs {none['flip']:.4f}, "
                             f"objective {r['objective']:.6f} vs {none['objective']:.6f}")
    body = ("## Correction methods: the speed-accuracy trade\n\n"
            f"Machine: {machine_description()}.\n"
            "Case: scikit-image astronaut, desktop preset (44.9 px/deg), -1.50 D myopia, 4 mm pupil, optical "
            "infinity, paper's ideal target (A t). Seconds: median of "
            f"{repeats} runs (one run at 1024x1024 and 1832x1920), each in its own process (`vrcorrect bench solvers`). Peak MiB: growth of the "
            "process's peak RSS during the solve. Gap: (objective - best) / best, best = fast run to "
            "tolerance 1e-6 (at most 300 iterations); every solution is scored with the default kernel (99.5% energy, chosen "
            "wavelength step). JOD (ColorVideoVDP, higher is better, 10 = identical) and FLIP score what the eye "
            "sees of each solution against the target, on the desktop's viewing conditions.\n\n"
            + "\n".join(lines) + "\n\n"
            + markdown_table(["group", "method / setting", "size", "seconds", "iterations", "peak MiB",
                              "JOD ↑", "FLIP ↓", "objective", "gap", "kernel px", "wavelength step"], rows)
            + f"\n\n![objective gap vs seconds]({plot.name})\n")
    if write:
        _plot(points, plot)
        write_section(out, "solvers", body)
    return body


def _plot(points, path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    colours = {"wiener": "tab:green", "fast": "tab:blue", "paper": "tab:orange", "conventional": "tab:red",
               "none": "grey"}
    for group, label, case, secs, gap, res in points:
        if group.startswith("resolution") and group != "resolution 512":
            continue
        ax.scatter(max(secs, 1e-4), max(gap, 1e-6), color=colours[case["method"]], s=25)
        ax.annotate(label, (max(secs, 1e-4), max(gap, 1e-6)), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("seconds (512x512, median)")
    ax.set_ylabel("relative objective gap to best known optimum")
    ax.set_title("Correction methods: speed vs accuracy (-1.5 D, desktop)")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
