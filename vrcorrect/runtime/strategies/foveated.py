"""``method="admm"`` with ``fovea_deg``: the real-time default solved only where the eye looks.

The GPU's foveated frame, held to its CPU twin :class:`vrcorrect.solvers.foveated.FoveatedFrames`
(which states the mathematics; ``tests/test_runtime_fovea.py``):

* **decode** the whole view (the source's codes to linear light), then **crop** the sub-image (the
  window around the gaze and a ring as wide as the kernel's radius, one size for every gaze, moved
  inside the view where it would cross an edge: :func:`~vrcorrect.solvers.foveated.fovea_window`)
  into the ADMM strategy's target;
* the ADMM frame of :class:`~vrcorrect.runtime.strategies.admm.AdmmStrategy` on the sub-image's
  grid, compiled with ``FOVEA``: the data term on the window only, the ring held to the target;
  the warm start reprojected by the content's motion less the window's, cold when the window
  jumps by the sub-image's size or more; no coarse level (it would not know the window);
* **compose** the view: the target outside the window; inside, the guarded solution faded to the
  target over the blend band along the window's edges that lie inside the view.

So a frame's FFTs run on the sub-image's grid, not the view's: the bytes of a frame fall with the
window's area (``vrcorrect bench cost --fovea``).  The early stop is off (the window moves with the
gaze).

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from ...plumbing.errors import ValidationError
from ..gl import fullscreen_triangle, release
from ..shaders import compile_compute, compile_program
from .admm import AdmmStrategy
from .base import Size, float_texture, groups_2d

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["FoveatedStrategy", "MIN_FOVEA_DEG", "MAX_FOVEA_DEG", "gaze_pixels"]

MIN_FOVEA_DEG = 0.5
"""The smallest window radius (degrees) taken: about the foveola's."""
MAX_FOVEA_DEG = 90.0
"""The largest window radius (degrees) taken; past the view, the window is the view."""


def gaze_pixels(gaze_deg: tuple[float, float], size: Size, ppd: float) -> tuple[float, float]:
    """``(x, y)`` degrees from the view's centre (x right, y up, as OpenXR's view space) to view
    pixels ``(x, y)``, x right, y down (rows top first), for a ``(W, H)`` view at ``ppd``."""
    W, H = size
    return W / 2.0 + float(gaze_deg[0]) * ppd, H / 2.0 - float(gaze_deg[1]) * ppd


class FoveatedStrategy(AdmmStrategy):
    """The ADMM strategy on a window around :attr:`gaze_px` (module docstring).

    ``radius_px``: the window's half-side in view pixels (the radius in degrees times the display's
    pixels per degree); ``band_px``: the blend band (default: a quarter of the radius, at least 4,
    at most the radius, as the twin's)."""

    name = "admm"

    def __init__(self, *args: Any, radius_px: float, band_px: int | None = None, **kwargs: Any):
        super().__init__(*args, fovea=True, **kwargs)
        if not (isinstance(radius_px, (int, float)) and math.isfinite(radius_px) and radius_px >= 1):
            raise ValidationError("fovea radius", radius_px, "at least 1 pixel (a radius in degrees times the "
                                  "display's pixels per degree)")
        self.radius_px = int(round(radius_px))
        self.band_px = min(max(self.radius_px // 4, 4), self.radius_px) if band_px is None else int(band_px)
        self.ring = self.model.margin // 2
        self.gaze_px: tuple[float, float] | None = None
        """Where the eye looks, view pixels ``(x, y)`` rows top first (None: the view's centre)."""
        self.window = None                  # the last frame's FoveaWindow
        self._move_gl = (0, 0)
        self._full: dict[Size, "moderngl.Texture"] = {}
        self._out: dict[Size, "moderngl.Texture"] = {}
        self._view: Size | None = None
        self._passes: dict[str, "moderngl.ComputeShader"] = {}
        self._present: tuple["moderngl.Program", "moderngl.VertexArray"] | None = None

    def _pass(self, kind: str) -> "moderngl.ComputeShader":
        program = self._passes.get(kind)
        if program is None:
            defines: dict[str, Any] = {kind: None, "IMG_FMT": "rgba16f" if self.half else "rgba32f"}
            program = self._passes[kind] = compile_compute(self.ctx, "fovea.glsl", defines=defines)
        return program

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        info.update(fovea_deg=self.options.fovea_deg, gaze_deg=list(self.options.gaze_deg),
                    fovea_radius_px=self.radius_px, fovea_band_px=self.band_px,
                    fovea_window=None if self.window is None else list(self.window.win))
        return info

    def reset(self) -> None:
        super().reset()
        self.window = None

    # ------------------------------------------------------------------ frames

    def decode(self, src: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        """Decode the whole view (for the pupil's light and the compose), then crop the sub-image
        around the gaze into the ADMM target."""
        from ...solvers.foveated import fovea_window  # start-up time: scipy with the first eye

        size = W, H = tuple(src.size)
        full = self._full.get(size)
        if full is None:
            full = self._full[size] = float_texture(self.ctx, size, "f2" if self.half else "f4")
        if self._view is not None and self._view != size:
            self.reset()
        self._view = size
        self.decoder.run(src, full)
        gaze = self.gaze_px if self.gaze_px is not None else (W / 2.0, H / 2.0)
        window = fovea_window((H, W), gaze, self.radius_px, self.ring)
        sy0, sy1, sx0, sx1 = window.sub
        sub_size = (sx1 - sx0, sy1 - sy0)
        target = self.decode_target(sub_size)
        self._sized[sub_size].compared = False                    # no early stop: the window moves
        self.gpu.run("crop: the window and its ring", self._pass("CROP"), groups_2d(sub_size),
                     sample={"u_t": full}, write={1: target},
                     uniforms={"u_origin": (sx0, H - sy1), "u_size": sub_size}, rows={"u_t": sub_size[1]})
        moved = (0, 0) if self.window is None else (sx0 - self.window.sub[2], sy0 - self.window.sub[0])
        self._move_gl = (moved[0], -moved[1])
        y0, y1, x0, x1 = window.win
        h = sub_size[1]
        self.window_gl = (x0 - sx0, h - (y1 - sy0), x1 - sx0, h - (y0 - sy0))
        self.window = window
        self._target = target
        return full

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        """The ADMM frame on the sub-image, warm-started across the content's motion less the
        window's; returns the view's decoded target (the compose reads it)."""
        target = self._target
        total = (int(motion_gl[0]) - self._move_gl[0], int(motion_gl[1]) - self._move_gl[1])
        w, h = target.size
        if abs(total[0]) >= w or abs(total[1]) >= h:
            super().reset()
            total = (0, 0)
        super().correct(target, total)
        return linear

    def _window_uniforms(self, size: Size) -> dict[str, Any]:
        W, H = size
        sy0, sy1, sx0, sx1 = self.window.sub
        y0, y1, x0, x1 = self.window.win
        return {"u_origin": (sx0, H - sy1), "u_view": size, "u_win": (x0, x1, y0, y1), "u_band": float(self.band_px)}

    def _compose(self, full: "moderngl.Texture") -> "moderngl.Texture":
        """The view shown into a float texture (previews, read-backs)."""
        size = tuple(full.size)
        out = self._out.get(size)
        if out is None:
            out = self._out[size] = float_texture(self.ctx, size)
        b = self._last
        self.gpu.run("compose: the window blended into the view", self._pass("COMPOSE"), groups_2d(size),
                     sample={"u_t": full, "u_q": b.q[b.current]}, write={1: out}, buffers={3: (b.guard.result, "r")},
                     uniforms=self._window_uniforms(size), rows={"u_q": self.window.sub_shape[0]})
        return out

    def present(self, shown: "moderngl.Texture", dst: "moderngl.Framebuffer",
                viewport: tuple[int, int, int, int] | None) -> None:
        """The view composed and sRGB-encoded in one draw (``fovea_present.glsl``)."""
        if self._present is None:
            program = compile_program(self.ctx, "fovea_present.glsl")
            self._present = (program, fullscreen_triangle(self.ctx, program))
        program, vao = self._present
        b = self._last
        vp = viewport if viewport is not None else (0, 0, *dst.size)
        self.gpu.draw("compose and encode", vao, program, dst, vp, sample={"u_t": shown, "u_q": b.q[b.current]},
                      uniforms=self._window_uniforms(tuple(shown.size)), buffers={3: b.guard.result},
                      rows={"u_q": self.window.sub_shape[0]})

    def shown_texture(self, shown: "moderngl.Texture") -> "moderngl.Texture":
        return self._compose(shown)

    def solution(self, size: Size) -> Any:
        """The view shown (linear, ``(H, W, 3)`` rows top first): the composed frame, read back."""
        import numpy as np

        full = self._full.get(tuple(size))
        if full is None or self.window is None:
            return None
        out = self._compose(full)
        W, H = size
        a = np.frombuffer(out.read(), np.float32).reshape(H, W, 4)[:, :, :3]
        return np.ascontiguousarray(a[::-1])

    def objective_fraction(self, size: Size, previous: bool = False) -> float | None:
        return None if self.window is None else super().objective_fraction(self.window.sub_shape[::-1], previous)

    def blend_weight(self, size: Size) -> float | None:
        return None if self.window is None else super().blend_weight(self.window.sub_shape[::-1])

    def release(self) -> None:
        release(*self._full.values(), *self._out.values(), *self._passes.values(), *(self._present or ()))
        self._present = None
        self._full.clear()
        self._out.clear()
        self._passes.clear()
        super().release()
