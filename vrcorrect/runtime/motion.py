"""The global motion between consecutive frames of a CPU source, for the reprojected warm start of
``Corrector(filter="fista")`` (:meth:`~vrcorrect.runtime.corrector.Corrector.apply`'s
``motion_px``).

:func:`estimate_shift` finds the whole-pixel shift of the content from one frame to the next by
phase correlation of their luminance (Hann-windowed against the frame's edges; large frames are
box-downsampled to at most :data:`MAX_SIDE` px on the long side first, and the shift scaled back).
The height of the correlation peak is its confidence: about 1 for a pure shift, near 0 for two
unrelated images; below :data:`CUT_CONFIDENCE` the frames are taken as a scene cut, and the
corrector starts cold (:func:`motion_for`).  A 3D scene rendered on the GPU (the mirror's demo)
is not a global shift and is not estimated here.

Layer 5: numpy only (``numpy.fft``); never torch.
"""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError

__all__ = ["MAX_SIDE", "CUT_CONFIDENCE", "estimate_shift", "motion_for", "MotionTracker"]

MAX_SIDE = 256
"""Frames larger than this on the long side are downsampled (by a whole factor) before the FFT."""

CUT_CONFIDENCE = 0.2
"""Below this phase-correlation peak the two frames are taken as unrelated (a scene cut).  Measured
on the bundled images at 128 px: a shift of a few pixels of a photograph peaks at about 0.93 (the
window and the exposed border lower it from 1), pairs of unrelated images at 0.04 to 0.10
(tests/test_runtime_motion.py)."""

_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _luminance(image: np.ndarray, factor: int) -> np.ndarray:
    a = np.asarray(image)
    a = a.astype(np.float64)
    y = a[..., :3] @ _LUMA if a.ndim == 3 and a.shape[2] >= 3 else (a[..., 0] if a.ndim == 3 else a)
    if factor > 1:
        h, w = (y.shape[0] // factor) * factor, (y.shape[1] // factor) * factor
        y = y[:h, :w].reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3))
    return y


def estimate_shift(prev: np.ndarray, new: np.ndarray, max_side: int = MAX_SIDE) -> tuple[int, int, float]:
    """The whole-pixel displacement ``(dx, dy)`` of the content from ``prev`` to ``new`` (x to the
    right, y down, rows top first: ``new(p) ~ prev(p - d)``) and the confidence of the estimate, the
    normalised phase-correlation peak in [0, 1].  ``prev`` and ``new``: ``(H, W)`` or ``(H, W, C)``
    arrays of the same shape, any numeric type (sRGB codes are fine).  Frames longer than
    ``max_side`` are downsampled by a whole factor first; the shift is scaled back and rounded, so
    it is then a multiple of that factor."""
    a, b = np.asarray(prev), np.asarray(new)
    if a.shape != b.shape or a.ndim not in (2, 3) or min(a.shape[:2]) < 2:
        raise ValidationError("new.shape", b.shape, f"the shape of prev, {a.shape}, as (H, W) or (H, W, C) with "
                              "H, W >= 2")
    factor = max(1, -(-max(a.shape[:2]) // max_side))
    ya, yb = _luminance(a, factor), _luminance(b, factor)
    h, w = ya.shape
    win = np.outer(np.hanning(h), np.hanning(w))
    fa = np.fft.fft2((ya - ya.mean()) * win)
    fb = np.fft.fft2((yb - yb.mean()) * win)
    cross = fb * np.conj(fa)
    mag = np.abs(cross)
    if not np.any(mag > 1e-12 * max(float(mag.max()), 1e-300)):
        return 0, 0, 0.0                                  # a flat frame: nothing to correlate
    r = np.fft.ifft2(cross / np.maximum(mag, 1e-12)).real
    iy, ix = np.unravel_index(int(np.argmax(r)), r.shape)
    dy = int(iy) - h if iy > h // 2 else int(iy)
    dx = int(ix) - w if ix > w // 2 else int(ix)
    confidence = float(np.clip(r[iy, ix], 0.0, 1.0))
    return dx * factor, dy * factor, confidence


def motion_for(prev: np.ndarray | None, new: np.ndarray, scale: tuple[float, float] = (1.0, 1.0),
               cut_confidence: float = CUT_CONFIDENCE) -> tuple[int, int] | None:
    """The ``motion_px`` to pass to ``Corrector.apply`` for a source frame ``new`` after ``prev``:
    ``(dx, dy)`` scaled by ``scale`` (source pixels to displayed pixels) and rounded; ``None`` for a
    scene cut (confidence below ``cut_confidence``, a change of size, or no previous frame): the
    caller then calls ``Corrector.reset()``."""
    if prev is None or np.shape(prev) != np.shape(new):
        return None
    dx, dy, confidence = estimate_shift(prev, new)
    if confidence < cut_confidence:
        return None
    return int(round(dx * scale[0])), int(round(dy * scale[1]))


class MotionTracker:
    """A source's motion from frame to frame (what :class:`~vrcorrect.runtime.scene._PictureSource`
    keeps): :meth:`new_frame` with each new picture; :meth:`take` once per displayed frame returns
    ``(0, 0)`` (nothing new), ``(dx, dy)`` or ``"cut"`` and clears it."""

    def __init__(self) -> None:
        self._prev: np.ndarray | None = None
        self._pending: tuple[int, int] | str = (0, 0)

    def new_frame(self, image: np.ndarray, scale: tuple[float, float] = (1.0, 1.0)) -> None:
        first = self._prev is None
        motion = motion_for(self._prev, image, scale)
        self._prev = np.array(image, copy=True)
        if first:
            return                       # the corrector's first frame is a cold start anyway
        if motion is None:
            self._pending = "cut"
        elif self._pending != "cut":
            px, py = self._pending
            self._pending = (px + motion[0], py + motion[1])

    def take(self) -> tuple[int, int] | str:
        out, self._pending = self._pending, (0, 0)
        return out
