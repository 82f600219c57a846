"""Command line: ``vrcorrect <command> ...``.

Library errors (:class:`vrcorrect.plumbing.errors.VrcorrectError`) become one line on
stderr and exit status 2; a command-line user never sees a traceback
(``VRCORRECT_DEBUG=1`` shows it for bug reports).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..plumbing.errors import InputError, ValidationError, VrcorrectError
from ..runtime.model_path import DEFAULT_MODEL, model_for_backend

EXIT_USAGE = 2
EXIT_INTERNAL = 3


def _progress(desc: str):
    """A tqdm progress callback for kernel builds (silent when stderr is not a terminal)."""
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit="PSF", disable=None, leave=False, file=sys.stderr)

    def update(done: int, total: int) -> None:
        bar.update(1)

    update.close = bar.close  # type: ignore[attr-defined]
    return update


def _load_eye(args: argparse.Namespace):
    from ..specs.prescription import bundled_sample_path, load_prescription

    path = Path(args.rx) if args.rx else bundled_sample_path()
    return path, load_prescription(path).eye(args.eye)


def _kernel_options(args: argparse.Namespace):
    from ..physics.kernel import KernelOptions
    from ..physics.optics import OpticsOptions

    distance = None
    if getattr(args, "distance_m", None) is not None:
        distance = math.inf if args.distance_m in ("inf", "infinity") else _positive_float("--distance-m", args.distance_m)
    optics = OpticsOptions(chromatic_aberration=not args.no_lca, viewing_distance_m=distance,
                           reference_wavelength_nm=args.reference_wavelength_nm)
    return KernelOptions(energy_fraction=args.energy_fraction, wavelength_tolerance=args.wavelength_tolerance,
                         wavelength_step_nm=args.wavelength_step_nm, optics=optics)


def _positive_float(field: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValidationError(field, text, "a number of metres or 'inf'") from None
    return value


def _build(args: argparse.Namespace, eye, display):
    from ..physics.kernel import build_kernel

    bar = _progress("building eye kernel")
    try:
        return build_kernel(eye, display, _kernel_options(args), progress=bar)
    finally:
        bar.close()


# ---------------------------------------------------------------- simulate

def cmd_simulate(args: argparse.Namespace) -> int:
    from ..plumbing.fileio import check_readable

    check_readable(args.input)                      # before the heavy imports: a typo is told at once
    from ..specs.display import decode, encode, get_display
    from ..plumbing.fileio import check_writable
    from ..vision.forward import what_the_eye_sees
    from ..plumbing.imageio import read_image, write_png

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    check_writable(out, force=args.force)
    rx_path, eye = _load_eye(args)
    display = get_display(args.display)
    notes: list[str] = []
    image = read_image(args.input, notes)
    _print_notes(notes)
    t0 = time.perf_counter()
    kernel = _build(args, eye, display)
    t1 = time.perf_counter()
    seen, info = what_the_eye_sees(decode(display, image), kernel, method=args.method)
    t2 = time.perf_counter()
    write_png(out, encode(display, seen), bits=16 if args.sixteen_bit else 8, force=args.force)
    if args.explain:
        print(f"prescription {rx_path} ({args.eye} eye): sphere {eye.sphere_D:+.2f} D, cylinder "
              f"{eye.cylinder_D:+.2f} D, axis {eye.axis_deg:g} deg, pupil {eye.pupil_diameter_mm:g} mm")
        print(f"display {display.name} ({display.title}): {display.pixels_per_degree:.1f} pixels per degree, "
              f"transfer {display.transfer}")
        for line in kernel.decisions:
            print(f"  - {line}")
        shortcut = "grey image: exact achromatic shortcut" if info.achromatic else "colour image"
        print(f"  - forward model: {info.path} path, {shortcut}, {info.convolutions} convolution(s) of "
              f"{image.shape[1]}x{image.shape[0]} px")
        print(f"  - time: kernel {t1 - t0:.2f} s, simulation {t2 - t1:.2f} s")
    print(f"wrote {out}: what the {args.eye} eye sees on {display.title}")
    return 0


# ---------------------------------------------------------------- correct

def cmd_correct(args: argparse.Namespace) -> int:
    from ..plumbing.fileio import atomic_paths, check_readable, check_writable

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    check_writable(out, force=args.force)
    if args.report:
        if Path(args.report).suffix.lower() != ".json":
            raise ValidationError("--report", args.report, "a path ending in .json")
        check_writable(Path(args.report), force=args.force)
    if args.iterations is not None and not (1 <= args.iterations <= 100000):
        raise ValidationError("--iterations", args.iterations, "1 to 100000")
    if not (0.0 < args.contrast <= 1.0):
        raise ValidationError("--contrast", args.contrast, "a number in (0, 1]")
    if args.tolerance is not None:
        if args.method not in ("fast", "conventional"):
            raise ValidationError("--tolerance", args.tolerance, "only with --method fast or conventional")
        if not (0.0 <= args.tolerance < 1.0):
            raise ValidationError("--tolerance", args.tolerance, "a number from 0 to 1")
    if args.iterations is not None and args.method in ("wiener", "learned"):
        raise ValidationError("--iterations", args.iterations, f"nothing: {args.method} is one pass")
    if args.model is not None and args.method != "learned":
        raise ValidationError("--model", args.model, "only with --method learned")
    check_readable(args.input)                      # before the heavy imports: a typo is told at once
    from ..specs.display import decode, encode, get_display
    from ..plumbing.imageio import png_writer, read_image
    from ..physics.kernel import build_reference_kernel
    from ..vision.metrics import evaluate_seen
    from ..solvers import make_problem, solve

    learned = _learned_model(args) if args.method == "learned" else None
    rx_path, eye = _load_eye(args)
    display = get_display(args.display)
    if learned is not None:                         # the model's range and display, before any work
        learned.check(eye, display)
    notes: list[str] = []
    image = read_image(args.input, notes)
    _print_notes(notes)
    _check_memory(args.method, *image.shape[:2])
    target = decode(display, image)
    t0 = time.perf_counter()
    kernel = _build(args, eye, display)
    reference = build_reference_kernel(eye, display, _kernel_options(args)) if args.reference == "glasses" else None
    t1 = time.perf_counter()
    problem = make_problem(target, kernel, reference, contrast=args.contrast)
    options: dict = {}
    if args.iterations is not None:
        options["iterations" if args.method == "paper" else "max_iterations"] = args.iterations
    if args.tolerance is not None:
        options["tolerance"] = args.tolerance
    bar = None
    if args.method in ("paper", "fast", "conventional"):
        from tqdm import tqdm

        bar = tqdm(desc=f"{args.method}", unit="it", disable=None, leave=False, file=sys.stderr)
    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()
    try:
        if learned is not None:
            result = _solve_learned(learned, problem, eye, display, kernel, reference)
        else:
            result = solve(problem, args.method, progress=progress, **options)
    finally:
        if bar is not None:
            bar.close()
    outputs = [(out, png_writer(out, encode(display, result.image), bits=16 if args.sixteen_bit else 8))]
    if args.report:
        corrected, _ = evaluate_seen(result.image, target, kernel, display, target_lms=problem.target_lms)
        uncorrected, _ = evaluate_seen(target, target, kernel, display, target_lms=problem.target_lms)
        report = {
            "input": str(args.input), "output": str(out), "prescription": str(rx_path), "eye": args.eye,
            "display": display.name, "method": result.method, "reference": problem.reference,
            "contrast": args.contrast, "iterations": result.iterations,
            "seconds": {"kernel": t1 - t0, "solve": result.seconds},
            "objective": result.objective, "objective_uncorrected": uncorrected.objective,
            "metrics": corrected.__dict__, "metrics_uncorrected": uncorrected.__dict__,
            "settings": result.settings, "kernel_decisions": list(kernel.decisions),
        }
        report_notes = list(notes)                  # what was said about the input, then the JSON repairs
        report = _finite_json(report, "", report_notes)
        if report_notes:
            report["notes"] = report_notes
        text = json.dumps(report, indent=2, default=float, allow_nan=False) + "\n"
        outputs.append((Path(args.report), lambda tmp: tmp.write_text(text, encoding="utf-8")))
    # the image and its report appear together or not at all (an interruption leaves neither)
    with atomic_paths([path for path, _ in outputs], force=args.force) as tmps:
        for (_, writer), tmp in zip(outputs, tmps):
            writer(tmp)
    print(f"wrote {out}: {result.method} correction for the {args.eye} eye on {display.title} "
          f"(objective {result.objective:.3g}, {result.iterations} iterations, {result.seconds:.2f} s)"
          + (f"; report {args.report}" if args.report else ""))
    return 0


def available_memory_bytes() -> float | None:
    """Memory available to a new allocation now (Linux ``MemAvailable``), or None where unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        return None
    return None


def _check_memory(method: str, height: int, width: int) -> None:
    """Refuse, before any work, an image whose correction would not fit in memory (one line)."""
    from ..solvers import PEAK_MEMORY, peak_memory_bytes

    available = available_memory_bytes()
    need = peak_memory_bytes(method, height, width)
    if available is None or need <= 0.9 * available:
        return
    fixed, per_pixel = PEAK_MEMORY[method]
    side = int(math.sqrt(max(0.9 * available - fixed, 0.0) / per_pixel))
    raise ValidationError("input", f"{width}x{height} pixels",
                          f"an image that fits in memory: {method} needs about {need / 2**30:.1f} GiB for it "
                          f"(about {per_pixel:.0f} bytes a pixel), {available / 2**30:.1f} GiB is available now; "
                          f"up to about {side}x{side} here")


def _print_notes(notes: Sequence[str]) -> None:
    for note in notes:
        print(f"vrcorrect: note: {note}", file=sys.stderr)


def _finite_json(value: Any, where: str, notes: list[str]) -> Any:
    """``value`` with every non-finite float replaced by ``None`` (JSON has no Infinity or NaN),
    each replacement explained in ``notes``: ``"metrics.psnr: null (inf: ...)"``."""
    if isinstance(value, dict):
        return {k: _finite_json(v, f"{where}.{k}" if where else str(k), notes) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_json(v, f"{where}[{i}]", notes) for i, v in enumerate(value)]
    if isinstance(value, (float, np.floating)) and not math.isfinite(float(value)):
        why = ("the two images are identical, so the error is zero" if where.endswith("psnr") and value > 0
               else "not a finite number")
        notes.append(f"{where}: null ({float(value)}: {why})")
        return None
    return value


def _learned_model(args: argparse.Namespace):
    """The learned model of ``--model`` (default: the shipped one), its reference checked."""
    from ..runtime.learned import LearnedModel

    path = Path(args.model) if args.model else DEFAULT_MODEL
    if args.model is None and not path.is_file():
        raise InputError(f"no default learned model is installed ({path}); pass --model PATH "
                         "(a model exported by tools/export_onnx.py), or use --method wiener or fast")
    model = LearnedModel(path)
    if model.reference != args.reference:
        raise ValidationError("--reference", args.reference, f"{model.reference} (the target {path.name} was "
                              "trained for)")
    return model


def _solve_learned(model, problem, eye, display, kernel, reference):
    """``--method learned``: the model bound to this eye (refused outside its range), one pass."""
    from ..solvers import SolveResult, objective

    bound = model.for_eye(eye, display, kernel, reference)
    t0 = time.perf_counter()
    chw = bound.infer(np.ascontiguousarray(np.moveaxis(problem.target, 2, 0)))
    seconds = time.perf_counter() - t0
    image = np.ascontiguousarray(np.moveaxis(chw, 0, 2))
    settings = {"model": str(model.path), "providers": list(model.providers),
                "ranges": model.ranges.as_dict(), "version": model.metadata.get("vrcorrect.version")}
    return SolveResult(image=image, method="learned", seconds=seconds, iterations=0,
                       objective=objective(image, problem), settings=settings)


# ---------------------------------------------------------------- psf

def cmd_psf(args: argparse.Namespace) -> int:
    import numpy as np

    from ..specs.display import get_display
    from ..plumbing.fileio import atomic_paths, check_writable
    from ..physics.kernel import monochromatic_psf

    out = Path(args.output)
    if out.suffix.lower() != ".npy":
        raise ValidationError("--output", str(out), "a path ending in .npy")
    sidecar = out.with_suffix(".json")
    if args.png and Path(args.png).suffix.lower() != ".png":
        raise ValidationError("--png", args.png, "a path ending in .png")
    check_writable(out, force=args.force)
    check_writable(sidecar, force=args.force)
    if args.png:
        check_writable(Path(args.png), force=args.force)
    rx_path, eye = _load_eye(args)
    if sidecar.resolve() == rx_path.resolve():
        raise ValidationError("--output", str(out), f"a name whose .json sidecar is not the prescription {rx_path}")
    display = get_display(args.display)
    options = _kernel_options(args)
    meta: dict = {"prescription": str(rx_path), "eye": args.eye, "display": display.name,
                  "pixels_per_degree": display.pixels_per_degree,
                  "reference_wavelength_nm": options.optics.reference_wavelength_nm,
                  "chromatic_aberration": options.optics.chromatic_aberration,
                  "energy_fraction": options.energy_fraction}
    if args.wavelength_nm is not None:
        psf, full, state = monochromatic_psf(eye, display, args.wavelength_nm, options)
        array = psf
        meta.update(kind="monochromatic PSF", axes=["y (rows, down the display)", "x (columns, to the right)"],
                    wavelength_nm=args.wavelength_nm, wavelengths_nm=[args.wavelength_nm],
                    kernel_size=int(psf.shape[0]), sum=float(psf.sum()),
                    fft_grid=full.sampling.grid, fine_samples_per_pixel=full.sampling.oversample)
    else:
        kernel = _build(args, eye, display)
        array = kernel.kernel
        meta.update(kind="LMS kernel K[cone, primary, y, x]", axes=["cone (L, M, S)", "primary (R, G, B)",
                    "y (rows, down the display)", "x (columns, to the right)"],
                    kernel_size=kernel.size, wavelengths_nm=list(kernel.node_wavelengths_nm),
                    wavelength_step_nm=kernel.wavelength_step_nm, identity=kernel.identity,
                    rgb_to_lms=kernel.matrix.tolist(), decisions=list(kernel.decisions))
    def save_array(tmp: Path) -> None:
        with tmp.open("wb") as f:
            np.save(f, array)

    text = json.dumps(meta, indent=2) + "\n"
    outputs = [(out, save_array), (sidecar, lambda tmp: tmp.write_text(text, encoding="utf-8"))]
    if args.png:
        from .plots import plot_psf

        outputs.append((Path(args.png), lambda tmp: plot_psf(array, meta, tmp)))
    with atomic_paths([path for path, _ in outputs], force=args.force) as tmps:   # all or nothing
        for (_, writer), tmp in zip(outputs, tmps):
            writer(tmp)
    print(f"wrote {out} ({'x'.join(map(str, array.shape))}) and {sidecar}" + (f" and {args.png}" if args.png else ""))
    return 0


# ---------------------------------------------------------------- rx

def cmd_rx_new(args: argparse.Namespace) -> int:
    from ..specs.prescription import write_template

    write_template(Path(args.path), force=args.force)
    print(f"wrote {args.path}: a commented prescription template; fill in both eyes, then run "
          f"'vrcorrect rx validate {args.path}'")
    return 0


def cmd_rx_validate(args: argparse.Namespace) -> int:
    from ..specs.prescription import validate_file

    problems = validate_file(Path(args.path))
    if problems:
        print(f"{args.path}: {len(problems)} problem{'s' if len(problems) != 1 else ''}:", file=sys.stderr)
        for p in problems:
            print(f"  - {p}", file=sys.stderr)
        return 1
    from ..specs.prescription import load_prescription

    rx = load_prescription(Path(args.path))
    print(f"{args.path}: valid")
    for name in ("right", "left"):
        e = rx.eye(name)
        pv = e.power_vector()
        print(f"  {name:5s} {e.sphere_D:+.2f} / {e.cylinder_D:+.2f} x {e.axis_deg:g}, pupil {e.pupil_diameter_mm:g} mm"
              f"  (M {pv.M_D:+.2f}, J0 {pv.J0_D:+.2f}, J45 {pv.J45_D:+.2f} D)")
    return 0


# ---------------------------------------------------------------- displays

def cmd_displays(args: argparse.Namespace) -> int:
    from .bench import markdown_table
    from ..specs.display import get_display, preset_names

    if args.fit:
        return _displays_fit(args)
    if args.plot:
        raise ValidationError("--plot", args.plot, "only together with --fit SPECTRA.csv")
    rows = []
    for name in preset_names():
        d = get_display(name)
        dist = "inf" if math.isinf(d.distance_m) else f"{d.distance_m:.2f}"
        res = "x".join(map(str, d.resolution_px)) if d.resolution_px else "-"
        ph = d.photometry
        rows.append([name, d.title, d.kind, f"{d.pixels_per_degree:.1f}", dist, res, d.transfer,
                     f"{ph.peak_luminance_cd_m2:g}", f"{ph.contrast:g}:1", f"{ph.ambient_lux:g}"])
    print(markdown_table(["preset", "display", "kind", "px/deg", "distance m", "resolution", "transfer",
                          "peak cd/m²", "contrast", "ambient lux"], rows))
    if args.verbose:
        for name in preset_names():
            d = get_display(name)
            print(f"\n{name}: {d.sources}\n  Photometry ({d.photometry.describe()}): {d.photometry.sources}")
    else:
        print("\n(sources and estimates: vrcorrect displays -v)")
    return 0


def _displays_fit(args: argparse.Namespace) -> int:
    from ..specs.display import fit_spectra, read_spectra_csv
    from ..plumbing.fileio import check_writable

    if args.plot:
        if Path(args.plot).suffix.lower() != ".png":
            raise ValidationError("--plot", args.plot, "a path ending in .png")
        check_writable(Path(args.plot), force=args.force)
    measured = read_spectra_csv(Path(args.fit))
    fit = fit_spectra(measured)
    print(f"{args.fit}: {len(measured.wavelength_nm)} samples, "
          f"{measured.wavelength_nm[0]:.0f}-{measured.wavelength_nm[-1]:.0f} nm")
    for label, rms, mx in zip(measured.labels, fit.rms_error, fit.max_error):
        print(f"  {label:6s} smooth non-negative fit: rms error {rms * 100:.2f}% of peak, max {mx * 100:.2f}%")
    if args.plot:
        from ..plumbing.fileio import write_with
        from .plots import plot_spectra_fit

        write_with(Path(args.plot), lambda tmp: plot_spectra_fit(measured, fit, tmp), force=args.force)
        print(f"wrote {args.plot}")
    return 0


# ---------------------------------------------------------------- demo

def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    for line in run_demo(Path(args.out), display_name=args.display, force=args.force):
        print(line)
    return 0


# ---------------------------------------------------------------- render

def cmd_render(args: argparse.Namespace) -> int:
    from ..plumbing.fileio import check_readable, check_writable
    from ..plumbing.imageio import read_image, write_png
    from ..specs.prescription import bundled_sample_path, load_prescription
    from ..runtime.mirror import filter_options, parse_frames
    from ..runtime.render import MAX_FRAMES, SETTLED_FRAMES, render_frame

    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise ValidationError("--output", str(out), "a path ending in .png")
    options = {"kernel_options": _kernel_options(args), **filter_options(args)}
    frames = parse_frames(args.frames, "--frames", MAX_FRAMES)
    if frames is None:
        frames = SETTLED_FRAMES if args.backend == "glsl" and options["filter"] == "fista" else 1
    check_readable(args.input)
    check_writable(out, force=args.force)
    model = model_for_backend(args.backend, args.model)
    rx_path = args.rx or str(bundled_sample_path())
    rx = load_prescription(rx_path)
    notes: list[str] = []
    image = read_image(args.input, notes)
    _print_notes(notes)
    if model:
        options["model"] = model
    from tqdm import tqdm

    with tqdm(total=frames, desc="render", unit="frame", disable=None, leave=False, file=sys.stderr) as bar:
        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()

        result, info = render_frame(image, rx, args.display, args.eye, args.backend, view=args.view,
                                    frames=frames, progress=progress, **options)
    write_png(out, result / 255.0, bits=8, force=args.force)
    print(f"{info['renderer']}: {args.eye} eye, sphere {info['sphere_D']:+.2f} D, cylinder {info['cylinder_D']:+.2f} D, "
          f"axis {info['axis_deg']:g} deg on {info['display']}; backend {info['backend']}")
    fraction = info.get("objective_fraction")
    if args.backend == "glsl" and info["filter"] == "fista":
        print(f"  projected gradient (FISTA), {info.get('iterations_per_frame', '-')} iteration(s) per frame, "
              f"{frames} frame(s) warm-started, FFT margin {info['margin']} px"
              + (f"; last frame's objective {fraction:.3f} of uncorrected" if fraction is not None else ""))
    elif args.backend == "glsl" and "ranks" in info:
        print(f"  separable filters {info['filter_size']} px, ranks {info['ranks']} ({info['taps_per_pixel']} "
              f"taps/pixel), regulariser {info['mu_rel']:g}, blend {info['beta']:.3f}")
    elif args.backend == "glsl":
        print(f"  FFT filter, margin {info['margin']} px, regulariser {info['mu_rel']:g}, blend {info['beta']:.3f}")
    for note in info["notes"]:
        print(f"  - {note}")
    per = f", {1e3 * info['frame_s'] / frames:.1f} ms per frame" if frames > 1 else ""
    print(f"  build {info['build_s']:.2f} s, {frames} frame(s) {1e3 * info['frame_s']:.1f} ms{per} "
          "(incl. upload and read-back)")
    print(f"wrote {out} ({info['view']})")
    return 0


# ---------------------------------------------------------------- bench

def cmd_bench(args: argparse.Namespace) -> int:
    if args.what == "kernel":
        from .bench.kernel import run_kernel_bench

        print(run_kernel_bench(repeats=args.repeats, out=Path(args.out), write=not args.no_write))
    elif args.what == "solvers":
        from .bench.solvers import RESOLUTIONS, run_solver_bench

        res = args.resolutions or list(RESOLUTIONS)
        for r in res:
            if r not in RESOLUTIONS:
                raise ValidationError("--resolutions", r, "some of " + ", ".join(RESOLUTIONS))
        print(run_solver_bench(out=Path(args.out), plot=Path(args.out).with_name("solver_tradeoff.png"),
                               resolutions=res, repeats=args.repeats, write=not args.no_write))
    elif args.what == "render":
        from .bench.render import run_render_bench

        print(run_render_bench(repeats=args.repeats, out=Path(args.out), write=not args.no_write))
    elif args.what == "xr":
        from .bench.xr import run_xr_bench

        print(run_xr_bench(repeats=args.repeats, out=Path(args.out), write=not args.no_write))
    elif args.what == "realtime":
        from .bench.realtime import run_realtime_bench

        print(run_realtime_bench(out=Path(args.out), write=not args.no_write, quick=args.quick))
    elif args.what == "learned":
        from .bench.learned import run_learned_bench

        path = Path(args.model) if args.model else DEFAULT_MODEL
        if not path.is_file():
            raise InputError(f"{path}: no such model; pass --model PATH (a model exported by tools/export_onnx.py)")
        if args.eyes < 1:
            raise ValidationError("--eyes", args.eyes, "at least 1")
        print(run_learned_bench(path, out=Path(args.out), card=Path(args.card) if args.card else None,
                                eyes=args.eyes, repeats=max(args.repeats, 3), write=not args.no_write,
                                plot=Path(args.out).with_name("learned_heldout.png"),
                                tradeoff=Path(args.out).with_name("learned_tradeoff.png"))["markdown"])
    else:
        raise ValidationError("bench", args.what, "kernel, solvers, render, realtime, xr or learned")
    return 0


# ---------------------------------------------------------------- parser

def _add_model_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rx", metavar="RX.json", help="prescription file (default: the bundled sample)")
    p.add_argument("--eye", choices=("right", "left"), default="right", help="which eye (default right)")
    p.add_argument("--display", default="quest2", metavar="PRESET",
                   help="display preset or profile .json (default quest2; list: vrcorrect displays)")
    g = p.add_argument_group("model")
    g.add_argument("--no-lca", action="store_true", help="leave out the eye's longitudinal chromatic aberration")
    g.add_argument("--distance-m", metavar="M",
                   help="viewing distance in metres, or 'inf' for the paper's setting (default: the display's)")
    g.add_argument("--reference-wavelength-nm", type=float, default=555.0,
                   help="wavelength at which the prescription holds (default 555)")
    g.add_argument("--energy-fraction", type=float, default=0.995,
                   help="fraction of PSF energy the kernel keeps (default 0.995)")
    g.add_argument("--wavelength-tolerance", type=float, default=1 / 255,
                   help="accepted error of the wavelength step against 1 nm (default 1/255)")
    g.add_argument("--wavelength-step-nm", type=int, choices=(80, 40, 20, 10, 5, 1),
                   help="force a wavelength step instead of choosing one")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="vrcorrect", description=(
        "Pre-correct displays for eyes that need glasses (ChromaCorrect: display spectra, Zernike PSFs per "
        "wavelength, cone responses)."))
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("simulate", help="what an eye sees of an image on a display")
    p.add_argument("input", metavar="IN", help="image file (PNG, JPEG, ...; sRGB code values)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.png")
    _add_model_options(p)
    p.add_argument("--method", choices=("auto", "fft", "direct"), default="auto", help="convolution path")
    p.add_argument("--explain", action="store_true", help="print every modelling decision")
    p.add_argument("--16bit", dest="sixteen_bit", action="store_true", help="write a 16-bit PNG")
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("correct", help="pre-correct an image for an eye (the displayed image)")
    p.add_argument("input", metavar="IN", help="image file (sRGB code values)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.png")
    _add_model_options(p)
    p.add_argument("--method", choices=("conventional", "paper", "fast", "wiener", "learned"), default="fast",
                   help="correction method (default fast)")
    p.add_argument("--model", metavar="MODEL.onnx",
                   help="learned: the exported model (default: models/default.onnx when shipped)")
    p.add_argument("--iterations", type=int, help="iterations (paper) or iteration limit (fast, conventional)")
    p.add_argument("--tolerance", type=float, help="fast, conventional: relative stopping tolerance")
    p.add_argument("--contrast", type=float, default=1.0, help="scale the target's contrast (0, 1] (default 1)")
    p.add_argument("--reference", choices=("glasses", "ideal"), default="glasses",
                   help="target: what the eye sees with glasses (default) or the paper's blur-free A t")
    p.add_argument("--report", metavar="REPORT.json", help="write metrics, timings and settings")
    p.add_argument("--16bit", dest="sixteen_bit", action="store_true", help="write a 16-bit PNG")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_correct)

    from .evaluate import add_parser as add_evaluate_parser

    add_evaluate_parser(sub)

    from .acuity_chart import add_parser as add_acuity_parser

    add_acuity_parser(sub)

    from .learning import add_parser as add_learn_parsers

    add_learn_parsers(sub)

    p = sub.add_parser("psf", help="write an eye's PSF (one wavelength) or full LMS kernel as .npy + .json")
    _add_model_options(p)
    p.add_argument("--wavelength-nm", type=float, help="monochromatic PSF at this wavelength (default: full kernel)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.npy")
    p.add_argument("--png", metavar="PLOT.png", help="also draw it")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_psf)

    p = sub.add_parser("rx", help="prescription files")
    rsub = p.add_subparsers(dest="rx_command", metavar="ACTION")
    rsub.required = True
    q = rsub.add_parser("new", help="write a commented prescription template")
    q.add_argument("path", metavar="PATH")
    q.add_argument("--force", action="store_true", help="overwrite PATH if it exists")
    q.set_defaults(func=cmd_rx_new)
    q = rsub.add_parser("validate", help="check a prescription file and report every problem")
    q.add_argument("path", metavar="PATH")
    q.set_defaults(func=cmd_rx_validate)

    p = sub.add_parser("displays", help="list display presets, or fit measured spectra")
    p.add_argument("-v", "--verbose", action="store_true", help="show each preset's sources")
    p.add_argument("--fit", metavar="SPECTRA.csv", help="fit a measured wavelength_nm,r,g,b CSV and report the error")
    p.add_argument("--plot", metavar="FIT.png", help="with --fit: draw the fit")
    p.add_argument("--force", action="store_true", help="overwrite the plot if it exists")
    p.set_defaults(func=cmd_displays)

    p = sub.add_parser("demo", help="the bundled default: what the sample eyes see of the sample image")
    p.add_argument("--out", default="out", help="output folder (default ./out)")
    p.add_argument("--display", default="quest2", metavar="PRESET")
    p.add_argument("--force", action="store_true", help="overwrite earlier demo outputs")
    p.set_defaults(func=cmd_demo)

    from ..runtime.mirror import add_filter_options

    p = sub.add_parser("render", help="frames through the real-time GL pipeline (headless EGL), the last written")
    p.add_argument("input", help="image (PNG/JPEG, sRGB)")
    p.add_argument("-o", "--output", required=True, help="output PNG")
    _add_model_options(p)
    p.add_argument("--backend", choices=("glsl", "onnx"), default="glsl", help="correction backend (default glsl)")
    p.add_argument("--model", metavar="MODEL.onnx", help="ONNX model for --backend onnx")
    add_filter_options(p)
    p.add_argument("--frames", metavar="N",
                   help="run N frames of the input as a still video and write the last; with --filter fista each "
                        "frame continues the last one's iterations (default: 10 with fista, a still view settled "
                        "after a tenth of a second at 90 Hz; 1 with the one-pass filters and the onnx backend)")
    p.add_argument("--view", choices=("corrected", "seen-corrected", "seen-uncorrected"), default="corrected",
                   help="the displayed image (default) or what the eye sees of it")
    p.add_argument("--force", action="store_true", help="overwrite the output")
    p.set_defaults(func=cmd_render)

    from ..runtime.mirror import add_parser as add_mirror_parser

    add_mirror_parser(sub)

    from ..runtime.overlay import add_parser as add_overlay_parser

    add_overlay_parser(sub)

    from ..runtime.xr import add_parser as add_xr_parser

    add_xr_parser(sub)

    p = sub.add_parser("bench", help="benchmarks: print a table and write docs/benchmarks.md")
    p.add_argument("what", choices=("kernel", "solvers", "render", "realtime", "xr", "learned"),
                   help="what to measure")
    p.add_argument("--repeats", type=int, default=3, help="timed runs per case (median reported)")
    p.add_argument("--resolutions", nargs="+", metavar="R",
                   help="solvers: image sizes to sweep (256 512 1024 1832x1920; default all)")
    p.add_argument("--out", default="docs/benchmarks.md", help="benchmarks file to update")
    p.add_argument("--no-write", action="store_true", help="print only")
    p.add_argument("--model", metavar="MODEL.onnx", help="learned: the model (default models/default.onnx)")
    p.add_argument("--card", metavar="CARD.md", help="learned: also write the model card there")
    p.add_argument("--eyes", type=int, default=6, help="learned: held-out eyes (default 6)")
    p.add_argument("--quick", action="store_true", help="realtime: fewer frames and sizes (a smoke run)")
    p.set_defaults(func=cmd_bench)
    return ap


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwinds like Ctrl-C, so every ``finally`` (temporary files, GL
    and OpenXR objects) runs and no partial output is left."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated(signum)


@contextlib.contextmanager
def _terminate_like_interrupt():
    """Treat SIGTERM and SIGHUP as Ctrl-C for the duration of a command (main thread only)."""
    names = [n for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n)]
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {n: signal.signal(getattr(signal, n), _raise_terminated) for n in names}
    try:
        yield
    finally:
        for n, handler in old.items():
            signal.signal(getattr(signal, n), handler)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with _terminate_like_interrupt():
            return int(args.func(args) or 0)
    except Terminated as exc:
        name = signal.Signals(exc.signum).name
        print(f"vrcorrect: terminated ({name})", file=sys.stderr)
        return 128 + exc.signum
    except VrcorrectError as exc:
        print(f"vrcorrect: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("vrcorrect: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print("vrcorrect: error: out of memory; try a smaller image or pupil", file=sys.stderr)
        return EXIT_INTERNAL
    except Exception as exc:  # never a traceback for a command-line user
        if os.environ.get("VRCORRECT_DEBUG"):
            raise
        print(f"vrcorrect: internal error: {type(exc).__name__}: {exc} (set VRCORRECT_DEBUG=1 for details)",
              file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
