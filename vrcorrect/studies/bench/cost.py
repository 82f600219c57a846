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
* **Projections** from a measured efficiency, not from peak bandwidth: milliseconds per eye on three
  GPUs (:data:`~vrcorrect.runtime.dispatch.BANDWIDTHS`) at the fraction of its peak bandwidth the
  frame reached on a GPU where it was measured: this run's, when it runs on a GPU whose peak is
  known (:data:`PEAKS`), else the last measured run's (:data:`REFERENCE_RUNS`).  Each is labelled a
  projection and names its source.  The peak-bandwidth figure stays beside it as a bound no code
  reaches (``peak_bound_ms``).
* **Measured**: each frame's wall time and GPU time (a ``GL_TIME_ELAPSED`` query) on whatever
  renderer the context has (``GL_RENDERER`` is reported beside it), by the routine ``bench
  workgroups`` times its frames with (:func:`~vrcorrect.studies.bench.frame_timing.time_frames`):
  after ``WARM_UP_S`` seconds of untimed frames so that a GPU's clocks have risen, ``frames``
  changing-content frames and ``frames`` cold frames (each after
  :meth:`~vrcorrect.runtime.corrector.Corrector.reset`, as a cut makes it), in rounds of five of each
  kind with two untimed frames before each; the medians.  The counted frames run untimed (a ledger
  reads the early stop's indirect arguments back, a wait inside the frame).  On llvmpipe that is a
  measurement of CPU cores; on a GPU's driver it is a measurement of that GPU, and the bytes over
  the time give the bandwidth the frame reached.  Each pass is timed too, in ``frames`` further
  frames with a ``glFinish`` before and after it (:attr:`~vrcorrect.runtime.dispatch.Gpu.pass_times`):
  where the frame's time goes.
* **A peer** (``peer="torch"``): the same default frame written plainly in torch on cuFFT
  (:mod:`~vrcorrect.studies.bench.peer`), timed in the same run on the same GPU, with its ratio to
  the GLSL frame; where torch sees no CUDA device, :data:`~vrcorrect.studies.bench.peer.NO_DEVICE`.

The default method is compared with the others the real-time path offers (ADMM in single
precision, FISTA, the one-pass FFT inverse) in one run.  ``dry_run`` counts without running the
passes (seconds instead of minutes on a software renderer; no wall times then).  Layer 6.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from ...plumbing.errors import ValidationError
from ...runtime.corrector import Corrector, CorrectorOptions
from ...runtime.dispatch import BANDWIDTHS, CostLedger, project_ms
from ...runtime.gl import (
    format_ms,
    headless_context,
    release,
    render_target,
    software_renderer,
    upload_texture,
    write_texture,
)
from ...solvers.foveated import fovea_pixels
from ...specs.display import get_display
from ...specs.prescription import Prescription, bundled_sample_path, load_prescription
from ...specs.vocabulary import VIEW_ORDER
from . import machine_description, markdown_table, publish
from .frame_timing import KindTimes, Subject, time_frames

__all__ = ["METHODS", "FRAME_BUDGET_MS", "TARGET_BYTES", "FOVEA_TARGET_BYTES", "fovea_method", "MethodCost", "parse_size", "eye_frame_cost",
           "run_cost_bench", "check_frames", "PEAKS", "ReferenceRun", "REFERENCE_RUNS", "efficiency_source"]

HEADSET_SIZE = (1832, 1920)                   # one Quest 2 eye, width x height
FRAME_BUDGET_MS = 1e3 / 90                    # both eyes of a 90 Hz frame
TARGET_BYTES = 2.0e9                          # the target per eye and frame
WARM_UP_S = 3.0
"""Seconds of untimed frames before the timed ones (at least ``warmup`` frames): a GPU raises its
clocks under load, and on an H100 a frame timed in its first second took 1.5-4x as long as one after
three (frames of 27, 16, 11 then 9 ms where the settled frame takes 6)."""
PEAKS: dict[str, tuple[tuple[str, ...], float, str]] = {
    "H100 SXM": (("H100 80GB HBM3", "H100 SXM"), 3.35e12, "NVIDIA H100 SXM5 80 GB: HBM3, 3.35 TB/s (NVIDIA's "
                                                           "H100 datasheet)"),
    "H200": (("H200",), 4.8e12, "NVIDIA H200: HBM3e, 4.8 TB/s (NVIDIA's H200 datasheet)"),
    "RTX 3060": (("RTX 3060",), BANDWIDTHS["RTX 3060"][0], BANDWIDTHS["RTX 3060"][1]),
    "RTX 4090": (("RTX 4090",), BANDWIDTHS["RTX 4090"][0], BANDWIDTHS["RTX 4090"][1]),
}
"""GPUs whose peak memory bandwidth is known, by what their driver calls them (``GL_RENDERER``): a
run on one of them measures the efficiency the other cards' projections use.  (The H100 PCIe, HBM2e
at 2.0 TB/s, is another card and matches none.)"""


@dataclass(frozen=True)
class ReferenceRun:
    """A measured run of the default frame on a GPU: ``bytes_`` counted, ``gpu_ms`` by timer query
    (the median, one Quest 2 eye), the card's peak bandwidth (bytes/s) and where the figures come
    from."""

    card: str
    date: str
    bytes_: int
    gpu_ms: float
    peak: float
    source: str

    @property
    def efficiency(self) -> float:
        """The fraction of the card's peak bandwidth the frame reached."""
        return self.bytes_ / (self.gpu_ms / 1e3) / self.peak


REFERENCE_RUNS = (
    ReferenceRun("NVIDIA H100 80GB HBM3", "2026-11-27", 1_788_414_216, 5.35, 3.35e12,
                 "docs/realtime.md: `bench cost --size 1832x1920 --frames 40`, the radix-2 passes of before issue 43"),
    ReferenceRun("NVIDIA H200", "2026-11-27", 1_788_414_216, 6.10, 4.8e12,
                 "issue 43: `bench cost --size 1832x1920 --frames 40`, the radix-2 passes of before issue 43"),
)
"""The default frame measured on GPUs so far, the last one last: where no GPU of :data:`PEAKS` runs
the bench, the projections use the last one's efficiency (the H200's 6 % of its peak)."""


METHODS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("admm (default)", {}),
    ("admm, single precision", {"filter": "admm", "precision": "single"}),
    ("fista, k = 4", {"filter": "fista"}),
    ("fft, per-frame blend", {"filter": "fft"}),
)
"""The methods compared, by label and Corrector options (the first is the default)."""


FOVEA_TARGET_BYTES = 0.5e9
"""Issue 45's target for a foveated frame at a 15 degree radius, per eye and changing frame."""


def fovea_method(radius_deg: float, periphery: str | None = None) -> tuple[str, dict[str, Any]]:
    """The foveated default frame at ``radius_deg`` (``periphery``: None, the default's), as a method
    row: label and Corrector options."""
    from ...runtime.strategies.foveated import (
        DEFAULT_PERIPHERY,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    p = periphery or DEFAULT_PERIPHERY
    return f"admm (default), fovea {radius_deg:g} deg, periphery {p}", {"fovea_deg": float(radius_deg),
                                                                        "fovea_periphery": p}


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
    grid: tuple[int, int] | None = None     # (NY, NX): the FFT grid of the method at this size
    cold_gpu_ms: float | None = None        # median GPU time of the cold frames
    model: Any = None                       # the eye model (the peer's kernels; not in the report)

    def row(self, efficiency: float = REFERENCE_RUNS[-1].efficiency) -> dict[str, Any]:
        c = self.changing
        return {"method": self.label, "eye": self.eye, "dispatches": c.dispatches, "fft_round_trips": c.fft_round_trips,
                "grid": None if self.grid is None else list(self.grid),
                "bytes_per_eye_frame": c.bytes, "still_view_bytes": self.still.bytes,
                "cold_frame_bytes": self.cold.bytes,
                "projected_ms": {gpu: project_ms(c.bytes, bw * efficiency) for gpu, (bw, _) in BANDWIDTHS.items()},
                "peak_bound_ms": {gpu: project_ms(c.bytes, bw) for gpu, (bw, _) in BANDWIDTHS.items()},
                "measured_cold_gpu_ms": self.cold_gpu_ms,
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
                   label: str = "", frames: int = 1, gaze_deg: tuple[float, float] = (0.0, 0.0)) -> MethodCost:
    """One eye's frame costs: ``warmup`` frames of changing content (the first, cold, counted; more
    until ``WARM_UP_S`` seconds have passed, unless ``dry_run``), then
    ``frames`` timed frames of new content (the budget case; the first counted), then, unless
    ``dry_run``, ``frames`` more with each pass timed (a ``glFinish`` around it) and ``frames`` timed
    cold frames (a reset before each, as a cut), then the same picture
    once more counted as the early stop's plan leaves a converged still view (module docstring).
    ``gaze_deg``: where the eye looks (a foveated method's window, ``fovea_deg`` in ``options``)."""
    check_frames(frames)
    rng = np.random.default_rng(seed)
    W, H = size
    corrector = Corrector(ctx, rx, display, eye, **options)
    corrector.gaze_deg = tuple(gaze_deg)
    corrector.gpu.dry_run = dry_run
    src = upload_texture(ctx, rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    tex, fbo = render_target(ctx, width=W, height=H)
    pictures = [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)]
    try:
        shown = [0]                                         # frames of new content so far

        def picture(i: int) -> None:                        # the two pictures in turn: never the last one
            write_texture(src, pictures[i % 2])

        def frame(new_content: bool = True) -> None:
            if new_content:
                shown[0] += 1
                picture(shown[0])
            corrector.apply(src, fbo)

        corrector.ledger = cold = CostLedger()              # the first frame: cold
        frame()
        corrector.ledger = None
        for _ in range(max(warmup - 1, 1)):
            frame()
        corrector.ledger = changing = CostLedger()          # counted, never timed (the ledger reads back)
        frame()
        corrector.ledger = None
        grid = _grid_of(corrector, size)
        times: dict[str, KindTimes] = {}
        pass_times: dict[str, list[float]] = {}
        if not dry_run:
            subject = Subject(apply=lambda: corrector.apply(src, fbo), picture=picture, reset=corrector.reset)
            (times,) = time_frames(ctx, [subject], frames, WARM_UP_S)
            corrector.gpu.pass_times = pass_times              # where the time goes: a wait around each pass
            for _ in range(int(frames)):
                frame()
            corrector.gpu.pass_times = None
            for _ in range(max(warmup, 1)):                 # back to a warm frame before the still view
                frame()
        corrector.gpu.dry_run = corrector.gpu.dry_run_idle = True      # the frame the plan leaves idle
        corrector.ledger = still = CostLedger()
        frame(False)
        changing_t, cold_t = times.get("changing"), times.get("cold")
        return MethodCost(label, eye, options, changing, still, cold,
                          None if dry_run else changing_t.wall_median, corrector.describe(),
                          None if dry_run else cold_t.wall_median,
                          () if dry_run else tuple(changing_t.wall_ms),
                          None if dry_run else {k: statistics.median(v) for k, v in pass_times.items()},
                          None if dry_run else changing_t.gpu_median, grid=grid,
                          cold_gpu_ms=None if dry_run else cold_t.gpu_median, model=corrector.model)
    finally:
        corrector.release()
        release(fbo, tex, src)                          # (moderngl queries have no release: the context frees them)


def _grid_of(corrector: Corrector, size: tuple[int, int]) -> tuple[int, int] | None:
    """The ``(NY, NX)`` FFT grid the corrector's strategy runs ``size`` frames on."""
    strategy = corrector.strategy
    window = getattr(strategy, "window", None)
    if window is not None:                               # foveated: the sub-image's grid
        return tuple(strategy.grid(window.sub_shape[::-1]))
    if hasattr(strategy, "grid"):
        return tuple(strategy.grid(size))
    try:
        return tuple(corrector.fft_grid_for(size)[0])
    except Exception:                                    # a strategy without an FFT grid
        return None


def efficiency_source(renderer: str, bytes_: int | None, gpu_ms: float | None) -> dict[str, Any]:
    """The efficiency the projections use (module docstring): this run's, where it measured the
    default's GPU time on a card of :data:`PEAKS`, else the last of :data:`REFERENCE_RUNS`;
    ``{"efficiency", "source", "this_run"}``."""
    card = next((c for c, (names, _, _) in PEAKS.items() if any(n in renderer for n in names)), None)
    if card is not None and gpu_ms and bytes_ and not software_renderer(renderer):
        peak = PEAKS[card][1]
        eff = bytes_ / (gpu_ms / 1e3) / peak
        return {"efficiency": eff, "this_run": True, "card": card,
                "source": f"this run on {renderer}: {bytes_ / 1e9:.2f} GB in {gpu_ms:.2f} ms of GPU time per eye, "
                          f"{100 * eff:.1f} % of the {card}'s {peak / 1e12:.2f} TB/s"}
    ref = REFERENCE_RUNS[-1]
    return {"efficiency": ref.efficiency, "this_run": False, "card": ref.card,
            "source": f"the last measured run: {ref.card}, {ref.date}, {ref.bytes_ / 1e9:.2f} GB in {ref.gpu_ms:.2f} ms "
                      f"of GPU time per eye, {100 * ref.efficiency:.1f} % of its {ref.peak / 1e12:.2f} TB/s ({ref.source})"}


def run_peer(peer: str, results: Sequence[MethodCost], size: tuple[int, int], frames: int,
             dry_run: bool) -> dict[str, Any]:
    """The peer's frame (:mod:`~vrcorrect.studies.bench.peer`) for each eye of the default, timed
    on the CUDA device torch sees, after a check against the CPU twin there; or why it did not run
    (exactly :data:`~vrcorrect.studies.bench.peer.NO_DEVICE` where torch sees no CUDA device)."""
    from .peer import (  # on use: start-up time (the CLI imports the studies to build its parser)
        NO_DEVICE,
        PEERS,
        peer_against_twin,
        peer_device,
        time_torch_peer,
    )

    if peer not in PEERS:
        raise ValidationError("--peer", peer, "one of " + ", ".join(PEERS))
    device, name = peer_device()
    if device is None:
        return {"peer": peer, "status": NO_DEVICE, "reason": name}
    if dry_run:
        return {"peer": peer, "status": "dry run: peer not run", "device": name}
    default = [r for r in results if r.label == results[0].label]
    eyes = {}
    for r in default:
        k = r.model.kernel
        ref = r.model.reference
        it = int(r.describe.get("iterations_per_frame", 2))
        eyes[r.eye] = {**time_torch_peer(k, ref, size, it, frames, WARM_UP_S,
                                         grid_kernel_size=getattr(r.model, "margin", None)),
                       "equal_to_twin": peer_against_twin(k, ref, device, iterations=it)}
    gpu = max(e["gpu_ms"] for e in eyes.values())
    glsl = _worst_ms(default, "gpu_ms")
    return {"peer": peer, "status": "run", "device": name, "eyes": eyes, "gpu_ms_per_eye_frame": gpu,
            "glsl_gpu_ms_per_eye_frame": glsl, "glsl_over_peer": None if not glsl else glsl / gpu}


def run_cost_bench(size: tuple[int, int] = HEADSET_SIZE, display_name: str = "quest2", rx_path: str | None = None,
                   out: Path = Path("docs/benchmarks.md"), json_out: Path | None = None, write: bool = True,
                   dry_run: bool = False, methods: Sequence[tuple[str, dict[str, Any]]] = METHODS,
                   force: bool = False, frames: int = 1, peer: str | None = None, fovea: Sequence[float] = (),
                   gaze_deg: tuple[float, float] = (0.0, 0.0), periphery: str | None = None) -> dict[str, Any]:
    """Count one frame per eye for each method and time ``frames`` of each kind (module docstring),
    and with ``peer`` the peer's frame; returns the report (a dict with ``markdown``), writes the
    ``cost`` section of ``out`` and, with ``json_out``, the JSON.  ``fovea``: radii (degrees) of
    foveated default frames counted beside the methods, their windows around ``gaze_deg``, the view
    outside them ``periphery`` (None: the default's)."""
    check_frames(frames)
    methods = list(methods) + [fovea_method(r, periphery) for r in fovea]
    if peer is not None:
        from .peer import PEERS  # on use: start-up time (the CLI imports the studies to build its parser)

        if peer not in PEERS:
            raise ValidationError("--peer", peer, "one of " + ", ".join(PEERS))
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
                                                  label=label, frames=frames, gaze_deg=gaze_deg))
                    bar.update()
    finally:
        ctx.release()
    default = [r for r in results if r.label == methods[0][0]]
    fov = {r: [m for m in results if m.label == fovea_method(r, periphery)[0]] for r in fovea}   # each radius's eyes
    d_bytes, d_gpu = max(r.changing.bytes for r in default), _worst_ms(default, "gpu_ms")
    projection = efficiency_source(renderer, d_bytes, d_gpu)
    report = {
        "size": list(size), "display": display.name, "prescription": str(rx_path or bundled_sample_path()),
        "machine": machine_description(), "renderer": renderer, "dry_run": dry_run,
        "timed_frames": None if dry_run else int(frames),
        "default_options": {k: v for k, v in CorrectorOptions().__dict__.items()
                            if k in ("filter", "iterations_per_frame", "precision")},
        "bandwidths_GBps": {gpu: bw / 1e9 for gpu, (bw, _) in BANDWIDTHS.items()},
        "projection": projection,
        "frame_budget_ms_both_eyes": FRAME_BUDGET_MS, "target_bytes_per_eye_frame": TARGET_BYTES,
        "default": {"dispatches": max(r.changing.dispatches for r in default),
                    "fft_round_trips": max(r.changing.fft_round_trips for r in default),
                    "grid": list(max(default, key=lambda r: r.changing.bytes).grid or ()),
                    "bytes_per_eye_frame": d_bytes,
                    "still_view_bytes_per_eye_frame": max(r.still.bytes for r in default),
                    "cold_frame_bytes_per_eye_frame": max(r.cold.bytes for r in default),
                    "cold_frame_fft_round_trips": max(r.cold.fft_round_trips for r in default),
                    "measured_ms_per_eye_frame": _worst_ms(default, "frame_ms"),
                    "measured_gpu_ms_per_eye_frame": d_gpu,
                    "measured_cold_ms_per_eye_frame": _worst_ms(default, "cold_ms"),
                    "measured_cold_gpu_ms_per_eye_frame": _worst_ms(default, "cold_gpu_ms")},
        "methods": [r.row(projection["efficiency"]) for r in results],
        "gaze_deg": list(gaze_deg),
        "fovea": [{"radius_deg": r, "radius_px": int(round(r * display.pixels_per_degree)),
                   "band_px": fovea_pixels(r, display.pixels_per_degree)[1],
                   "periphery": fovea_method(r, periphery)[1]["fovea_periphery"],
                   "bytes_per_eye_frame": max(m.changing.bytes for m in fov[r]),
                   "cold_frame_bytes_per_eye_frame": max(m.cold.bytes for m in fov[r]),
                   "grid": list(max(fov[r], key=lambda m: m.changing.bytes).grid or ())} for r in fovea],
    }
    if peer is not None:
        report["peer"] = run_peer(peer, results, size, frames, dry_run)
    report["markdown"] = _markdown(report, results, size, display.name, renderer, dry_run)
    return publish(report, "cost", out, write, json_out, force)


def _fovea_section(report: dict[str, Any], gpus: list[str], efficiency: float) -> str:
    """The foveated frames against the default's (empty without ``--fovea``)."""
    if not report["fovea"]:
        return ""
    d = report["default"]["bytes_per_eye_frame"]
    x, y = report["gaze_deg"]
    lines = []
    for f in report["fovea"]:
        b = f["bytes_per_eye_frame"]
        both = ", ".join(f"{2 * project_ms(b, BANDWIDTHS[g][0] * efficiency):.1f} ms on {g}" for g in gpus)
        grid = "x".join(str(v) for v in f["grid"][::-1])
        solved = 2 * (f["radius_px"] + f["band_px"])
        lines.append(f"- radius {f['radius_deg']:g} deg ({f['radius_px']} px, and a blend band of {f['band_px']} px "
                     f"beyond it: a window of {solved} px a side and its ring, FFT grid {grid}; periphery: {f['periphery']}): {_gb(b)} GB per eye per changing "
                     f"frame, {100 * b / d:.0f} % of "
                     f"the full field's (a cold frame: {_gb(f['cold_frame_bytes_per_eye_frame'])} GB, with its cold "
                     f"iterations); both eyes projected at {both}"
                     + (f" (issue 45's target at 15 deg: at most {FOVEA_TARGET_BYTES / 1e9:.1f} GB: "
                        f"{'met' if b <= FOVEA_TARGET_BYTES else 'not met'})" if f["radius_deg"] == 15 else ""))
    return (f"**Foveated** (`--fovea`; the default frame solved on a window around the gaze at ({x:g}, {y:g}) deg; "
            "outside it the periphery: a correction of the whole view at a quarter or half of the resolution, or the "
            "target as it is; projections as above, not measurements):\n\n"
            + "\n".join(lines) + "\n\n")


def _still_sentence(d: dict[str, Any]) -> str:
    still, changing = d["still_view_bytes_per_eye_frame"], d["bytes_per_eye_frame"]
    if still >= changing:
        return "A converged still view costs what a changing frame costs: the iterations run every frame."
    return (f"A converged still view costs {_gb(still)} GB, {changing / still:.0f}x less: once the view is still and "
            "two frames' objectives agree to 1e-3, the GPU gives the passes no work until the picture changes (the "
            "early stop; FISTA and the one-pass methods have none).")


def _cold_sentence(d: dict[str, Any], gpus: list[str], efficiency: float) -> str:
    cold, changing = d["cold_frame_bytes_per_eye_frame"], d["bytes_per_eye_frame"]
    both = {g: 2 * project_ms(cold, BANDWIDTHS[g][0] * efficiency) for g in gpus}
    return (f"A shot's first frame (cold: the first frame, a cut, a new prescription) costs {_gb(cold)} GB, "
            f"{cold / changing:.1f}x a changing frame ({d['cold_frame_fft_round_trips']} FFT round trips, most of them "
            "at half resolution: the coarse level that starts it); both eyes of such a frame project (at the same "
            "efficiency) at " + ", ".join(f"{both[g]:.1f} ms on {g}" for g in gpus) + ".")


def _peer_section(report: dict[str, Any]) -> str:
    """The peer's paragraph and table (empty without ``--peer``)."""
    p = report.get("peer")
    if p is None:
        return ""
    head = f"**Peer ({p['peer']} on cuFFT, the same frame written plainly: `--peer {p['peer']}`)**: "
    if p["status"] != "run":
        return head + p["status"] + ".\n\n"
    rows = []
    for eye, e in p["eyes"].items():
        check = e["equal_to_twin"]
        rows.append([eye, format_ms(e["gpu_ms"]), "yes" if e["graph"] else "no (eager)",
                     f"{check['shown']:.1e} / {check['objective']:.1e}"])
    table = markdown_table(["eye", "peer GPU ms per frame (median, CUDA events)", "one CUDA graph",
                            "peer - CPU twin on the device: frame shown (max) / objective (relative)"], rows)
    ratio = p.get("glsl_over_peer")
    return (head + f"run on {p['device']} after the GLSL frames, {report['timed_frames']} changing frames per eye after "
            f"{WARM_UP_S:g} s of warm-up. The larger eye: GLSL {format_ms(p['glsl_gpu_ms_per_eye_frame'])} ms, peer "
            f"{format_ms(p['gpu_ms_per_eye_frame'])} ms of GPU time"
            + (f": the GLSL frame takes {ratio:.2f}x the peer's" if ratio else "") + ".\n\n" + table + "\n\n")


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
    projection = report["projection"]
    eff = projection["efficiency"]
    rows = []
    for label, rs in by_label.items():
        worst = max(rs, key=lambda r: r.changing.bytes)
        b = worst.changing.bytes
        ms = _worst_ms(rs, "frame_ms")
        grid = "x".join(str(v) for v in worst.grid[::-1]) if worst.grid else "-"
        rows.append([label, grid, worst.changing.dispatches, worst.changing.fft_round_trips, _gb(b),
                     _gb(max(r.still.bytes for r in rs)), _gb(max(r.cold.bytes for r in rs)),
                     *(f"{project_ms(b, BANDWIDTHS[g][0] * eff):.2f}" for g in gpus),
                     _ms(ms), _ms(_worst_ms(rs, "gpu_ms")), _ms(_worst_ms(rs, "cold_ms")),
                     "-" if ms is None else _rate(b, ms)])
    table = markdown_table(["method", "FFT grid (NX x NY)", "dispatches", "FFT round trips",
                            "GB per eye frame, changing content",
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
    both = {g: 2 * project_ms(d["bytes_per_eye_frame"], BANDWIDTHS[g][0] * eff) for g in gpus}
    bound = {g: 2 * project_ms(d["bytes_per_eye_frame"], BANDWIDTHS[g][0]) for g in gpus}
    fista = by_label.get("fista, k = 4")
    ratio = (max(r.changing.bytes for r in fista) / d["bytes_per_eye_frame"]) if fista else None
    fits = [g for g in gpus if both[g] <= FRAME_BUDGET_MS]
    sources = "; ".join(f"{g}: {what}" for g, (_, what) in BANDWIDTHS.items())
    return (
        f"## Real-time frame cost, counted from the dispatches: {W}x{H} per eye\n\n"
        f"Machine: {report['machine']}; OpenGL renderer: {renderer}. Display `{display}`, the bundled sample "
        "prescription (both eyes; the larger eye's figures). Each pass of a frame goes through "
        "`runtime.dispatch.Gpu`, which binds the resources the pass names and counts each texel of them read or "
        "written once at its stored size (caches not modelled); the table sums those records "
        "(`vrcorrect bench cost`)." + (" **Dry run: counted, not run; no times.**" if dry_run else "") + "\n\n"
        "The budget case is content that changes every frame (a new picture each frame, the warm start carried "
        "over); the still view is the same picture frame after frame. Projected milliseconds are **projections, "
        "not measurements**, from a measured efficiency, not from peak bandwidth: the bytes at each card's "
        f"published peak memory bandwidth times the fraction of its peak the default frame reached on "
        f"{'this run' if projection['this_run'] else 'the last GPU it was measured on'}, {100 * eff:.1f} % "
        f"(source: {projection['source']}); peaks: {sources}. "
        + ("The measured columns were not run (dry run)." if dry_run else
           f"The measured columns are wall times on {where}, from the first pass's dispatch to `glFinish`, the "
           f"median of {report['timed_frames']} frame(s) of each kind (a cold frame after a reset, as a cut; timed "
           "as `bench workgroups` times its frames: in rounds of five of each kind after two untimed ones), the "
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
        + f"both eyes projected (at {100 * eff:.1f} % of each card's peak) at "
        + ", ".join(f"{both[g]:.1f} ms on {g}" for g in gpus)
        + f" against the {FRAME_BUDGET_MS:.1f} ms of a 90 Hz frame: "
        + (f"inside the budget on {', '.join(fits)}" if fits else "outside it on all three")
        + "; at peak bandwidth, a bound no code reaches, " + ", ".join(f"{bound[g]:.1f} ms on {g}" for g in gpus)
        + ". " + _measured_sentence(d, renderer) + _still_sentence(d) + " "
        + _cold_sentence(d, gpus, eff) + "\n\n" + _fovea_section(report, gpus, eff) + _peer_section(report)
        + "The default's passes, changing content, one eye"
        + ("" if dry_run else f" (measured: the median of {report['timed_frames']} frame(s) with a `glFinish` before "
           f"and after each pass, on {where}; the waits add a little to each)") + ":\n\n" + passes + "\n"
    )
