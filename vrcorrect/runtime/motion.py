"""The global motion between consecutive frames of a CPU source, for the reprojected warm start of
``Corrector(filter="fista")`` (:meth:`~vrcorrect.runtime.corrector.Corrector.apply`'s
``motion_px``).

:func:`estimate_shift` finds the whole-pixel shift of the content from one frame to the next by
phase correlation of their luminance (Hann-windowed against the frame's edges; large frames are
box-downsampled to at most :data:`MAX_SIDE` px on the long side first, and the shift scaled back).
The height of the correlation peak is its confidence: about 1 for a pure shift, near 0 for two
unrelated images; below :data:`CUT_CONFIDENCE` the frames are taken as a scene cut, and the
corrector starts cold (:func:`motion_for`).

Where the motion is known it is used instead: :func:`view_shift` turns the change of an eye's
tracked orientation between two frames (a head turn in ``vrcorrect xr``) into the shift of the
content at the centre of the view, as asynchronous timewarp reprojects a frame by the rotation.
Translation (parallax) and objects that move in the scene are not modelled: they leave a residual
the iterations and the guard absorb.

Layer 5: numpy only (``numpy.fft``); never torch.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..plumbing.errors import ValidationError

__all__ = ["MAX_SIDE", "CUT_CONFIDENCE", "estimate_shift", "motion_for", "MotionTracker", "view_shift"]

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


def _as_matrix(m: npt.ArrayLike, field: str) -> np.ndarray:
    a = np.asarray(m, dtype=np.float64)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise ValidationError(field, f"shape {a.shape}" if a.shape != (4, 4) else "a matrix with NaN or inf",
                              "a finite 4x4 matrix")
    return a


def view_shift(view_before: npt.ArrayLike, view_after: npt.ArrayLike, projection: npt.ArrayLike,
               size: tuple[int, int]) -> tuple[int, int] | None:
    """The whole-pixel displacement ``(dx, dy)`` (x to the right, y down) of distant content at the
    centre of an eye's image when the eye turns from ``view_before`` to ``view_after`` (4x4
    world-to-eye matrices, OpenGL convention: the eye looks down -z) under ``projection`` (4x4,
    possibly asymmetric, as a headset's field of view), for an image of ``size = (width, height)``
    pixels.  Only the rotation counts (content far away; a head's few centimetres of translation
    move distant content by a fraction of a pixel).  ``None`` when the old centre ray is no longer
    in front of the eye (a turn of 90 degrees or more: a cut)."""
    v0 = _as_matrix(view_before, "view_before")
    v1 = _as_matrix(view_after, "view_after")
    p = _as_matrix(projection, "projection")
    width, height = size
    # the ray through the centre of the old image, in the old eye's frame (any point on it)
    centre = np.linalg.solve(p, np.array([0.0, 0.0, 1.0, 1.0]))
    ray = centre[:3] / centre[3] if abs(centre[3]) > 1e-300 else centre[:3]
    # rotations only: world from old eye, then new eye from world
    turned = v1[:3, :3] @ (v0[:3, :3].T @ ray)
    clip = p @ np.append(turned, 0.0)               # a point at infinity along the turned ray
    if clip[3] <= 1e-12 * np.linalg.norm(clip):
        return None
    x_ndc, y_ndc = clip[0] / clip[3], clip[1] / clip[3]
    return int(round(x_ndc * width / 2.0)), int(round(-y_ndc * height / 2.0))


class MotionTracker:
    """A source's motion from frame to frame (what :class:`~vrcorrect.runtime.shell.sources.PictureSource`
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
