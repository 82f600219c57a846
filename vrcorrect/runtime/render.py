"""Frames through the whole GL pipeline on a headless EGL context (``vrcorrect render``).

Upload the image (sRGB code values), run :class:`~vrcorrect.runtime.corrector.Corrector`
(``apply``, or ``simulate`` for what the eye sees) on ``frames`` frames of it (``filter="fista"``
warm-starts each from the last: N frames of k iterations are N k iterations), read the last
frame's framebuffer back.  The same
code path as the mirror and the headset, minus the window: for servers, tests and
benchmarks.  Layer 5 (numpy, moderngl; onnxruntime for the ONNX backend).
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..plumbing.errors import ValidationError
from ..specs.display import DisplayProfile
from ..vision.forward import check_image
from .corrector import Corrector, RxSource
from .gl import check_gl_errors, headless_context, read_framebuffer, release, render_target, upload_texture

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["VIEWS", "MAX_FRAMES", "SETTLED_FRAMES", "check_frames", "render_frame"]

VIEWS = ("corrected", "seen-corrected", "seen-uncorrected")
MAX_FRAMES = 10_000
# ``vrcorrect render``'s default number of frames with ``filter="fista"``: a still view a tenth of a
# second after it appeared at 90 Hz, when k = 4 is within 5 % of ``fast`` (docs/benchmarks.md)
SETTLED_FRAMES = 10


def check_frames(frames: object, field: str = "frames") -> int:
    """``frames``: a whole number from 1 to :data:`MAX_FRAMES`."""
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or not 1 <= frames <= MAX_FRAMES:
        raise ValidationError(field, frames, f"a whole number of frames from 1 to {MAX_FRAMES}")
    return int(frames)


def render_frame(image: np.ndarray, rx: RxSource, display: str | os.PathLike[str] | DisplayProfile,
                 eye: str = "right", backend: str = "glsl", view: str = "corrected",
                 ctx: "moderngl.Context | None" = None, frames: int = 1,
                 progress: Callable[[int, int], None] | None = None,
                 **options: Any) -> tuple[np.ndarray, dict[str, Any]]:
    """Correct (or simulate) one ``(H, W, 3)`` image of sRGB code values in [0, 1] (float) or
    uint8, ``frames`` times as a still video (the last frame is returned); returns the 8-bit result
    ``(H, W, 3)`` and what was built (``Corrector.describe()`` plus ``build_s``, ``frame_s`` (all
    frames, with the upload and the read-back), ``frames`` and ``objective_fraction``: the last
    frame's objective over uncorrected where the GPU computes it (``filter="fista"`` and the
    per-frame blend), else None).  ``ctx``: an existing context (default: a new headless one);
    ``progress(done, total)`` is called after each frame."""
    if view not in VIEWS:
        raise ValidationError("view", view, "one of " + ", ".join(VIEWS))
    frames = check_frames(frames)
    img = check_image(image, "image", codes=True)
    if img.dtype != np.uint8:
        img = np.round(img.astype(np.float64) * 255).astype(np.uint8)
    own = ctx is None
    if ctx is None:
        ctx = headless_context(require=430)
    corrector = src = tex = fbo = None
    try:
        t0 = time.perf_counter()
        corrector = Corrector(ctx, rx, display, eye, backend, **options)
        t1 = time.perf_counter()
        src = upload_texture(ctx, img)
        tex, fbo = render_target(ctx, width=img.shape[1], height=img.shape[0])
        total = frames if view != "seen-uncorrected" else 1
        for done in range(1, total + 1):
            if view == "corrected":
                corrector.apply(src, fbo)
            else:
                corrector.simulate(src, fbo, corrected=view == "seen-corrected")
            if progress is not None:
                ctx.finish()
                progress(done, total)
        out = read_framebuffer(fbo)
        t2 = time.perf_counter()
        check_gl_errors(ctx, "render")
        info = corrector.describe()
        fraction = corrector.last_objective_fraction((img.shape[1], img.shape[0])) \
            if view != "seen-uncorrected" and corrector.enabled else None
        info.update(build_s=t1 - t0, frame_s=t2 - t1, renderer=ctx.info.get("GL_RENDERER", "?"), view=view,
                    frames=frames, objective_fraction=fraction)
        return out, info
    finally:
        if corrector is not None:
            corrector.release()
        release(fbo, tex, src)
        if own:
            ctx.release()
