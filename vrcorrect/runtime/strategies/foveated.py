"""``method="admm"`` with ``fovea_deg``: the real-time default solved only where the eye looks.

The GPU's foveated frame, held to its CPU twin :class:`vrcorrect.solvers.foveated.FoveatedFrames`
(which states the mathematics; ``tests/test_runtime_fovea.py``):

* **decode** the whole view (the source's codes to linear light), then **crop** the sub-image (the
  window around the gaze and a ring as wide as the kernel's radius, one size for every gaze, moved
  inside the view where it would cross an edge: :func:`~vrcorrect.solvers.foveated.fovea_window`)
  into the ADMM strategy's target;
* the ADMM frame of :class:`~vrcorrect.runtime.strategies.admm.AdmmStrategy` on the sub-image's
  grid, compiled with ``FOVEA``: the data term on the window only, the ring held to what the view
  shows there (the periphery);
  the warm start reprojected by the content's motion less the window's, cold when the window
  jumps by the sub-image's size or more; no coarse level (it would not know the window);
* **compose** the view: the periphery outside the window; inside, the guarded solution faded to
  the periphery over the blend band along the window's edges that lie inside the view.
* **the periphery** (``periphery``): the target itself, or a correction of the whole view at half
  or a quarter of the resolution: the ADMM frame (with its guard) on the view's 2x2 (or twice 2x2)
  block means with the kernels such blocks see, warm-started from frame to frame; its change from
  the block means upsampled bilinearly onto the target (``fovea.glsl``'s POOL and DELTA,
  ``fovea_periphery.glsl``).  The window's ring is held to it (``u_hold``).

So a frame's FFTs run on the sub-image's grid, not the view's: the bytes of a frame fall with the
window's area (``vrcorrect bench cost --fovea``).  The early stop is off (the window moves with the
gaze).

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ...plumbing.errors import ValidationError
from ...specs.vocabulary import PERIPHERY_LEVELS, Periphery, names
from ..gl import fullscreen_triangle, release
from ..shaders import compile_compute, compile_program
from .admm import AdmmStrategy
from .spectra import coarse_model
from .base import Size, float_texture, groups_2d

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ..eye_model import EyeModel

__all__ = ["FoveatedStrategy", "MIN_FOVEA_DEG", "MAX_FOVEA_DEG", "PERIPHERY_ITERATIONS", "DEFAULT_PERIPHERY",
           "gaze_pixels"]

MIN_FOVEA_DEG = 0.5
"""The smallest window radius (degrees) taken: about the foveola's."""
MAX_FOVEA_DEG = 90.0
"""The largest window radius (degrees) taken; past the view, the window is the view."""
PERIPHERY_ITERATIONS = {Periphery.HALF: 1, Periphery.QUARTER: 2}
"""The periphery's ADMM iterations a frame (``vrcorrect bench fovea`` measures what they keep)."""
DEFAULT_PERIPHERY = Periphery.QUARTER
"""Outside the window: a quarter-resolution correction of the whole view.  The target alone there
loses nearly all of the full field's gain to FovVideoVDP on a Quest 2 (``bench fovea``): at 19 px
a degree the display carries at most 9.4 cycles a degree, and an eye 15-20 degrees from the fovea
still resolves about 6-8, so the periphery sees the blur.  A half-resolution periphery keeps nearly
all of the gain but costs a Quest 2 eye 0.70 GB a frame at a 15 degree window; a quarter-resolution
one 0.48 GB, inside issue 45's 0.5 GB (``bench cost --fovea 15``)."""


def gaze_pixels(gaze_deg: tuple[float, float], size: Size, ppd: float) -> tuple[float, float]:
    """``(x, y)`` degrees from the view's centre (x right, y up, as OpenXR's view space) to view
    pixels ``(x, y)``, x right, y down (rows top first), for a ``(W, H)`` view at ``ppd``."""
    W, H = size
    return W / 2.0 + float(gaze_deg[0]) * ppd, H / 2.0 - float(gaze_deg[1]) * ppd


class FoveatedStrategy(AdmmStrategy):
    """The ADMM strategy on a window around :attr:`gaze_px` (module docstring).

    ``radius_px``: the half-side of the window solved, in view pixels; ``band_px``: the blend band
    along its edges (default: a quarter of it, at least 4, at most all of it, as the twin's).
    :func:`~vrcorrect.solvers.foveated.fovea_pixels` gives both for a fovea in degrees: the radius
    plus a band beyond it (what :func:`~vrcorrect.runtime.strategies.make_strategy` passes); ``periphery``: ``"target"``, ``"half"`` or ``"quarter"``."""

    name = "admm"

    def __init__(self, *args: Any, radius_px: float, band_px: int | None = None, periphery: str = DEFAULT_PERIPHERY,
                 **kwargs: Any):
        super().__init__(*args, fovea=True, **kwargs)
        if not (isinstance(radius_px, (int, float)) and math.isfinite(radius_px) and radius_px >= 1):
            raise ValidationError("fovea radius", radius_px, "at least 1 pixel (a radius in degrees times the "
                                  "display's pixels per degree)")
        if periphery not in PERIPHERY_LEVELS:
            raise ValidationError("fovea_periphery", periphery, " or ".join(names(PERIPHERY_LEVELS)))
        self.radius_px = int(round(radius_px))
        self.band_px = min(max(self.radius_px // 4, 4), self.radius_px) if band_px is None else int(band_px)
        self.ring = self.model.margin // 2
        self.periphery = periphery
        self.levels = PERIPHERY_LEVELS[periphery]
        self.outer: AdmmStrategy | None = None
        """The periphery's ADMM strategy (its own guard) at ``levels`` halvings of the view."""
        from ...solvers.foveated import COLD_PERIPHERY_ITERATIONS, COLD_WINDOW_ITERATIONS  # start-up time: scipy

        if self.levels:
            model = self.model
            for _ in range(self.levels):
                model = coarse_model(model)
            options = replace(self.options, iterations_per_frame=PERIPHERY_ITERATIONS[periphery], early_stop=False,
                              cold_iterations=0, fovea_deg=None, cold_start_model=None)
            self.outer = AdmmStrategy(self.gpu, model, options, self.encoder, self.decoder, cap=self.cap)
            self.outer.cold_extra_iterations = max(COLD_PERIPHERY_ITERATIONS - PERIPHERY_ITERATIONS[periphery], 0)
        self.cold_extra_iterations = COLD_WINDOW_ITERATIONS
        self.gaze_px: tuple[float, float] | None = None
        """Where the eye looks, view pixels ``(x, y)`` rows top first (None: the view's centre)."""
        self.window = None                  # the last frame's FoveaWindow
        self._move_gl = (0, 0)
        self._textures: dict[tuple[str, Size], "moderngl.Texture"] = {}
        self._view: Size | None = None
        self._sizes: list[Size] = []
        self._passes: dict[tuple[str, bool], "moderngl.ComputeShader"] = {}
        self._present: tuple["moderngl.Program", "moderngl.VertexArray"] | None = None

    def _texture(self, kind: str, size: Size, dtype: str) -> "moderngl.Texture":
        t = self._textures.get((kind, size))
        if t is None:
            t = self._textures[(kind, size)] = float_texture(self.ctx, size, dtype)
        return t

    @property
    def _dtype(self) -> str:
        return "f2" if self.half else "f4"

    def _pass(self, kind: str, **extra: None) -> "moderngl.ComputeShader":
        key = (kind, *sorted(extra))
        program = self._passes.get(key)
        if program is None:
            defines: dict[str, Any] = {kind: None, "IMG_FMT": "rgba16f" if self.half else "rgba32f", **extra,
                                       **self._cap_define}
            if self.half:
                defines["HALF"] = None
            program = self._passes[key] = compile_compute(self.ctx, "fovea.glsl", defines=defines)
        return program

    def describe(self) -> dict[str, Any]:
        info = super().describe()
        info.update(fovea_deg=self.options.fovea_deg, gaze_deg=list(self.options.gaze_deg),
                    fovea_radius_px=self.radius_px, fovea_band_px=self.band_px, fovea_periphery=self.periphery,
                    fovea_periphery_iterations=PERIPHERY_ITERATIONS.get(self.periphery),
                    fovea_cold_iterations=self.cold_extra_iterations,
                    fovea_window=None if self.window is None else list(self.window.win))
        return info

    def reset(self) -> None:
        super().reset()
        if self.outer is not None:
            self.outer.reset()
        self.window = None

    def swap_model(self, model: "EyeModel") -> bool:
        """A pupil bank's switch: with a periphery the design is installed anew (its coarse levels
        have no precomputed spectra), without one as the full-field strategy swaps."""
        return False if self.outer is not None else super().swap_model(model)

    # ------------------------------------------------------------------ frames

    def look(self, gaze_deg: tuple[float, float], size: Size, ppd: float) -> None:
        self.gaze_px = gaze_pixels(gaze_deg, size, ppd)

    def decode(self, src: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        """Decode the whole view (for the pupil's light, the periphery and the compose), place the
        window around the gaze, and pool the periphery's levels."""
        from ...solvers.foveated import fovea_window  # start-up time: scipy with the first eye

        size = W, H = tuple(src.size)
        full = self._texture("full", size, self._dtype)
        if self._view is not None and self._view != size:
            self.reset()
        self._view = size
        self.decoder.run(src, full)
        gaze = self.gaze_px if self.gaze_px is not None else (W / 2.0, H / 2.0)
        window = fovea_window((H, W), gaze, self.radius_px, self.ring)
        sy0, sy1, sx0, sx1 = window.sub
        sub_size = (sx1 - sx0, sy1 - sy0)
        self._target = self.decode_target(sub_size)
        self._sized[sub_size].compared = False                    # no early stop: the window moves
        moved = (0, 0) if self.window is None else (sx0 - self.window.sub[2], sy0 - self.window.sub[0])
        self._move_gl = (moved[0], -moved[1])
        y0, y1, x0, x1 = window.win
        h = sub_size[1]
        self.window_gl = (x0 - sx0, h - (y1 - sy0), x1 - sx0, h - (y0 - sy0))
        self.window = window
        self._sizes = [size]
        for _ in range(self.levels):
            w, h = self._sizes[-1]
            self._sizes.append(((w + 1) // 2, (h + 1) // 2))
        source = full
        for level in range(1, self.levels + 1):
            dst = self.outer.decode_target(self._sizes[level]) if level == self.levels else \
                self._texture("pooled", self._sizes[level], self._dtype)
            self.gpu.run("periphery: 2x2 block means", self._pass("POOL"), groups_2d(self._sizes[level]),
                         sample={"u_t": source}, write={1: dst},
                         uniforms={"u_src_size": self._sizes[level - 1], "u_dst_size": self._sizes[level]})
            source = dst
        if self.outer is not None:
            self.outer._sized[self._sizes[-1]].compared = False
        return full

    def _periphery_uniforms(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """The samplers and uniforms of ``fovea_periphery.glsl`` (none without a periphery)."""
        if self.outer is None:
            return {}, {}
        return ({"u_pdelta": self._texture("delta", self._sizes[1], "f4")},
                {"u_psize": self._sizes[1], "u_full": self._sizes[0]})

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        """The periphery's frame (when there is one), the crop (and the ring's values), then the
        ADMM frame on the sub-image, warm-started across the content's motion less the window's;
        returns the view's decoded target (the compose reads it)."""
        W, H = self._sizes[0]
        if self.outer is not None:
            scale = 2 ** self.levels
            coarse = self._sizes[-1]
            target_c = self.outer._sized[coarse].t[self.outer._sized[coarse].next_t]
            self.outer.correct(target_c, (int(round(motion_gl[0] / scale)), int(round(motion_gl[1] / scale))))
            shown_c = self.outer.shown_texture(target_c)
            delta = self._texture("delta", self._sizes[1], "f4")
            if self.levels == 1:
                self.gpu.run("periphery: its change", self._pass("DELTA", FROM_FRAME=None, SAME=None),
                             groups_2d(coarse), sample={"u_out": shown_c, "u_t": target_c}, write={1: delta},
                             uniforms={"u_src_size": coarse, "u_dst_size": coarse})
            else:
                self.gpu.run("periphery: its change, upsampled", self._pass("DELTA", FROM_FRAME=None),
                             groups_2d(self._sizes[1]), sample={"u_out": shown_c, "u_t": target_c}, write={1: delta},
                             uniforms={"u_src_size": coarse, "u_dst_size": self._sizes[1]})
        window = self.window
        sy0, sy1, sx0, sx1 = window.sub
        sub_size = (sx1 - sx0, sy1 - sy0)
        target = self._target
        samplers, uniforms = self._periphery_uniforms()
        write = {1: target}
        if self.outer is not None:
            self.hold = self._texture("hold", sub_size, self._dtype)
            write[2] = self.hold
        else:
            self.hold = None
        extra = {"PERIPHERY": None} if self.outer is not None else {}
        self.gpu.run("crop: the window and its ring", self._pass("CROP", **extra), groups_2d(sub_size),
                     sample={"u_t": self._textures[("full", (W, H))], **samplers}, write=write,
                     uniforms={"u_origin": (sx0, H - sy1), "u_size": sub_size, **uniforms},
                     rows={"u_t": sub_size[1]})
        total = (int(motion_gl[0]) - self._move_gl[0], int(motion_gl[1]) - self._move_gl[1])
        if abs(total[0]) >= sub_size[0] or abs(total[1]) >= sub_size[1]:
            super().reset()
            total = (0, 0)
        super().correct(target, total)
        return linear

    def _window_uniforms(self, size: Size) -> tuple[dict[str, Any], dict[str, Any]]:
        W, H = size
        sy0, sy1, sx0, sx1 = self.window.sub
        y0, y1, x0, x1 = self.window.win
        samplers, uniforms = self._periphery_uniforms()
        return samplers, {"u_origin": (sx0, H - sy1), "u_view": size, "u_win": (x0, x1, y0, y1),
                          "u_band": float(self.band_px), **uniforms}

    def _compose(self, full: "moderngl.Texture") -> "moderngl.Texture":
        """The view shown into a float texture (previews, read-backs)."""
        size = tuple(full.size)
        out = self._texture("out", size, "f4")
        b = self._last
        samplers, uniforms = self._window_uniforms(size)
        extra = {"PERIPHERY": None} if self.outer is not None else {}
        self.gpu.run("compose: the window blended into the view", self._pass("COMPOSE", **extra), groups_2d(size),
                     sample={"u_t": full, "u_q": b.q[b.current], **samplers}, write={1: out},
                     buffers={3: (b.guard.result, "r")}, uniforms=uniforms, rows={"u_q": self.window.sub_shape[0]})
        return out

    def present(self, shown: "moderngl.Texture", dst: "moderngl.Framebuffer",
                viewport: tuple[int, int, int, int] | None) -> None:
        """The view composed and sRGB-encoded in one draw (``fovea_present.glsl``)."""
        if self._present is None:
            program = compile_program(self.ctx, "fovea_present.glsl", defines={
                **({"PERIPHERY": None} if self.outer is not None else {}), **self._cap_define})
            self._present = (program, fullscreen_triangle(self.ctx, program))
        program, vao = self._present
        b = self._last
        vp = viewport if viewport is not None else (0, 0, *dst.size)
        samplers, uniforms = self._window_uniforms(tuple(shown.size))
        self.gpu.draw("compose and encode", vao, program, dst, vp, sample={"u_t": shown, "u_q": b.q[b.current],
                                                                             **samplers},
                      uniforms=uniforms, buffers={3: b.guard.result}, rows={"u_q": self.window.sub_shape[0]})

    def shown_texture(self, shown: "moderngl.Texture") -> "moderngl.Texture":
        return self._compose(shown)

    def solution(self, size: Size) -> Any:
        """The view shown (linear, ``(H, W, 3)`` rows top first): the composed frame, read back."""

        full = self._textures.get(("full", tuple(size)))
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
        release(*self._textures.values(), *self._passes.values(), *(self._present or ()))
        self._textures.clear()
        self._passes.clear()
        self._present = None
        if self.outer is not None:
            self.outer.release()
        super().release()
