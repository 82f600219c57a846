"""``vrcorrect bench realtime``: projected gradient (FISTA) spread over frames, the GPU method of
issue 15, against ``fast`` (the converged CPU optimum).

(About 750 lines: four measurements that share their eye, images and plots, one bench.)

Four parts, one section of ``docs/benchmarks.md`` and two plots beside it (``realtime_still.png``,
``realtime_motion.png``):

1. **Still image** (scikit-image's astronaut at 256x256, the desktop preset, the eye
   -2.00 / -1.00 x 120 with a 4 mm pupil, target: what the eye sees with its glasses): the
   objective of the displayed frame relative to ``fast``'s, and JOD (ColorVideoVDP) of what the
   eye sees, against frame number, for k = 1, 2, 4 and 8 iterations per frame.  Computed with the
   CPU twin, :func:`vrcorrect.solvers.wiener.projected_gradient` continued from its state frame
   after frame (one GL iteration equals one CPU step to about 5e-7, ``tests/test_runtime_fista.py``),
   each frame then guarded as the GPU guards it (the best blend with the target,
   :func:`guarded`); one point of it (k = 4, frame 10) is also run through the GPU
   :class:`~vrcorrect.runtime.corrector.Corrector` on headless EGL (:func:`gpu_check`).
2. **Moving sequences**, 20 frames each, k = 4 (:func:`sequences`): a pan of 2 px per frame
   across the photograph, a zoom into its centre, a clip with a cut (the pan, then a pan across
   another photograph) and a head turn of 0.5 degrees a frame in the mirror's 3D demo scene
   (rendered on the headless GL context).  Per frame, the objective relative to ``fast`` on that
   frame and JOD, for a cold start every frame, the GPU's plain warm start
   (``x = clip(x_prev + t - t_prev)``, momentum kept), the previous solution reprojected by the
   known motion (the pan's step, the cut, the change of the eye's pose through
   :func:`~vrcorrect.runtime.motion.view_shift`; newly exposed pixels from the new target, a cold
   start at a cut) and by the shift phase correlation estimates (:func:`phase_correlation_shift`,
   a cold start where it sees a cut).  CPU twin.
3. **llvmpipe** milliseconds per frame per stage (:func:`stage_ms`) through the GPU ``Corrector``
   (``glFinish`` after each stage, median of 3 frames) at 256x256 and 512x512 for k = 1, 2, 4.
4. **A GPU cost model** per Quest 2 eye (1832 x 1920 on a 2048 x 2048 FFT grid) (:func:`cost_model`):
   FFT passes and bytes moved per frame for each k, in phase A's form (``2k + 3`` FFT round trips)
   and in Gram form (``k + 3``), turned into milliseconds at a published GPU FFT bandwidth
   (:data:`FFT_BANDWIDTH`): a projection, not a measurement.

``quick`` shrinks everything (48x48, 4 frames, no JOD) for tests.  Layer 6.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from ...physics.kernel import build_kernel, build_reference_kernel
from ...plumbing.images import prepare_image
from ...runtime.corrector import Corrector
from ...runtime.fft import fft_grid
from ...runtime.gl import download_texture, headless_context, release, render_target, upload_texture
from ...runtime.motion import motion_for, view_shift
from ...runtime.scene import DemoScene, SceneConfig, eye_position, perspective, rotation_y, translation
from ...solvers import make_problem, solve
from ...solvers.wiener import FistaState, gradient_plan, projected_gradient
from ...specs.display import decode, get_display
from ...specs.prescription import EyeRx, Prescription
from ...vision.forward import simulate_lms
from ...vision.metrics import evaluate_seen
from ..plots import pyplot, save_figure
from . import machine_description, markdown_table, write_section

PHOTO = "astronaut"
DISPLAY = "desktop"
EYE = dict(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
STILL_KS = (1, 2, 4, 8)
PAN_K = 4
PAN_PX = 2
TIMING_KS = (1, 2, 4)
HEADSET_EYE = (1832, 1920)                    # width, height of one Quest 2 eye
STRATEGIES = ("cold", "warm", "reprojected", "estimated")
STRATEGY_TITLES = {"cold": "cold start every frame", "warm": "plain warm start, clip(x + t - t_prev)",
                   "reprojected": "warm start reprojected by the known motion",
                   "estimated": "warm start reprojected by phase correlation"}
SEQUENCES = ("pan", "zoom", "cut", "head turn")
CUT_PHOTO = "coffee"                          # the second shot of the clip with a cut
TURN_DEG = 0.5                                # head turn per frame in the demo scene (45 deg/s at 90 Hz)

FFT_BANDWIDTH = {
    "gpu": "NVIDIA A100",
    "GBps": 1260.0,
    "what": ("VkFFT's published benchmark of batched 1D C2C FFTs on an NVIDIA A100 (VkFFT README, 'Benchmark "
             "results in comparison to cuFFT', plot benchmark_plot/fp64_cuda_a100.png, github.com/DTolm/VkFFT, "
             "2024): about 1.26 TB/s achieved for radix-2 lengths up to 2048, where the figure counts one read "
             "and one write of the data per transform (FP64; an FFT of these lengths is bound by memory "
             "bandwidth, so FP32 moves bytes at about the same rate)"),
}
"""The published GPU FFT throughput the cost model projects with (bytes per second of a
bandwidth-bound FFT)."""


# --------------------------------------------------------------------------
# The case
# --------------------------------------------------------------------------


@dataclass
class Case:
    """The bench's eye on its display: kernels, and the still photograph (8-bit and linear)."""

    display: Any
    kernel: Any
    reference: Any
    photo_u8: np.ndarray                     # (S, S, 3) uint8 sRGB, a bit larger than ``size`` for the pan
    size: int

    def target(self, image_u8: np.ndarray) -> np.ndarray:
        return decode("srgb", image_u8.astype(np.float32) / 255).astype(np.float32)

    def problem(self, image_u8: np.ndarray):
        return make_problem(self.target(image_u8), self.kernel, self.reference)

    @property
    def still_u8(self) -> np.ndarray:
        """The still image: the photograph's centre ``size x size``."""
        s, n = self.size, self.photo_u8.shape[0]
        o = (n - s) // 2
        return self.photo_u8[o:o + s, o:o + s]


def make_case(size: int = 256, pan_frames: int = 20, pan_px: int = PAN_PX, display_name: str = DISPLAY) -> Case:
    """The eye -2.00 / -1.00 x 120 (4 mm pupil) on ``display_name``; the photograph large enough
    for a pan of ``pan_frames`` frames of ``pan_px`` px across a ``size`` window."""
    display = get_display(display_name)
    eye = EyeRx(**EYE)
    from skimage import data  # optional: scikit-image (bundled photographs)

    photo = prepare_image(getattr(data, PHOTO)()[..., :3], size + pan_px * max(pan_frames - 1, 0), PHOTO)
    return Case(display=display, kernel=build_kernel(eye, display), reference=build_reference_kernel(eye, display),
                photo_u8=np.round(np.clip(photo, 0, 1) * 255).astype(np.uint8), size=size)


# --------------------------------------------------------------------------
# The CPU twin of a frame: guard, still convergence, pan
# --------------------------------------------------------------------------


def _residual(image: np.ndarray, problem) -> np.ndarray:
    lms, _ = simulate_lms(image.astype(np.float32), problem.kernel, "fft" if problem.kernel.size > 1 else "auto")
    return lms.astype(np.float64) - problem.target_lms.astype(np.float64)


def guarded(x: np.ndarray, problem, r0: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
    """The frame the GPU displays for a solution ``x``: ``t + beta (x - t)`` with the ``beta`` in
    [0, 1] that minimises the objective (``shaders/blend.glsl``); returns ``(displayed, objective,
    beta)``.  ``r0``: the target's residual ``K t - T`` if already known."""
    t = problem.target
    r0 = _residual(t, problem) if r0 is None else r0
    kd = _residual(x, problem) - r0
    kk = float(np.sum(kd * kd))
    beta = 0.0 if kk <= 0 else float(np.clip(-np.sum(r0 * kd) / kk, 0.0, 1.0))
    shown = (t + np.float32(beta) * (x - t)).astype(np.float32)
    r = r0 + beta * kd
    return shown, float(np.mean(r * r)), beta


def _jod(shown: np.ndarray, problem, case: Case) -> float:
    m, _ = evaluate_seen(shown, problem.target, case.kernel, case.display, reference_kernel=case.reference)
    return float(m.jod)


@dataclass
class Series:
    """Per-frame figures of one run: guarded objective, its ratio to ``fast`` on that frame, JOD."""

    objective: list[float] = field(default_factory=list)
    ratio: list[float] = field(default_factory=list)
    jod: list[float | None] = field(default_factory=list)


def still_convergence(case: Case, ks: Sequence[int] = STILL_KS, frames: int = 20,
                      with_jod: bool = True) -> dict[str, Any]:
    """Frame after frame on the still image, k iterations each, continued from the last frame's
    FISTA state (the GPU's warm start on a still source); each frame guarded.  Returns
    ``{"series": {k: Series}, "fast": objective, "none": objective, "fast_jod", "none_jod"}``."""
    p = case.problem(case.still_u8)
    plan = gradient_plan(p.kernel, p.target.shape[:2])
    r0 = _residual(p.target, p)
    fast = solve(p, "fast")
    none = float(np.mean(r0 * r0))
    out: dict[str, Any] = {"fast": fast.objective, "none": none, "series": {},
                           "fast_jod": _jod(fast.image, p, case) if with_jod else None,
                           "none_jod": _jod(p.target, p, case) if with_jod else None}
    for k in ks:
        s, state = Series(), None
        for _ in range(frames):
            x, state = projected_gradient(p, k, plan, state=state, return_state=True)
            shown, obj, _ = guarded(x, p, r0)
            s.objective.append(obj)
            s.ratio.append(obj / fast.objective)
            s.jod.append(_jod(shown, p, case) if with_jod else None)
        out["series"][k] = s
    return out


def pan_targets(case: Case, frames: int, px: int = PAN_PX, photo: np.ndarray | None = None) -> list[np.ndarray]:
    """``frames`` 8-bit windows of ``case.size`` across the photograph (``photo``, default the
    case's), ``px`` to the right each frame (the content moves ``px`` to the left), vertically
    centred."""
    photo = case.photo_u8 if photo is None else photo
    s, n = case.size, photo.shape[0]
    if s + px * (frames - 1) > photo.shape[1]:
        raise ValueError("the photograph is too small for this pan")
    top = (n - s) // 2
    return [photo[top:top + s, px * f:px * f + s] for f in range(frames)]


def zoom_targets(case: Case, frames: int) -> list[np.ndarray]:
    """``frames`` 8-bit views of the photograph's centre zooming in: the crop shrinks linearly
    from the whole photograph to ``case.size`` and is resized to ``case.size`` (anti-aliased)."""
    from skimage.transform import resize  # optional: scikit-image

    n, s = case.photo_u8.shape[0], case.size
    out = []
    for f in range(frames):
        side = int(round(n - (n - s) * f / max(frames - 1, 1)))
        o = (n - side) // 2
        crop = case.photo_u8[o:o + side, o:o + side].astype(np.float32) / 255
        if side != s:
            crop = resize(crop, (s, s, 3), order=1, anti_aliasing=True)
        out.append(np.round(np.clip(crop, 0, 1) * 255).astype(np.uint8))
    return out


def cut_targets(case: Case, frames: int, px: int = PAN_PX) -> tuple[list[np.ndarray], int]:
    """A clip with a cut: the pan across the case's photograph for the first half of ``frames``,
    then a pan across another photograph (:data:`CUT_PHOTO`); returns the frames and the index of
    the first frame after the cut."""
    from skimage import data  # optional: scikit-image (bundled photographs)


    first = frames // 2
    other = prepare_image(getattr(data, CUT_PHOTO)()[..., :3], case.photo_u8.shape[0], CUT_PHOTO)
    other_u8 = np.round(np.clip(other, 0, 1) * 255).astype(np.uint8)
    return pan_targets(case, first, px) + pan_targets(case, frames - first, px, other_u8), first


def head_turn_targets(ctx, case: Case, frames: int, deg_per_frame: float = TURN_DEG,
                      frame_s: float = 1 / 90) -> tuple[list[np.ndarray], list[tuple[int, int] | None]]:
    """The mirror's 3D demo scene (:class:`~vrcorrect.runtime.scene.DemoScene`, on ``ctx``) seen by
    the right eye while the head turns left ``deg_per_frame`` degrees a frame at 90 frames a second
    (the cube turns and the banner scrolls as well); returns the 8-bit frames and the known shift of
    each frame after the first from the change of the eye's pose
    (:func:`~vrcorrect.runtime.motion.view_shift`, as ``vrcorrect xr`` computes it), as (dy, dx)."""
    s = case.size
    config = SceneConfig()
    projection = perspective(config.fov_y_deg, 1.0, 0.05, 60.0)
    camera = eye_position("right", config)
    scene = DemoScene(ctx, s, s, config)
    images, views = [], []
    try:
        for f in range(frames):
            view = np.linalg.inv(translation(*camera) @ rotation_y(math.radians(deg_per_frame * f)))
            views.append(view)
            eye_views = {eye: (projection @ view, camera) for eye in ("left", "right")}
            texture = scene.render(f * frame_s, views=eye_views)[1]
            images.append(np.ascontiguousarray(download_texture(texture)[..., :3]))
    finally:
        scene.release()
    known = []
    for a, b in zip(views, views[1:]):
        shift = view_shift(a, b, projection, (s, s))
        known.append(None if shift is None else (shift[1], shift[0]))
    return images, known


def phase_correlation_shift(previous: np.ndarray, current: np.ndarray) -> tuple[int, int] | None:
    """The whole-pixel displacement ``(dy, dx)`` of the content from ``previous`` to ``current``
    (``current(p) ~ previous(p - d)``), or ``None`` for a scene cut:
    :func:`vrcorrect.runtime.motion.motion_for` (phase correlation of their luminance, a cut below
    its confidence threshold; what the mirror, the overlay and xr run), in the bench's (dy, dx)."""
    motion = motion_for(previous, current)
    return None if motion is None else (motion[1], motion[0])


def reproject(image_chw: np.ndarray, target_hwc: np.ndarray, shift: tuple[int, int]) -> np.ndarray:
    """``image_chw`` (3, H, W) moved by ``shift = (dy, dx)`` (content displacement); the pixels the
    move exposes come from ``target_hwc`` (H, W, 3)."""
    dy, dx = shift
    out = np.ascontiguousarray(np.moveaxis(target_hwc, 2, 0), dtype=np.float32).copy()
    _, h, w = out.shape
    if abs(dy) >= h or abs(dx) >= w:
        return out
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[:, yd, xd] = image_chw[:, ys, xs]
    return out


CUT = "cut"
"""A known transition that is a scene cut (the reprojected strategy starts cold there)."""


def motion_sequence(case: Case, images: Sequence[np.ndarray], known: Sequence[Any] | None, k: int = PAN_K,
                    strategies: Sequence[str] = STRATEGIES, with_jod: bool = True) -> dict[str, Any]:
    """Frames ``images`` (8-bit), ``k`` iterations per frame, for each start strategy
    (:data:`STRATEGIES`); every frame guarded.  ``known``: per transition, the content's known
    shift ``(dy, dx)`` or :data:`CUT`; ``None`` when the motion is not a shift (a zoom): no
    ``reprojected`` series then.  The ``estimated`` strategy uses :func:`phase_correlation_shift`
    (a cold start where it reports a cut).  Returns ``{"series": {strategy: Series}, "fast": [...],
    "none": [...], "shifts": [estimated (dy, dx) or None per transition]}``."""
    problems = [case.problem(im) for im in images]
    plan = gradient_plan(case.kernel, problems[0].target.shape[:2])
    r0s = [_residual(p.target, p) for p in problems]
    fast = [solve(p, "fast").objective for p in problems]
    none = [float(np.mean(r * r)) for r in r0s]
    shifts = [phase_correlation_shift(a, b) for a, b in zip(images, images[1:])]
    out: dict[str, Any] = {"fast": fast, "none": none, "shifts": shifts, "series": {}}
    for strategy in strategies:
        if strategy == "reprojected" and known is None:
            continue
        s, state = Series(), None
        for f, p in enumerate(problems):
            start = None
            if f > 0 and strategy != "cold":
                t, prev = p.target, problems[f - 1].target
                if strategy == "warm":                      # the GPU's rule (shaders/fista.glsl)
                    change = np.moveaxis(t - prev, 2, 0)
                    start = FistaState(x=np.clip(state.x + change, 0.0, 1.0), y=state.y + change,
                                       momentum=state.momentum)
                else:
                    shift = known[f - 1] if strategy == "reprojected" else shifts[f - 1]
                    if shift is not None and shift != CUT:
                        start = FistaState(x=reproject(state.x, t, shift), y=reproject(state.y, t, shift),
                                           momentum=state.momentum)
            x, state = projected_gradient(p, k, plan, state=start, return_state=True)
            shown, obj, _ = guarded(x, p, r0s[f])
            s.objective.append(obj)
            s.ratio.append(obj / fast[f])
            s.jod.append(_jod(shown, p, case) if with_jod else None)
        out["series"][strategy] = s
    return out


def pan_sequence(case: Case, frames: int = 20, k: int = PAN_K, px: int = PAN_PX,
                 strategies: Sequence[str] = STRATEGIES, with_jod: bool = True) -> dict[str, Any]:
    """The pan (:func:`pan_targets`) through :func:`motion_sequence`; the known shift is ``(0, -px)``."""
    return motion_sequence(case, pan_targets(case, frames, px), [(0, -px)] * (frames - 1), k, strategies, with_jod)


def sequences(ctx, case: Case, frames: int, k: int = PAN_K, with_jod: bool = True) -> dict[str, dict[str, Any]]:
    """Every moving sequence of the bench (:data:`SEQUENCES`) through :func:`motion_sequence`."""
    cut_images, cut_at = cut_targets(case, frames)
    cut_known: list[Any] = [(0, -PAN_PX)] * (frames - 1)
    cut_known[cut_at - 1] = CUT
    turn_images, turn_known = head_turn_targets(ctx, case, frames)
    turn_known = [CUT if d is None else d for d in turn_known]
    runs = {"pan": (pan_targets(case, frames), [(0, -PAN_PX)] * (frames - 1)),
            "zoom": (zoom_targets(case, frames), None),
            "cut": (cut_images, cut_known),
            "head turn": (turn_images, turn_known)}
    out = {}
    for name, (images, known) in runs.items():
        out[name] = motion_sequence(case, images, known, k, STRATEGIES, with_jod)
        out[name]["known"] = known
        if name == "cut":
            out[name]["cut_at"] = cut_at
    return out


# --------------------------------------------------------------------------
# The GPU path: one point checked against the CPU twin, stage times on llvmpipe
# --------------------------------------------------------------------------


def _prescription():
    eye = EyeRx(**EYE)
    return Prescription(right=eye, left=eye)


def gpu_check(ctx, case: Case, k: int = 4, frames: int = 10) -> dict[str, float]:
    """``frames`` frames of the still image at ``k`` through the GPU ``Corrector`` (filter
    ``fista``) against the CPU twin: the GPU's own objective fraction of the last frame and the
    CPU's (``guarded``), and the largest difference between the two solutions."""
    image = case.still_u8
    size = (image.shape[1], image.shape[0])
    c = Corrector(ctx, _prescription(), case.display, "right", filter="fista", iterations_per_frame=k)
    src = upload_texture(ctx, np.ascontiguousarray(image))
    tex, fbo = render_target(ctx, width=size[0], height=size[1])
    try:
        for _ in range(frames):
            c.apply(src, fbo)
        gpu_fraction = c.last_objective_fraction(size)
        x_gpu = c.solution(size)
        p = case.problem(image)
        state = None
        for _ in range(frames):
            x, state = projected_gradient(p, k, state=state, return_state=True)
        r0 = _residual(p.target, p)
        _, obj, _ = guarded(x, p, r0)
        cpu_fraction = obj / float(np.mean(r0 * r0))
        return {"k": k, "frames": frames, "gpu_fraction": gpu_fraction, "cpu_fraction": cpu_fraction,
                "max_solution_difference": float(np.abs(x_gpu - x).max())}
    finally:
        c.release()
        release(fbo, tex, src)


STAGES = ("decode", "start", "iterations", "guard", "present")
STAGE_TITLES = {"decode": "decode", "start": "warm start + target T", "iterations": "k iterations",
                "guard": "guard", "present": "encode + present"}


def stage_ms(ctx, case: Case, size: int, ks: Sequence[int] = TIMING_KS, repeats: int = 3) -> list[dict[str, Any]]:
    """Milliseconds per stage of one eye's frame through the GPU ``Corrector`` (``fista``) at
    ``size x size``: ``glFinish`` then the clock after each stage (``Corrector.profile``); one
    warm-up frame (spectra and allocations), then the median of ``repeats`` frames per ``k`` (the
    warm start goes on across them, as it would)."""
    from skimage import data  # optional: scikit-image (bundled photographs)

    image = np.round(np.clip(prepare_image(getattr(data, PHOTO)()[..., :3], size, PHOTO), 0, 1) * 255
                     ).astype(np.uint8)
    c = Corrector(ctx, _prescription(), case.display, "right", filter="fista", iterations_per_frame=ks[0])
    src = upload_texture(ctx, image)
    tex, fbo = render_target(ctx, width=size, height=size)
    marks: list[tuple[str, float]] = []

    def hook(stage: str) -> None:
        ctx.finish()
        marks.append((stage, time.perf_counter()))

    rows = []
    try:
        c.apply(src, fbo)
        ctx.finish()
        c.profile = hook
        for k in ks:
            c.iterations_per_frame = k
            per: dict[str, list[float]] = {s: [] for s in STAGES + ("total",)}
            for _ in range(repeats):
                marks.clear()
                ctx.finish()
                t0 = last = time.perf_counter()
                c.apply(src, fbo)
                for stage, t in marks:
                    if stage in per:
                        per[stage].append(1e3 * (t - last))
                    last = t
                per["total"].append(1e3 * (last - t0))
            rows.append({"size": size, "k": k, **{s: statistics.median(v) for s, v in per.items()}})
    finally:
        c.profile = None
        c.release()
        release(fbo, tex, src)
    return rows


# --------------------------------------------------------------------------
# The GPU cost model
# --------------------------------------------------------------------------


def round_trip_bytes(grid: tuple[int, int], size: tuple[int, int], combine_images: int) -> int:
    """Bytes one FFT round trip of :class:`~vrcorrect.runtime.fft.FftBankGL` reads and writes:
    rows forward (the rgba32f image in, two complex layers out), columns forward, the 3x3 complex
    multiply (two layers in, the 9-entry complex spectrum, two layers out), columns and rows
    inverse (the image's window out), then the combine pass touching ``combine_images`` rgba32f
    images (its input included)."""
    n = grid[0] * grid[1]
    p = size[0] * size[1]
    layers = 2 * 8                                   # two complex64 layers per grid point
    return (16 * p + layers * n          # rows forward
            + 2 * layers * n             # columns forward (in place)
            + layers * n + 9 * 8 * n + layers * n    # multiply: in, the spectrum, out
            + 2 * layers * n             # columns inverse
            + layers * n + layers * p    # rows inverse: in, the window out
            + 16 * p * combine_images)   # combine


def cost_model(ks: Sequence[int], size: tuple[int, int] = HEADSET_EYE, margin: int = 32,
               bandwidth_GBps: float = FFT_BANDWIDTH["GBps"]) -> list[dict[str, Any]]:
    """Per eye and frame, for each ``k``: FFT round trips, 2D complex FFTs (each round trip is two
    forward and two inverse, the three channels packed as R + iG and B), bytes moved and the
    projected milliseconds at ``bandwidth_GBps``, in two forms.

    ``"phase A"``: what the GPU runs now, ``2k + 3`` round trips (per iteration ``K y - T`` and
    ``K^H r``; per frame ``T = K_ref t`` and the guard's ``K t - T`` and ``K x - T``).  ``"Gram"``:
    a step ``IFFT((K^H K) Y - K^H T)`` is one round trip, with ``K^H T`` once per frame, so ``k + 3``
    (it minimises the objective over the whole padded field, blur spilling onto the black surround
    included, not the cropped one).  Per frame both also decode (RGBA8 in, rgba32f out), start
    (four images in, three out), blend (three in, one out) and encode (one in, RGBA8 out)."""
    grid = fft_grid(size[0], size[1], margin)
    p = size[0] * size[1]
    frame_bytes = (4 + 16) * p + 16 * 7 * p + 16 * 5 * p + (16 + 4) * p   # decode, start, guard's blend, encode

    def trip(images: int) -> int:
        return round_trip_bytes(grid, size, images)

    # combine passes: a residual touches 4 images (filtered, input, T, out), a FISTA update 6 (filtered, input,
    # x and y read and written), the target T 3 (filtered, input, out)
    per_frame = trip(3) + 2 * trip(4) + frame_bytes        # T (or K^H T), the guard's K t - T and K x - T
    rows = []
    for form in ("phase A", "Gram"):
        for k in ks:
            if form == "phase A":
                trips = 2 * k + 3
                moved = k * (trip(4) + trip(6)) + per_frame
            else:
                trips = k + 3
                moved = k * trip(6) + per_frame
            rows.append({"form": form, "k": k, "round_trips": trips, "fft2d": 4 * trips, "grid": grid,
                         "GB": moved / 1e9, "ms": moved / (bandwidth_GBps * 1e9) * 1e3})
    return rows


# --------------------------------------------------------------------------
# The bench
# --------------------------------------------------------------------------


def _describe_motion(seq: dict) -> str:
    """The motion of a sequence in words: known shifts (or cut), and what phase correlation found."""
    def words(shifts) -> str:
        kinds = sorted({"cut" if d in (None, CUT) else f"({d[0]}, {d[1]})" for d in shifts})
        return ", ".join(kinds) if len(kinds) <= 4 else ", ".join(kinds[:4]) + f" and {len(kinds) - 4} more"

    known = seq.get("known")
    head = "not a shift" if known is None else f"known (dy, dx): {words(known)}"
    return f"{head}; estimated: {words(seq['shifts'])}"


def _fmt_jod(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _first_within(ratios: Sequence[float], bound: float = 1.05) -> str:
    for i, r in enumerate(ratios):
        if r <= bound:
            return str(i + 1)
    return f"> {len(ratios)}"


def run_realtime_bench(out: Path = Path("docs/benchmarks.md"), write: bool = True, quick: bool = False,
                       plot_still: Path | None = None, plot_pan: Path | None = None) -> str:
    """Run the four parts (see the module docstring); returns the Markdown and, with ``write``,
    writes the ``realtime`` section of ``out`` and the two plots beside it."""

    size, frames = (48, 4) if quick else (256, 20)
    still_ks = (1, 4) if quick else STILL_KS
    timing_sizes = (48,) if quick else (256, 512)
    timing_ks = (1,) if quick else TIMING_KS
    repeats = 1 if quick else 3
    check_frames = min(frames, 10)
    with_jod = not quick
    plot_still = plot_still or out.with_name("realtime_still.png")
    plot_pan = plot_pan or out.with_name("realtime_motion.png")

    steps = tqdm(total=5, desc="bench realtime", unit="part", leave=False)
    case = make_case(size, frames)
    still = still_convergence(case, still_ks, frames, with_jod)
    steps.update()
    ctx = headless_context(require=430)
    try:
        renderer = ctx.info.get("GL_RENDERER", "?")
        pan = sequences(ctx, case, frames, PAN_K, with_jod)
        steps.update()
        check = gpu_check(ctx, case, 4, check_frames)
        steps.update()
        timing = [row for s in timing_sizes for row in stage_ms(ctx, case, s, timing_ks, repeats)]
        steps.update()
    finally:
        ctx.release()

    headset = get_display("quest2")
    margin = max(build_kernel(EyeRx(**EYE), headset).size, build_reference_kernel(EyeRx(**EYE), headset).size)
    costs = cost_model(STILL_KS, HEADSET_EYE, margin)
    steps.update()
    steps.close()

    body = _markdown(case, still, pan, check, timing, costs, renderer, frames, quick, plot_still, plot_pan,
                     headset_margin=margin)
    if write:
        _plot_still(still, case, plot_still)
        _plot_pan(pan, case, plot_pan)
        write_section(out, "realtime", body)
    return body


def _markdown(case: Case, still: dict, pan: dict, check: dict, timing: list, costs: list, renderer: str,
              frames: int, quick: bool, plot_still: Path, plot_pan: Path, headset_margin: int) -> str:
    s = case.size
    eye = f"{EYE['sphere_D']:+.2f} / {EYE['cylinder_D']:+.2f} x {EYE['axis_deg']:g}, {EYE['pupil_diameter_mm']:g} mm pupil"
    shown_frames = [f for f in (1, 2, 5, 10, 20) if f <= frames]
    rows = []
    for k, ser in still["series"].items():
        rows.append([k, *(f"{ser.ratio[f - 1]:.3f}" for f in shown_frames), _first_within(ser.ratio),
                     *(_fmt_jod(ser.jod[f - 1]) for f in shown_frames if f in (1, 10, 20) or f == frames)])
    jod_cols = [f"JOD f{f}" for f in shown_frames if f in (1, 10, 20) or f == frames]
    still_table = markdown_table(["k", *(f"f{f} / fast" for f in shown_frames), "frames to <= 1.05", *jod_cols], rows)
    none_ratio = still["none"] / still["fast"]
    check_line = (f"GPU check (k = {check['k']}, frame {check['frames']}, the same image through the GPU `Corrector` "
                  f"on {renderer}): objective {check['gpu_fraction']:.4f} of uncorrected (the GPU's own reduction) "
                  f"against the CPU twin's {check['cpu_fraction']:.4f} (difference "
                  f"{abs(check['gpu_fraction'] - check['cpu_fraction']):.1e}); the solutions differ by at most "
                  f"{check['max_solution_difference']:.1e} in linear light.")

    pan_frames = [f for f in (1, 2, 5, 10, 20) if f <= frames]
    tail_from = min(10, frames)
    prow = []
    for name, seq in pan.items():
        for strategy, ser in seq["series"].items():
            tail = ser.ratio[tail_from - 1:]
            jods = [j for j in ser.jod[tail_from - 1:] if j is not None]
            worse = sum(o > n for o, n in zip(ser.objective, seq["none"]))
            prow.append([name, STRATEGY_TITLES[strategy], *(f"{ser.ratio[f - 1]:.3f}" for f in pan_frames),
                         f"{statistics.median(tail):.3f}", f"{max(tail):.3f}",
                         _fmt_jod(statistics.median(jods) if jods else None), worse])
    pan_table = markdown_table(["sequence", "start", *(f"f{f} / fast" for f in pan_frames), f"median f{tail_from}+",
                                f"worst f{tail_from}+", f"JOD median f{tail_from}+", "frames worse than uncorrected"],
                               prow)
    none_rows = [[name, f"{statistics.median(n / f for n, f in zip(seq['none'], seq['fast'])):.2f}",
                  _describe_motion(seq)] for name, seq in pan.items()]
    none_table = markdown_table(["sequence", "uncorrected / fast (median)", "motion"], none_rows)

    trow = []
    for r in timing:
        trow.append([f"{r['size']}x{r['size']}", r["k"], *(f"{r[st]:.0f}" for st in STAGES),
                     f"{r['iterations'] / r['k']:.0f}", f"{r['total']:.0f}"])
    timing_table = markdown_table(["size", "k", *(STAGE_TITLES[st] + " ms" for st in STAGES), "ms per iteration",
                                   "frame ms"], trow)

    crow = [[c["form"], c["k"], c["round_trips"], c["fft2d"], f"{c['GB']:.1f}", f"{c['ms']:.1f}"] for c in costs]
    grid = costs[0]["grid"]
    cost_table = markdown_table(["form", "k", "FFT round trips", "2D complex FFTs of the grid", "GB moved",
                                 f"projected ms ({FFT_BANDWIDTH['gpu']})"], crow)
    k4 = {c["form"]: c for c in costs if c["k"] == 4}
    spectrum_share = 9 * 8 * grid[0] * grid[1] / round_trip_bytes(grid, HEADSET_EYE, 4)
    bw = FFT_BANDWIDTH["GBps"]

    body = (
        "## Real-time projected gradient (FISTA) over frames\n\n"
        f"Machine: {machine_description()}; OpenGL renderer: {renderer}.\n"
        f"Eye {eye} on the `{case.display.name}` preset; target: what the eye sees with its glasses (the "
        f"project's default); scikit-image's {PHOTO} at {s}x{s}." + (" **Quick run (tiny sizes).**" if quick else "")
        + "\n\n"
        "### Still image: convergence over frames\n\n"
        f"Each frame runs k projected-gradient (FISTA) iterations continued from the last frame, then the guard "
        f"(the best blend with the target), as the GPU does. The figures come from the CPU twin "
        f"(`solvers.wiener.projected_gradient` continued from its state), which equals the GPU iteration to about "
        f"5e-7 per step (`tests/test_runtime_fista.py`); {check_line}\n\n"
        f"Objective of the displayed frame relative to `fast`'s ({still['fast']:.3e}; uncorrected is "
        f"{none_ratio:.2f}x `fast`), and JOD of what the eye sees (uncorrected {_fmt_jod(still['none_jod'])}, "
        f"`fast` {_fmt_jod(still['fast_jod'])}):\n\n"
        + still_table + f"\n\n![still image]({plot_still.name})\n\n"
        f"### Moving sequences, k = {PAN_K}\n\n"
        f"{frames} frames of {s}x{s} each; every frame's objective relative to `fast` on that frame (the "
        "converged CPU optimum of that frame), for four ways to start the frame's iterations. Plain warm start "
        "continues from the last solution as it was, moved only by the change of the target "
        "(`shaders/fista.glsl` with no motion); reprojection moves the previous solution (and FISTA's "
        "extrapolated point) by the content's shift and fills the exposed pixels from the new target, and "
        "starts cold at a cut: the known motion is what the application knows (the pan's step, the cut, the "
        "change of the tracked eye's pose by `runtime.motion.view_shift`, as `vrcorrect xr` does), the "
        "estimate is phase correlation of consecutive frames (`runtime.motion.motion_for`, what the mirror, the "
        "overlay and xr run for picture sources). A zoom is not a shift: it has no known-shift run. CPU twin "
        "(the GPU's reprojection equals it, `tests/test_runtime_motion.py`).\n\n"
        + none_table + "\n\n" + pan_table + f"\n\n![moving sequences]({plot_pan.name})\n\n"
        "### llvmpipe: ms per frame per stage (one eye)\n\n"
        f"Measured through the GPU `Corrector` (`filter=\"fista\"`) on {renderer}, the Mesa software rasteriser "
        f"on this machine's {os.cpu_count()} CPU cores (shared with other jobs: noisy), `glFinish` after each "
        f"stage, median of {3 if not quick else 1} frames after a warm-up frame. A frame runs 2k + 3 FFT round "
        "trips; on llvmpipe these are seconds, not milliseconds: a software renderer, not a projection of a "
        "GPU.\n\n"
        + timing_table + "\n\n"
        "### GPU cost model per eye: 1832 x 1920 (Quest 2), a projection, not a measurement\n\n"
        f"FFT grid {grid[1]}x{grid[0]} (the image plus the eye's {headset_margin} px kernel margin on the quest2 "
        "preset, padded to powers of two). Bytes counted pass by pass as the shaders run them "
        "(`vrcorrect.apps.bench.realtime.round_trip_bytes`): each round trip reads and writes the grid's two complex64 layers "
        "in every FFT pass and reads the 3x3 complex spectrum (72 bytes per grid point) in the multiply, "
        "plus the per-frame decode, warm start, guard and encode. Projected at "
        f"{bw / 1e3:.2f} TB/s: {FFT_BANDWIDTH['what']}. That assumes these shaders move bytes as fast as a "
        "tuned FFT library does; a measured figure needs a GPU (this machine has none).\n\n"
        + cost_table + "\n\n"
        f"The issue's target, k = 4 at <= 2 ms per eye, is not met by this projection: {k4['phase A']['ms']:.1f} ms "
        f"in phase A's form and {k4['Gram']['ms']:.1f} ms in Gram form on an {FFT_BANDWIDTH['gpu']}. The 3x3 "
        f"complex spectrum read in every multiply is {spectrum_share:.0%} of a round trip's bytes; a "
        "real-to-complex half spectrum, half-precision spectra and the multiply fused into the column pass (as "
        "VkFFT's convolutions do) would cut that, by an amount this model does not claim; none of it is built.\n"
    )
    return body


def _plot_still(still: dict, case: Case, path: Path) -> None:
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for k, ser in still["series"].items():
        n = range(1, len(ser.ratio) + 1)
        a.plot(n, ser.ratio, "o-", ms=3, label=f"k = {k}")
        if ser.jod[0] is not None:
            b.plot(n, ser.jod, "o-", ms=3, label=f"k = {k}")
    a.axhline(1.0, color="k", lw=0.8, label="fast")
    a.axhline(still["none"] / still["fast"], color="grey", ls="--", lw=0.8, label="uncorrected")
    a.set_yscale("log")
    a.set_xlabel("frame")
    a.set_ylabel("objective / fast's")
    a.set_title("objective of the displayed frame", fontsize=9)
    a.legend(fontsize=7)
    if still["fast_jod"] is not None:
        b.axhline(still["fast_jod"], color="k", lw=0.8, label="fast")
        b.axhline(still["none_jod"], color="grey", ls="--", lw=0.8, label="uncorrected")
    b.set_xlabel("frame")
    b.set_ylabel("JOD of what the eye sees (10 = as with glasses)")
    b.set_title("ColorVideoVDP", fontsize=9)
    if still["fast_jod"] is not None:
        b.legend(fontsize=7)
    fig.suptitle(f"Still {PHOTO} {case.size}x{case.size}, {case.display.name}, eye {EYE['sphere_D']:+.2f} / "
                 f"{EYE['cylinder_D']:+.2f} x {EYE['axis_deg']:g}: k FISTA iterations per frame, warm-started",
                 fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def _plot_pan(pan: dict, case: Case, path: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, len(pan), figsize=(4 * len(pan), 3.8), sharey=True)
    axes = np.atleast_1d(axes)
    for a, (name, seq) in zip(axes, pan.items()):
        for strategy, ser in seq["series"].items():
            n = range(1, len(ser.ratio) + 1)
            style = "--" if strategy == "estimated" else "-"
            a.plot(n, ser.ratio, style, marker="o", ms=2.5, label=STRATEGY_TITLES[strategy])
        a.plot(range(1, len(seq["none"]) + 1), [u / f for u, f in zip(seq["none"], seq["fast"])], ":", color="grey",
               label="uncorrected")
        if "cut_at" in seq:
            a.axvline(seq["cut_at"] + 1, color="red", lw=0.8)
        a.axhline(1.0, color="k", lw=0.8)
        a.set_yscale("log")
        a.set_xlabel("frame")
        a.set_title(name, fontsize=9)
    axes[0].set_ylabel("objective / fast's on that frame")
    axes[0].legend(fontsize=6)
    fig.suptitle(f"Moving sequences, {case.size}x{case.size}, k = {PAN_K} FISTA iterations per frame", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
