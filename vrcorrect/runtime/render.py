"""One frame through the whole GL pipeline on a headless EGL context (``vrcorrect render``).

Upload the image (sRGB code values), run :class:`~vrcorrect.runtime.corrector.Corrector`
(``apply``, or ``simulate`` for what the eye sees), read the framebuffer back.  The same
code path as the mirror and the headset, minus the window: for servers, tests and
benchmarks.  Layer 5 (numpy, moderngl; onnxruntime for the ONNX backend).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..errors import ValidationError

__all__ = ["VIEWS", "render_frame"]

VIEWS = ("corrected", "seen-corrected", "seen-uncorrected")


def render_frame(image: np.ndarray, rx, display, eye: str = "right", backend: str = "glsl",
                 view: str = "corrected", ctx=None, **options) -> tuple[np.ndarray, dict[str, Any]]:
    """Correct (or simulate) one ``(H, W, 3)`` image of sRGB code values in [0, 1] (float) or
    uint8; returns the 8-bit result ``(H, W, 3)`` and what was built (``Corrector.describe()``
    plus ``build_s`` and ``frame_s``).  ``ctx``: an existing context (default: a new headless one)."""
    from .corrector import Corrector
    from .gl import check_gl_errors, headless_context, read_framebuffer, release, render_target, upload_texture

    if view not in VIEWS:
        raise ValidationError("view", view, "one of " + ", ".join(VIEWS))
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValidationError("image", f"shape {img.shape}", "(H, W, 3) RGB")
    if img.dtype != np.uint8:
        img = np.round(np.clip(img.astype(np.float64), 0.0, 1.0) * 255).astype(np.uint8)
    own = ctx is None
    if own:
        ctx = headless_context(require=430)
    corrector = src = tex = fbo = None
    try:
        t0 = time.perf_counter()
        corrector = Corrector(ctx, rx, display, eye, backend, **options)
        t1 = time.perf_counter()
        src = upload_texture(ctx, img)
        tex, fbo = render_target(ctx, width=img.shape[1], height=img.shape[0])
        if view == "corrected":
            corrector.apply(src, fbo)
        else:
            corrector.simulate(src, fbo, corrected=view == "seen-corrected")
        out = read_framebuffer(fbo)
        t2 = time.perf_counter()
        check_gl_errors(ctx, "render")
        info = corrector.describe()
        info.update(build_s=t1 - t0, frame_s=t2 - t1, renderer=ctx.info.get("GL_RENDERER", "?"), view=view)
        return out, info
    finally:
        if corrector is not None:
            corrector.release()
        release(fbo, tex, src)
        if own:
            ctx.release()
