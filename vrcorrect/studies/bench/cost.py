"""``vrcorrect bench cost``: what one real-time frame costs a GPU, counted from the passes that run it.

Each eye of the prescription gets a :class:`~vrcorrect.runtime.corrector.Corrector` at the stated
size; after warm-up frames, a :class:`~vrcorrect.runtime.dispatch.CostLedger` is attached and one
more frame runs.  Every pass goes through :class:`~vrcorrect.runtime.dispatch.Gpu`, which binds what
the pass names and counts its bytes (each texel of a bound resource read or written once), so the
figures are the code's, not a formula written beside it.

* **The budget case**: content that changes every frame (a new picture each frame, the warm start
  carried over): the most a frame costs.
* **A cold frame**: the first frame of a shot (a cut, the first frame, a new prescription), where the
  default starts from ``cold_iterations`` iterations at half resolution: counted on the first frame.
* **A converged still view**: the same picture frame after frame, once the early stop's plan gives
  the passes no work (the GPU decides that when two frames' objectives agree to 1e-3: 17 frames for
  a 64 px photograph, ``tests/test_runtime_admm.py``); counted as the plan leaves it (the decode, the
  plan and the present), without running the frames until then.
* **Projections**: milliseconds per eye at the published peak memory bandwidth of three GPUs
  (:data:`~vrcorrect.runtime.dispatch.BANDWIDTHS`): a frame of these passes cannot be faster than
  that; real code reaches some fraction of the peak (on an H100 the default's passes reached 5-12 %
  of it, docs/realtime.md).  They are projections, not measurements.
* **Measured**: the frame's wall time on whatever renderer the context has (``GL_RENDERER`` is
  reported beside it), after ``WARM_UP_S`` seconds of untimed frames so that a GPU's clocks have
  risen: the median of ``frames`` changing-content frames and of ``frames`` cold frames
  (each after :meth:`~vrcorrect.runtime.corrector.Corrector.reset`, as a cut makes it), each from the
  dispatch of the first pass to ``ctx.finish()``.  On llvmpipe that is a measurement of CPU cores; on
  a GPU's driver it is a measurement of that GPU, and the bytes over the time give the bandwidth the
  frame reached.  Each pass is timed too, in ``frames`` further frames with a ``glFinish`` before and
  after it (:attr:`~vrcorrect.runtime.dispatch.Gpu.pass_times`): where the frame's time goes.

The default method is compared with the others the real-time path offers (ADMM in single
precision, FISTA, the one-pass FFT inverse) in one run.  ``dry_run`` counts without running the
passes (seconds instead of minutes on a software renderer; no wall times then).  Layer 6.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from ...plumbing.errors import ValidationError
from ...runtime.corrector import Corrector, CorrectorOptions
from ...runtime.dispatch import BANDWIDTHS, CostLedger, project_ms
from ...runtime.gl import (format_ms, headless_context, release, render_target, software_renderer, timer_query_ms,
                           upload_texture, write_texture)
from ...specs.display import get_display
from ...specs.prescription import Prescription, bundled_sample_path, load_prescription
from ...specs.vocabulary import VIEW_ORDER
from . import machine_description, markdown_table, publish

__all__ = ["METHODS", "FRAME_BUDGET_MS", "TARGET_BYTES", "MethodCost", "parse_size", "eye_frame_cost",
           "run_cost_bench", "check_frames"]

HEADSET_SIZE = (1832, 1920)                   # one Quest 2 eye, width x height
FRAME_BUDGET_MS = 1e3 / 90                    # both eyes of a 90 Hz frame
TARGET_BYTES = 2.0e9                          # the target per eye and frame
WARM_UP_S = 3.0
"""Seconds of untimed frames before the timed ones (at least ``warmup`` frames): a GPU raises its
clocks under load, and on an H100 a frame timed in its first second took 1.5-4x as long as one after
three (frames of 27, 16, 11 then 9 ms where the settled frame takes 6)."""
METHODS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("admm (default)", {}),
    ("admm, single precision", {"filter": "admm", "precision": "single"}),
    ("fista, k = 4", {"filter": "fista"}),
    ("fft, per-frame blend", {"filter": "fft"}),
)
"""The methods compared, by label and Corrector options (the first is the default)."""


def parse_size(text: str, field: str = "--size") -> tuple[int, int]:
    """``WxH`` -> ``(W, H)``, each 16 to 4096 px."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        w = h = 0
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise ValidationError(field, text, "WxH with each side 16 to 4096 pixels, e.g. 1832x1920")
    return w, h


@dataclass
class MethodCost:
    """One method's frame, one eye: the ledger of the changing-content frame and the still one."""

    label: str
    eye: str
    options: dict[str, Any]
    changing: CostLedger
    still: CostLedger
    cold: CostLedger
    frame_ms: float | None                  # median wall time of the changing frames (None: dry run)
    describe: dict[str, Any]
    cold_ms: float | None = None            # median wall time of the cold frames (None: dry run)
    frame_times_ms: tuple[float, ...] = ()  # every timed changing frame
    pass_ms: dict[str, float] | None = None  # median wall time of each pass, a glFinish around it
    gpu_ms: float | None = None             # median GPU time of the changing frames (GL_TIME_ELAPSED)

    def row(self) -> dict[str, Any]:
        c = self.changing
        return {"method": self.label, "eye": self.eye, "dispatches": c.dispatches, "fft_round_trips": c.fft_round_trips,
                "bytes_per_eye_frame": c.bytes, "still_view_bytes": self.still.bytes,
                "cold_frame_bytes": self.cold.bytes,
                "projected_ms": {gpu: project_ms(c.bytes, bw) for gpu, (bw, _) in BANDWIDTHS.items()},
                "measured_ms": self.frame_ms, "measured_cold_ms": self.cold_ms,
                "measured_frames_ms": list(self.frame_times_ms), "measured_gpu_ms": self.gpu_ms,
                "measured_pass_ms": self.pass_ms, "stages": c.by_stage(), "strategy": self.describe.get("strategy"),
                "iterations_per_frame": self.describe.get("iterations_per_frame")}


def check_frames(frames: int, what: str = "timed frames") -> None:
    """``--frames``: a whole number of ``what`` from 1 to 1000."""
    if not 1 <= int(frames) <= 1000:
        raise ValidationError("--frames", frames, f"a whole number of {what} from 1 to 1000")


def eye_frame_cost(ctx: Any, rx: Prescription, display: Any, eye: str, size: tuple[int, int],
                   options: dict[str, Any], warmup: int = 2, dry_run: bool = False, seed: int = 0,
                   label: str = "", frames: int = 1) -> MethodCost:
    """One eye's frame costs: ``warmup`` frames of changing content (the first, cold, counted; more
    until ``WARM_UP_S`` seconds have passed, unless ``dry_run``), then
    ``frames`` timed frames of new content (the budget case; the first counted), then, unless
    ``dry_run``, ``frames`` more with each pass timed (a ``glFinish`` around it) and ``frames`` timed
    cold frames (a reset before each, as a cut), then the same picture
    once more counted as the early stop's plan leaves a converged still view (module docstring)."""
    check_frames(frames)
    rng = np.random.default_rng(seed)
    W, H = size
    corrector = Corrector(ctx, rx, display, eye, **options)
    corrector.gpu.dry_run = dry_run
    src = upload_texture(ctx, rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    tex, fbo = render_target(ctx, width=W, height=H)
    pictures = [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)]
    try:
        query = None if dry_run else ctx.query(time=True)
        gpu_times: list[float] = []

        shown = [0]                                         # frames of new content so far

        def frame(new_content: bool, gpu_time: bool = False) -> float:
            if new_content:                                 # the two pictures in turn: never the last one
                shown[0] += 1
                write_texture(src, pictures[shown[0] % 2])
            ctx.finish()                                    # the upload is not the frame's
            t0 = time.perf_counter()
            if gpu_time and query is not None:
                with query:                                 # GL_TIME_ELAPSED: the GPU's own clock
                    corrector.apply(src, fbo)
            else:
                corrector.apply(src, fbo)
            ctx.finish()
            ms = 1e3 * (time.perf_counter() - t0)
            if gpu_time and query is not None:
                value = timer_query_ms(query.elapsed)       # None when saturated (a frame of 4.29 s or more)
                if value is not None:
                    gpu_times.append(value)
            return ms

        corrector.ledger = cold = CostLedger()
        frame(True)
        corrector.ledger = None
        warm_until = time.perf_counter() + (0.0 if dry_run else WARM_UP_S)
        done = 1
        while done < warmup or time.perf_counter() < warm_until:
            frame(True)
            done += 1
        corrector.ledger = changing = CostLedger()
        times = []
        for _ in range(int(frames)):
            times.append(frame(True, gpu_time=True))
            corrector.ledger = None
        pass_times: dict[str, list[float]] = {}
        cold_times = []
        if not dry_run:
            corrector.gpu.pass_times = pass_times              # where the time goes: a wait around each pass
            for _ in range(int(frames)):
                frame(True)
            corrector.gpu.pass_times = None
            for _ in range(int(frames)):
                corrector.reset()
                cold_times.append(frame(True))
            for _ in range(max(warmup, 1)):                 # back to a warm frame before the still view
                frame(True)
        corrector.gpu.dry_run = corrector.gpu.dry_run_idle = True      # the frame the plan leaves idle
        corrector.ledger = still = CostLedger()
        frame(False)
        return MethodCost(label, eye, options, changing, still, cold,
                          None if dry_run else statistics.median(times), corrector.describe(),
                          None if dry_run else statistics.median(cold_times),
                          () if dry_run else tuple(times),
                          None if dry_run else {k: statistics.median(v) for k, v in pass_times.items()},
                          statistics.median(gpu_times) if gpu_times else None)
    finally:
        corrector.release()
        release(fbo, tex, src)                          # (moderngl queries have no release: the context frees them)


def run_cost_bench(size: tuple[int, int] = HEADSET_SIZE, display_name: str = "quest2", rx_path: str | None = None,
                   out: Path = Path("docs/benchmarks.md"), json_out: Path | None = None, write: bool = True,
                   dry_run: bool = False, methods: Sequence[tuple[str, dict[str, Any]]] = METHODS,
                   force: bool = False, frames: int = 1) -> dict[str, Any]:
    """Count one frame per eye for each method and time ``frames`` of each kind (module docstring);
    returns the report (a dict with ``markdown``), writes the ``cost`` section of ``out`` and, with
    ``json_out``, the JSON."""
    check_frames(frames)
    display = get_display(display_name)
    rx = load_prescription(rx_path or bundled_sample_path())
    ctx = headless_context(require=430)
    results: list[MethodCost] = []
    try:
        renderer = ctx.info.get("GL_RENDERER", "?")
        with tqdm(total=2 * len(methods), desc="bench cost", unit="eye", leave=False) as bar:
            for label, options in methods:
                for eye in VIEW_ORDER:
                    results.append(eye_frame_cost(ctx, rx, display, eye, size, options, dry_run=dry_run,
                                                  label=label, frames=frames))
                    bar.update()
    finally:
        ctx.release()
    default = [r for r in results if r.label == methods[0][0]]
    report = {
        "size": list(size), "display": display.name, "prescription": str(rx_path or bundled_sample_path()),
        "machine": machine_description(), "renderer": renderer, "dry_run": dry_run,
        "timed_frames": None if dry_run else int(frames),
        "default_options": {k: v for k, v in CorrectorOptions().__dict__.items()
                            if k in ("filter", "iterations_per_frame", "precision")},
        "bandwidths_GBps": {gpu: bw / 1e9 for gpu, (bw, _) in BANDWIDTHS.items()},
        "frame_budget_ms_both_eyes": FRAME_BUDGET_MS, "target_bytes_per_eye_frame": TARGET_BYTES,
        "default": {"dispatches": max(r.changing.dispatches for r in default),
                    "fft_round_trips": max(r.changing.fft_round_trips for r in default),
                    "bytes_per_eye_frame": max(r.changing.bytes for r in default),
                    "still_view_bytes_per_eye_frame": max(r.still.bytes for r in default),
                    "cold_frame_bytes_per_eye_frame": max(r.cold.bytes for r in default),
                    "cold_frame_fft_round_trips": max(r.cold.fft_round_trips for r in default),
                    "measured_ms_per_eye_frame": _worst_ms(default, "frame_ms"),
                    "measured_gpu_ms_per_eye_frame": _worst_ms(default, "gpu_ms"),
                    "measured_cold_ms_per_eye_frame": _worst_ms(default, "cold_ms")},
        "methods": [r.row() for r in results],
    }
    report["markdown"] = _markdown(report, results, size, display.name, renderer, dry_run)
    return publish(report, "cost", out, write, json_out, force)


def _still_sentence(d: dict[str, Any]) -> str:
    still, changing = d["still_view_bytes_per_eye_frame"], d["bytes_per_eye_frame"]
    if still >= changing:
        return "A converged still view costs what a changing frame costs: the iterations run every frame."
    return (f"A converged still view costs {_gb(still)} GB, {changing / still:.0f}x less: once the view is still and "
            "two frames' objectives agree to 1e-3, the GPU gives the passes no work until the picture changes (the "
            "early stop; FISTA and the one-pass methods have none).")


def _cold_sentence(d: dict[str, Any], gpus: list[str]) -> str:
    cold, changing = d["cold_frame_bytes_per_eye_frame"], d["bytes_per_eye_frame"]
    both = {g: 2 * project_ms(cold, BANDWIDTHS[g][0]) for g in gpus}
    return (f"A shot's first frame (cold: the first frame, a cut, a new prescription) costs {_gb(cold)} GB, "
            f"{cold / changing:.1f}x a changing frame ({d['cold_frame_fft_round_trips']} FFT round trips, most of them "
            "at half resolution: the coarse level that starts it); both eyes of such a frame project at "
            + ", ".join(f"{both[g]:.1f} ms on {g}" for g in gpus) + ".")


def _worst_ms(results: Sequence[MethodCost], field: str) -> float | None:
    """The larger eye's median time (None on a dry run)."""
    times = [getattr(r, field) for r in results if getattr(r, field) is not None]
    return max(times) if times else None


def _ms(value: float | None) -> str:
    return f"{value:.0f}" if value is not None and value >= 100 else format_ms(value)


RENDERER_NAMES = {"RTX 3060": ("RTX 3060",), "RTX 4090": ("RTX 4090",), "H100 SXM": ("H100 80GB HBM3", "H100 SXM")}
"""What each projected GPU's driver calls it (``GL_RENDERER``), to put a measurement beside its
projection; the H100 PCIe (HBM2e, 2.0 TB/s) is another card and matches none."""


def _measured_sentence(d: dict[str, Any], renderer: str) -> str:
    """The measured frame, both eyes, against the 90 Hz budget (empty on a dry run)."""
    ms, cold = d.get("measured_ms_per_eye_frame"), d.get("measured_cold_ms_per_eye_frame")
    if ms is None:
        return ""
    what = "on this machine's software renderer (CPU cores, not a GPU)" if software_renderer(renderer) else f"on {renderer}"
    gpu = d.get("measured_gpu_ms_per_eye_frame")
    same = next((g for g, names in RENDERER_NAMES.items() if any(n in renderer for n in names)), None)
    projected = project_ms(d["bytes_per_eye_frame"], BANDWIDTHS[same][0]) if same else None
    return (f"**Measured {what}**: both eyes of a changing frame take {_ms(2 * ms)} ms "
            f"({100 * 2 * ms / FRAME_BUDGET_MS:.0f} % of a 90 Hz frame"
            + (f"; {_ms(2 * gpu)} ms of it the renderer's own time by timer query" if gpu is not None else "")
            + f"), {_rate(d['bytes_per_eye_frame'], ms)} GB/s reached"
            + (f", {ms / projected:.0f}x the {projected:.2f} ms per eye projected for {same} at its peak"
               if projected else "")
            + f"; both eyes of a shot's first frame {_ms(2 * cold)} ms. ")


def _rate(bytes_moved: int, ms: float) -> str:
    """GB/s: ``bytes_moved`` in ``ms``."""
    rate = bytes_moved / (ms / 1e3) / 1e9
    return f"{rate:.0f}" if rate >= 10 else f"{rate:.2g}"


def _gb(n: int) -> str:
    return f"{n / 1e9:.2f}"


def _markdown(report: dict, results: list[MethodCost], size: tuple[int, int], display: str, renderer: str,
              dry_run: bool) -> str:
    W, H = size
    gpus = list(BANDWIDTHS)
    by_label: dict[str, list[MethodCost]] = {}
    for r in results:
        by_label.setdefault(r.label, []).append(r)
    software = software_renderer(renderer)
    where = f"{renderer}, a CPU" if software else renderer
    rows = []
    for label, rs in by_label.items():
        worst = max(rs, key=lambda r: r.changing.bytes)
        b = worst.changing.bytes
        ms = _worst_ms(rs, "frame_ms")
        rows.append([label, worst.changing.dispatches, worst.changing.fft_round_trips, _gb(b),
                     _gb(max(r.still.bytes for r in rs)), _gb(max(r.cold.bytes for r in rs)),
                     *(f"{project_ms(b, BANDWIDTHS[g][0]):.2f}" for g in gpus),
                     _ms(ms), _ms(_worst_ms(rs, "gpu_ms")), _ms(_worst_ms(rs, "cold_ms")),
                     "-" if ms is None else _rate(b, ms)])
    table = markdown_table(["method", "dispatches", "FFT round trips", "GB per eye frame, changing content",
                            "GB per eye frame, still view", "GB per eye frame, cold (a shot's first)",
                            *(f"projected ms per eye, {g}" for g in gpus),
                            "measured ms per eye, changing", "of it the renderer's time (timer query)",
                            "measured ms per eye, cold",
                            "GB/s reached, changing"], rows)
    default = by_label[next(iter(by_label))]
    larger = max(default, key=lambda r: r.changing.bytes)
    stages, timed = larger.changing, larger.pass_ms

    def measured(p: Any) -> list[str]:
        ms = (timed or {}).get(p.name)
        if ms is None:
            return ["-", "-"]
        return [_ms(ms), _rate(p.bytes_read + p.bytes_written, ms)]

    passes = markdown_table(["stage", "pass", "work groups", "MB read", "MB written", "FFT round trip",
                             "measured ms", "GB/s reached"],
                            [[p.stage, p.name, "x".join(str(g) for g in p.groups) or "draw",
                              f"{p.bytes_read / 1e6:.1f}", f"{p.bytes_written / 1e6:.1f}",
                              "yes" if p.round_trip else "", *measured(p)] for p in stages.records])
    d = report["default"]
    both = {g: 2 * project_ms(d["bytes_per_eye_frame"], BANDWIDTHS[g][0]) for g in gpus}
    fista = by_label.get("fista, k = 4")
    ratio = (max(r.changing.bytes for r in fista) / d["bytes_per_eye_frame"]) if fista else None
    fits = [g for g in gpus if both[g] <= FRAME_BUDGET_MS]
    fits_75 = [g for g in gpus if both[g] / 0.75 <= FRAME_BUDGET_MS]
    sources = "; ".join(f"{g}: {what}" for g, (_, what) in BANDWIDTHS.items())
    return (
        f"## Real-time frame cost, counted from the dispatches: {W}x{H} per eye\n\n"
        f"Machine: {report['machine']}; OpenGL renderer: {renderer}. Display `{display}`, the bundled sample "
        "prescription (both eyes; the larger eye's figures). Each pass of a frame goes through "
        "`runtime.dispatch.Gpu`, which binds the resources the pass names and counts each texel of them read or "
        "written once at its stored size (caches not modelled); the table sums those records "
        "(`vrcorrect bench cost`)." + (" **Dry run: counted, not run; no times.**" if dry_run else "") + "\n\n"
        "The budget case is content that changes every frame (a new picture each frame, the warm start carried "
        "over); the still view is the same picture frame after frame. Projected milliseconds are the bytes at the "
        "GPU's published peak memory bandwidth: a lower bound for these bandwidth-bound passes, **a projection, "
        f"not a measurement**; {sources}. "
        + ("The measured columns were not run (dry run)." if dry_run else
           f"The measured columns are wall times on {where}, from the first pass's dispatch to `glFinish`, the "
           f"median of {report['timed_frames']} frame(s) of each kind (a cold frame after a reset, as a cut), the "
           "larger eye's, and the changing frames' GPU time by a `GL_TIME_ELAPSED` query around them (the rest "
           "is the CPU's work of issuing the passes); the last column is the changing frame's counted bytes over "
           "its measured time"
           + (" (a CPU's, not a GPU's)." if software else ".")) + "\n\n"
        + table + "\n\n"
        f"**The default** ({report['default_options']['filter']}, {report['default_options']['iterations_per_frame']} "
        f"iterations a frame, {report['default_options']['precision']} precision): {d['dispatches']} dispatches, "
        f"{d['fft_round_trips']} FFT round trips and {_gb(d['bytes_per_eye_frame'])} GB per eye per frame on "
        f"changing content (target: at most {TARGET_BYTES / 1e9:.1f} GB), "
        + (f"{ratio:.1f}x fewer bytes than FISTA's k = 4 frame; " if ratio else "")
        + "both eyes projected at "
        + ", ".join(f"{both[g]:.1f} ms on {g}" for g in gpus)
        + f" against the {FRAME_BUDGET_MS:.1f} ms of a 90 Hz frame: "
        + (f"inside the budget on {', '.join(fits)} at peak bandwidth" if fits else "outside it on all three")
        + (f"; at 75 % of the peak, as well-tuned bandwidth-bound code reaches, on {', '.join(fits_75)}"
           if fits_75 != fits else "") + " (a bound: a GPU measured so far reached far less of its peak, "
        "docs/realtime.md). " + _measured_sentence(d, renderer) + _still_sentence(d) + " "
        + _cold_sentence(d, gpus) + "\n\n"
        "The default's passes, changing content, one eye"
        + ("" if dry_run else f" (measured: the median of {report['timed_frames']} frame(s) with a `glFinish` before "
           f"and after each pass, on {where}; the waits add a little to each)") + ":\n\n" + passes + "\n"
    )
