"""The real-time correction where the eye looks: the CPU twin of a foveated frame (issue 45).

Acuity falls steeply away from the fovea, so the full correction is solved only on a *window*
around the gaze, a square of half-side ``radius_px`` (a radius in degrees times the display's
pixels per degree), and the rest of the view shows the *periphery*: the target itself, or a
correction of the whole view at half or a quarter of the resolution.

* **The sub-problem.**  The real-time ADMM (:class:`~vrcorrect.solvers.realtime.AdmmFrames`) runs on
  a sub-image: the window plus a *ring* as wide as the kernel's radius on each side that lies inside
  the image.  The data term holds on the window's retina only.  The ring's pixels are held to the
  periphery (their box is ``[p, p]``): the light that reaches the window's retina from outside it
  is modelled as what is really shown there, not as black.  Past the image's own edges the grid's
  surround is black, as in the full-field twin.  The sub-image keeps one size (it is moved, not
  shrunk, where the window meets the image's edge), so one grid serves every gaze.
* **The blend.**  The solution is shown inside the window, faded to the periphery over a band
  (``band_px``, a raised cosine) along the window's edges that lie inside the image: no seam.
  Outside the window the view is the periphery, exactly.
* **The periphery** (``periphery="half"`` or ``"quarter"``): the full-field twin on the view's 2x2
  (or twice 2x2) block means with the kernels such blocks see, warm-started, guarded; its change
  from the block means upsampled bilinearly (once or twice) onto the target, clipped to [0, 1].
* **The guard.**  As the full-field twin's, on the sub-image: the window's correction is scaled by the
  weight that minimises the objective over the sub-image's retina, so it is never worse than none
  there.
* **The gaze moves.**  The sub-image moves with the window; its state is reprojected by the window's
  motion (the content, fixed in the view, moves the other way inside the sub-image) plus the
  content's own motion, as the full-field twin reprojects content motion.  A move of the whole
  sub-image or more starts cold.
* **Cold frames** start from the target (no half-resolution level: it would not know the window)
  and run :data:`COLD_WINDOW_ITERATIONS` more iterations; the periphery's cold frames run
  :data:`COLD_PERIPHERY_ITERATIONS`.

With the window as large as the view, a frame equals the full-field twin's (``tests/test_foveated.py``).

The GPU's foveated frame (:mod:`vrcorrect.runtime.strategies.foveated`) equals this twin to 2e-5
(``tests/test_runtime_fovea.py``).  Not yet (issue 45): the gaze from OpenXR and the frame budget.

Layer 4: numpy and scipy.fft; no torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..physics.kernel import EyeKernel
from ..plumbing.errors import ValidationError
from ..specs.vocabulary import PERIPHERY_LEVELS, Precision, names
from .problem import light_cap
from .realtime import (
    ADMM_BALANCE,
    ADMM_RELAXATION,
    ADMM_RHO,
    AdmmFrame,
    AdmmFrames,
    _frame_target,
    _store,
    admm_grid,
    coarse_eye_kernel,
    pool_half,
    upsample_double,
)

__all__ = ["FoveaWindow", "fovea_window", "blend_ramp", "FoveatedFrames", "FoveatedFrame", "foveated_grid",
           "PERIPHERIES", "BAND_FRACTION", "MIN_BAND_PX", "COLD_WINDOW_ITERATIONS", "COLD_PERIPHERY_ITERATIONS",
           "fovea_pixels"]

BAND_FRACTION = 0.1
"""The blend band's width as a fraction of the fovea's radius.  The band lies *outside* the radius:
the window solved is the radius plus the band, so that everything within the radius is the full
correction and the fade to the periphery happens beyond it.  (With the band a quarter of the radius
and inside it, 44 % of the window's area was a fade to the periphery, and a quarter-resolution
periphery cost the window's crop 0.14-0.28 JOD against the full field; ``bench fovea``.)  A tenth
keeps a Quest 2 eye at 15 degrees under 0.5 GB a frame (``bench cost --fovea 15``)."""
MIN_BAND_PX = 4
"""The narrowest band, pixels."""
COLD_WINDOW_ITERATIONS = 8
"""The iterations a cold window runs beyond the frame's own (the first frame, a cut, a jump of the
gaze).  The window has no coarse level to start from, so without them it starts from the target and
takes about five frames to converge, which a judge of video sees.  Chosen on the tuning suite
(``suite``'s ``sprite`` and ``cut`` at 960 px, 30 frames of 2 iterations, quest2, the bench's eye,
the periphery's cold frames at :data:`COLD_PERIPHERY_ITERATIONS`) by the objective: the mean over
the frames of the objective as a fraction of none's, with 0, 4 and 8 of them, was 0.4873, 0.4812 and
0.4793 (sprite) and 0.6068, 0.6036 and 0.6034 (cut).  FovVideoVDP at the gaze, as video, foveated
less full field: -0.27, -0.11, -0.07 (sprite) and -0.19, -0.13, -0.12 (cut).  A cold foveated frame
then costs about twice a changing one, as the full field's cold frame (its coarse level) does
(``bench cost --fovea``); a changing frame costs what it did."""
COLD_PERIPHERY_ITERATIONS = 8
"""The iterations the periphery's correction runs on its cold frames (at least its own a frame).  At
a quarter of the resolution, 2 a frame took about five frames to converge; 8 take one.  On the tuning
suite the mean objective fell from 0.4895 to 0.4873 (sprite) and from 0.6105 to 0.6068 (cut) with the
window's cold iterations off.  A quarter-resolution iteration moves a sixteenth of a full one's bytes."""


def fovea_pixels(radius_deg: float, ppd: float) -> tuple[int, int]:
    """A fovea of ``radius_deg`` at ``ppd`` pixels a degree as ``(radius_px, band_px)``: the half-side
    of the window solved (the fovea's radius plus the band) and the band faded to the periphery
    along its edges (:data:`BAND_FRACTION` of the radius, at least :data:`MIN_BAND_PX`)."""
    nominal = max(int(round(float(radius_deg) * float(ppd))), 1)
    band = max(int(round(BAND_FRACTION * nominal)), MIN_BAND_PX)
    return nominal + band, band

PERIPHERIES: tuple[str, ...] = names(PERIPHERY_LEVELS)
"""What the view shows outside the window: the target itself, or a half- or quarter-resolution
correction of the whole view (the real-time frame on the target's 2x2 or 4x4 block means, its change
upsampled)."""


@dataclass(frozen=True)
class FoveaWindow:
    """Where a foveated frame solves, in the view's pixels (rows ``y``, columns ``x``, half-open):
    the sub-image ``sub`` (the window and its ring) and the window ``win`` inside it, both
    ``(y0, y1, x0, x1)``."""

    sub: tuple[int, int, int, int]
    win: tuple[int, int, int, int]

    @property
    def sub_shape(self) -> tuple[int, int]:
        return self.sub[1] - self.sub[0], self.sub[3] - self.sub[2]


def _check_radius(radius_px: float) -> int:
    if not (isinstance(radius_px, (int, float)) and math.isfinite(radius_px) and radius_px >= 1):
        raise ValidationError("radius_px", radius_px, "a window half-side of at least 1 pixel")
    return int(round(radius_px))


def fovea_window(shape: tuple[int, int], gaze_px: tuple[float, float], radius_px: float, ring: int) -> FoveaWindow:
    """The window around ``gaze_px`` (``(x, y)`` in the view's pixels, clamped into the view) of
    half-side ``radius_px``, clipped to the view, and the sub-image that holds it with a ``ring``
    of pixels on each side, of one size for every gaze (moved inside the view where it would cross
    an edge)."""
    H, W = (int(v) for v in shape)
    r = _check_radius(radius_px)
    gx = min(max(float(gaze_px[0]), 0.0), W - 1.0)
    gy = min(max(float(gaze_px[1]), 0.0), H - 1.0)
    cx, cy = int(math.floor(gx)), int(math.floor(gy))
    win = (max(cy - r, 0), min(cy + r, H), max(cx - r, 0), min(cx + r, W))
    sh, sw = min(2 * (r + ring), H), min(2 * (r + ring), W)
    sy0 = min(max(cy - r - ring, 0), H - sh)
    sx0 = min(max(cx - r - ring, 0), W - sw)
    return FoveaWindow(sub=(sy0, sy0 + sh, sx0, sx0 + sw), win=win)


def blend_ramp(window: FoveaWindow, shape: tuple[int, int], band_px: int) -> np.ndarray:
    """The weight of the solution inside the window, ``(h, w)`` of the window: 1 in its middle,
    falling as a raised cosine to 0 over ``band_px`` along each edge that lies inside the view (an
    edge on the view's own border needs no fade)."""
    H, W = shape
    y0, y1, x0, x1 = window.win

    def axis(lo: int, hi: int, n: int) -> np.ndarray:
        i = np.arange(lo, hi, dtype=np.float64)
        ramp = np.ones(hi - lo)
        if band_px > 0:
            if lo > 0:
                ramp = np.minimum(ramp, np.clip((i - lo + 0.5) / band_px, 0.0, 1.0))
            if hi < n:
                ramp = np.minimum(ramp, np.clip((hi - 0.5 - i) / band_px, 0.0, 1.0))
        return 0.5 - 0.5 * np.cos(np.pi * ramp)

    return np.outer(axis(y0, y1, H), axis(x0, x1, W)).astype(np.float32)


def foveated_grid(shape: tuple[int, int], radius_px: float, kernel_size: int) -> tuple[int, int]:
    """The FFT grid a foveated frame solves on (:func:`~vrcorrect.solvers.realtime.admm_grid` of the
    sub-image), for counting what it costs against the full field's."""
    ring = kernel_size // 2
    r = _check_radius(radius_px)
    H, W = shape
    return admm_grid(min(2 * (r + ring), W), min(2 * (r + ring), H), kernel_size)


class _WindowTwin(AdmmFrames):
    """The full-field twin on the sub-image, with the data term on the window only and the ring's
    box held to the target."""

    def set_window(self, sub_window: tuple[int, int, int, int]) -> None:
        y0, y1, x0, x1 = sub_window
        H, W = self.shape
        self.inside = np.zeros(self.grid, bool)
        self.inside[y0:y1, x0:x1] = True
        self.held = np.zeros(self.grid, bool)
        self.held[:H, :W] = True
        self.held[y0:y1, x0:x1] = False
        self.fixed = np.zeros((3,) + self.grid, np.float32)

    def hold(self, t: np.ndarray) -> None:
        """The ring's values this frame, ``(3, h, w)`` as stored: what the view shows there."""
        H, W = self.shape
        self.fixed[:, :H, :W] = t

    def proj(self, q: np.ndarray) -> np.ndarray:
        z = super().proj(q)
        z[:, self.held] = self.fixed[:, self.held]
        return z


@dataclass
class FoveatedFrame:
    """One foveated frame: the view shown (``(H, W, 3)`` float32), the window it was solved on, and
    the sub-image's frame (its guard's weight and objectives, over the sub-image's retina)."""

    shown: np.ndarray
    window: FoveaWindow
    sub: AdmmFrame
    periphery: np.ndarray | None = None         # the half-resolution correction shown outside, (H, W, 3)


class FoveatedFrames:
    """Foveated ADMM over frames for one eye and view size (module docstring).

    Parameters
    ----------
    kernel, reference
        As :class:`~vrcorrect.solvers.realtime.AdmmFrames`'.
    shape
        The view's ``(H, W)``.
    radius_px
        The window's half-side in pixels (a radius in degrees times the display's pixels per degree).
    band_px
        The blend band's width (default: a quarter of the radius, at least 4 pixels, at most the radius).
    precision, rho, relaxation, balance
        As the full-field twin's.
    periphery
        ``"target"`` (default): the view outside the window is the target; ``"half"`` or
        ``"quarter"``: a correction of the whole view at half or a quarter of the resolution
        (:class:`AdmmFrames` on the target's 2x2 or 4x4 block means with the kernels such blocks
        see, warm-started from frame to frame; its change from the block means upsampled bilinearly
        onto the target), which the window's ring is held to and the blend fades to.
    periphery_iterations
        Its ADMM iterations a frame (None: the window's).
    cold_window_iterations, cold_periphery_iterations
        The window's iterations beyond the frame's on a cold frame (:data:`COLD_WINDOW_ITERATIONS`),
        and the periphery's on its cold frames, at least its own (:data:`COLD_PERIPHERY_ITERATIONS`).
    cap
        The box's upper end is the target's light cap (a robust design's, as the full-field twin's
        ``cap``): in the window, in the periphery and in what the view shows of it.
    """

    def __init__(self, kernel: EyeKernel, reference: EyeKernel | None, shape: tuple[int, int], radius_px: float,
                 band_px: int | None = None, precision: str = Precision.HALF, rho: float = ADMM_RHO,
                 relaxation: float = ADMM_RELAXATION, balance: float = ADMM_BALANCE, periphery: str = "target",
                 periphery_iterations: int | None = None, cold_window_iterations: int = COLD_WINDOW_ITERATIONS,
                 cold_periphery_iterations: int = COLD_PERIPHERY_ITERATIONS, cap: bool = False):
        r = _check_radius(radius_px)
        for name, v in (("cold_window_iterations", cold_window_iterations),
                        ("cold_periphery_iterations", cold_periphery_iterations)):
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 0):
                raise ValidationError(name, v, "a whole number of iterations, 0 or more")
        self.cold_window_iterations, self.cold_periphery_iterations = cold_window_iterations, cold_periphery_iterations
        if periphery not in PERIPHERIES:
            raise ValidationError("periphery", periphery, " or ".join(PERIPHERIES))
        if band_px is None:
            band_px = min(max(r // 4, 4), r)
        if not (isinstance(band_px, int) and 0 <= band_px <= r):
            raise ValidationError("band_px", band_px, f"a whole number of pixels from 0 to the radius ({r})")
        H, W = (int(v) for v in shape)
        self.shape, self.radius_px, self.band_px = (H, W), r, band_px
        self.ring = max(kernel.size, reference.size if reference is not None else 1) // 2
        self._kernel, self._reference = kernel, reference
        self._options = {"precision": precision, "rho": rho, "relaxation": relaxation, "balance": balance,
                         "cap": bool(cap)}
        self.twin: _WindowTwin | None = None
        self.window: FoveaWindow | None = None
        self.periphery = periphery
        self.periphery_iterations = periphery_iterations
        self.coarse = None
        self.levels = PERIPHERY_LEVELS[periphery]
        if self.levels:
            k, ref, shape = kernel, reference, (H, W)
            self._shapes = [shape]
            for _ in range(self.levels):
                k, ref = coarse_eye_kernel(k), None if ref is None else coarse_eye_kernel(ref)
                shape = ((shape[0] + 1) // 2, (shape[1] + 1) // 2)
                self._shapes.append(shape)
            self.coarse = AdmmFrames(k, ref, shape, cold_iterations=0, **self._options)

    def reset(self) -> None:
        """The next frame starts cold."""
        if self.twin is not None:
            self.twin.reset()
        if self.coarse is not None:
            self.coarse.reset()

    def frame(self, target: np.ndarray, iterations: int, gaze_px: tuple[float, float],
              shift: tuple[int, int] | None = None, cold: bool = False) -> FoveatedFrame:
        """One frame: ``target`` ``(H, W, 3)`` linear RGB in [0, 1], ``iterations`` ADMM iterations on
        the window around ``gaze_px`` (``(x, y)`` pixels), warm-started across the window's motion
        and the content's (``shift``: ``(dx, dy)`` whole pixels, x right, y down), then the guard and
        the blend."""
        H, W = self.shape
        t_full = _frame_target(target, self.shape)
        window = fovea_window(self.shape, gaze_px, self.radius_px, self.ring)
        sy0, sy1, sx0, sx1 = window.sub
        inner = (window.win[0] - sy0, window.win[1] - sy0, window.win[2] - sx0, window.win[3] - sx0)
        if self.twin is None:
            self.twin = _WindowTwin(self._kernel, self._reference, window.sub_shape, cold_iterations=0,
                                    **self._options)
        twin = self.twin
        move = (0, 0)
        if self.window is not None:
            move = (sx0 - self.window.sub[2], sy0 - self.window.sub[0])
        content = (0, 0) if shift is None else (int(shift[0]), int(shift[1]))
        total = (content[0] - move[0], content[1] - move[1])
        if cold or abs(total[0]) >= window.sub_shape[1] or abs(total[1]) >= window.sub_shape[0]:
            twin.reset()
        twin.set_window(inner)
        outside = t_full                                   # what the view shows outside the window, (3, H, W)
        periphery = None
        if self.coarse is not None:
            pooled = t_full
            for _ in range(self.levels):
                pooled = pool_half(pooled)
            scale = 2 ** self.levels
            half = (int(round(content[0] / scale)), int(round(content[1] / scale)))
            k = iterations if self.periphery_iterations is None else self.periphery_iterations
            if cold or self.coarse.w is None:
                k = max(k, self.cold_periphery_iterations)
            c = self.coarse.frame(np.moveaxis(pooled, 0, 2), k, shift=half if half != (0, 0) else None,
                                  cold=cold)
            change = np.moveaxis(c.shown, 2, 0) - pooled
            for shape in self._shapes[-2::-1]:
                change = upsample_double(change, shape)
            top = light_cap(t_full) if self._options["cap"] else 1.0
            outside = np.clip(t_full + change, 0.0, top).astype(np.float32)
            periphery = np.ascontiguousarray(np.moveaxis(outside, 0, 2))
        t = np.ascontiguousarray(t_full[:, sy0:sy1, sx0:sx1])
        t_stored, T, T_inside = twin._targets(t)
        twin.hold(t_stored if self.coarse is None else
                  _store_like(np.ascontiguousarray(outside[:, sy0:sy1, sx0:sx1]), twin))
        window_cold = twin.w is None
        twin.start(t_stored, T, total if total != (0, 0) else None)
        for _ in range(iterations + (self.cold_window_iterations if window_cold else 0)):
            twin.iterate(T)
        sub = twin.guard(t_stored, T_inside)
        self.window = window
        shown = np.ascontiguousarray(np.moveaxis(outside, 0, 2)).copy()
        y0, y1, x0, x1 = window.win
        ramp = blend_ramp(window, self.shape, self.band_px)[..., None]
        inside = sub.shown[inner[0]:inner[1], inner[2]:inner[3]]
        blended = shown[y0:y1, x0:x1] + ramp * (inside - shown[y0:y1, x0:x1])
        shown[y0:y1, x0:x1] = np.where(ramp >= 1.0, inside, blended)        # the solution itself, unrounded
        return FoveatedFrame(shown=shown, window=window, sub=sub, periphery=periphery)


def _store_like(a: np.ndarray, twin: AdmmFrames) -> np.ndarray:
    """``a`` as ``twin`` stores its state (16-bit floats, rounded to nearest, where it is half)."""

    return _store(a, twin.half)
