"""What every correction strategy is, and the passes several of them share.

A :class:`Strategy` corrects one eye's image, in linear light, for one :class:`EyeModel`: the
:class:`~vrcorrect.runtime.corrector.Corrector` decodes the source into the strategy's
:meth:`~Strategy.decode_target`, calls :meth:`~Strategy.correct` and then
:meth:`~Strategy.present`.  A strategy owns its GPU programs (made once) and its per-size buffers
(typed dataclasses, made on the first frame of a size and kept: later frames allocate nothing), and
runs every pass through :class:`~vrcorrect.runtime.dispatch.Gpu`, so its cost is counted from its
dispatches.  A new prescription makes a new strategy (the corrector releases the old one).

Shared here: :class:`Encoder` (linear light to sRGB codes into the caller's framebuffer),
:class:`FrameBlend` (the guard: the objective-optimal blend of a correction with the target,
``shaders/blend.glsl``) and :func:`float_texture`.

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ...plumbing.errors import ValidationError
from ..dispatch import Gpu
from ..eye_model import check_iterations
from ..gl import fullscreen_triangle, release
from ..shaders import compile_compute, compile_program

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ..eye_model import CorrectorOptions, EyeModel

__all__ = ["Strategy", "Encoder", "Decoder", "FrameBlend", "GuardResult", "LuminanceMeter", "PageLook", "float_texture", "GROUP",
           "groups_2d"]

GROUP = 16
"""Side of the 16 x 16 work groups of the per-pixel passes."""

Size = tuple[int, int]


def groups_2d(size: Size) -> tuple[int, int, int]:
    """Work groups of a per-pixel pass over a ``(W, H)`` image."""
    return math.ceil(size[0] / GROUP), math.ceil(size[1] / GROUP), 1


def float_texture(ctx: "moderngl.Context", size: Size, dtype: str = "f4", components: int = 4) -> "moderngl.Texture":
    """A float texture of ``size`` (W, H), nearest sampling (texel-exact reads)."""
    t = ctx.texture(size, components, dtype=dtype)
    t.filter = (ctx.NEAREST, ctx.NEAREST)
    return t


class Encoder:
    """The frame's last pass: a texture of linear light, sRGB-encoded into the caller's framebuffer
    (``shaders/passthrough.glsl``)."""

    def __init__(self, gpu: Gpu):
        self.gpu = gpu
        self.program = compile_program(gpu.ctx, "passthrough.glsl", defines={"ENCODE_SRGB": None})
        self.vao = fullscreen_triangle(gpu.ctx, self.program)

    def present(self, texture: "moderngl.Texture", dst: "moderngl.Framebuffer",
                viewport: tuple[int, int, int, int] | None) -> None:
        vp = viewport if viewport is not None else (0, 0, *dst.size)
        self.gpu.draw("encode", self.vao, self.program, dst, vp, sample={"u_source": texture})

    def release(self) -> None:
        release(self.vao, self.program)


class Decoder:
    """The frame's first pass: the source (RGBA8 sRGB code values, or float linear light) into a
    linear-light texture (rgba32f, or rgba16f rounded to nearest), optionally comparing it with the
    last frame's to flag a change (``correction.glsl``'s ``PASS_DECODE``).  Programs are made on
    first use, one per source kind, target format and comparison."""

    def __init__(self, gpu: Gpu):
        self.gpu = gpu
        self._programs: dict[tuple[bool, str, bool], "moderngl.ComputeShader"] = {}

    def run(self, src: "moderngl.Texture", target: "moderngl.Texture",
            compare: tuple["moderngl.Texture", "moderngl.Buffer"] | None = None) -> None:
        """Decode ``src`` into ``target``; ``compare``: (the last frame's target, a buffer whose first
        uint becomes nonzero where any pixel differs)."""
        key = (src.dtype == "f1", target.dtype, compare is not None)
        program = self._programs.get(key)
        if program is None:
            program = self._programs[key] = compile_compute(
                self.gpu.ctx, "correction.glsl", defines={
                    "PASS_DECODE": None, "LAYERS": 1, "RADIUS": 0,
                    **({"LINEAR_FMT": "rgba16f", "LINEAR_HALF": None} if target.dtype == "f2" else {}),
                    **({"SOURCE_SRGB": None} if key[0] else {}), **({"COMPARE": None} if key[2] else {})})
        sample = {"u_source": src}
        buffers = {}
        if compare is not None:
            sample["u_previous"] = compare[0]
            buffers[5] = (compare[1], "rw")
        self.gpu.run("decode", program, groups_2d(tuple(src.size)), sample=sample, write={0: target}, buffers=buffers)

    def release(self) -> None:
        release(*self._programs.values())
        self._programs.clear()


class Strategy:
    """One way of correcting an eye's linear image on the GPU (module docstring).

    Subclasses set :attr:`name` and implement :meth:`correct`; the read-back methods answer
    ``None`` where a strategy has nothing to say."""

    name = ""
    iterative = False                   # has a per-frame iteration count (iterations_per_frame)
    last_cold = False                   # the last frame started cold and ran its cold work (a budget skips its time)

    def __init__(self, gpu: Gpu, model: "EyeModel", options: "CorrectorOptions", encoder: Encoder,
                 decoder: Decoder | None = None):
        self.gpu, self.ctx, self.model, self.options, self.encoder = gpu, gpu.ctx, model, options, encoder
        self.decoder = decoder if decoder is not None else Decoder(gpu)
        self._inputs: dict[Size, "moderngl.Texture"] = {}

    # ------------------------------------------------------------------ frames

    def decode_target(self, size: Size) -> "moderngl.Texture":
        """The texture the corrector decodes this frame's source into (rgba32f, linear light)."""
        tex = self._inputs.get(size)
        if tex is None:
            tex = self._inputs[size] = float_texture(self.ctx, size)
        return tex

    def decode(self, src: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        """This frame's source in linear light (:meth:`decode_target`, through the decoder)."""
        target = self.decode_target(tuple(src.size))
        self.decoder.run(src, target)
        return target

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        """Correct ``linear`` (this frame's target, from :meth:`decode_target`); returns the
        texture to present, linear light.  ``motion_gl``: the content's whole-texel motion since
        the last frame in GL coordinates (iterative strategies reproject their warm start by it)."""
        raise NotImplementedError

    def present(self, shown: "moderngl.Texture", dst: "moderngl.Framebuffer",
                viewport: tuple[int, int, int, int] | None) -> None:
        """Encode what :meth:`correct` returned into ``dst`` (a strategy may fuse its last pass here)."""
        self.encoder.present(shown, dst, viewport)

    def shown_texture(self, shown: "moderngl.Texture") -> "moderngl.Texture":
        """What :meth:`correct` returned as a texture of linear light (for the preview)."""
        return shown

    def look(self, gaze_deg: tuple[float, float], size: Size, ppd: float) -> None:
        """Where the eye looks, ``gaze_deg`` from the view's centre (x right, y up), for the next frame
        of ``size`` at ``ppd`` pixels a degree: only a foveated strategy uses it."""

    def reset(self) -> None:
        """Make the next frame a cold start (iterative strategies)."""

    # ------------------------------------------------------------------ live knobs and read-backs

    @property
    def iterations_per_frame(self) -> int | None:
        return None

    @iterations_per_frame.setter
    def iterations_per_frame(self, value: int) -> None:
        raise ValidationError("iterations_per_frame", value, f"only with an iterative method (not {self.name})")

    def objective_fraction(self, size: Size, previous: bool = False) -> float | None:
        """The last frame's objective over the uncorrected one's (``previous``: the frame before,
        read without waiting for the GPU); ``None`` without a per-frame guard."""
        return None

    def blend_weight(self, size: Size) -> float | None:
        """The last frame's blend weight of the correction (per-frame guards)."""
        return None

    def solution(self, size: Size) -> np.ndarray | None:
        """The current solution before the guard, ``(H, W, 3)`` rows top first (iterative strategies)."""
        return None

    def describe(self) -> dict[str, Any]:
        return {}

    def release(self) -> None:
        release(*self._inputs.values())
        self._inputs.clear()


class IterativeStrategy(Strategy):
    """A strategy that runs a number of iterations each frame: :attr:`iterations_per_frame`, its
    options' count, changed live (checked against the one range,
    :data:`~vrcorrect.specs.vocabulary.MAX_ITERATIONS_PER_FRAME`; the options are replaced, so the
    count lives in one place)."""

    iterative = True

    @property
    def iterations_per_frame(self) -> int:
        return self.options.iterations_per_frame

    @iterations_per_frame.setter
    def iterations_per_frame(self, value: int) -> None:
        value = check_iterations(value)
        if value != self.options.iterations_per_frame:
            self.options = replace(self.options, iterations_per_frame=value)


class GuardResult:
    """The guard's result on the GPU, ``(beta, <r0, Kd>, <Kd, Kd>, <r0, r0>)`` (16 bytes), and a
    two-slot ring of earlier frames' copies (made on the GPU): the previous frame's figures can be
    read while this frame's work is still queued, with no wait for the GPU."""

    def __init__(self, ctx: "moderngl.Context"):
        self.ctx = ctx
        self.result = ctx.buffer(reserve=16)
        self.history = [ctx.buffer(reserve=16) for _ in range(2)]
        self.frames = 0

    def keep(self) -> None:
        """After the pass that wrote :attr:`result`: copy it into the ring (on the GPU)."""
        self.ctx.copy_buffer(self.history[self.frames % 2], self.result)
        self.frames += 1

    def beta(self) -> float:
        return float(np.frombuffer(self.result.read(), np.float32)[0])

    def objective_fraction(self, previous: bool = False) -> float | None:
        """The blended frame's objective over the uncorrected one's (``None`` for a perfect
        target, whose objective is 0, or, with ``previous``, before the second frame).

        The last frame's: reads the sums back, which waits for the GPU to finish that frame (a
        sync).  ``previous``: the frame before it, from the copy of its sums the GPU made then
        into the ring slot the last frame did not touch; the read waits only for that earlier
        frame (drivers track each buffer's pending writes), not for the frame in flight: a live
        panel's figure, one frame late."""
        if previous:
            if self.frames < 2:
                return None
            data = self.history[(self.frames - 2) % 2].read()
        else:
            data = self.result.read()
        return objective_fraction_of(*(float(v) for v in np.frombuffer(data, np.float32)))

    def release(self) -> None:
        release(self.result, *self.history)


class LuminanceMeter:
    """Each frame's mean relative luminance (white = 1) on the GPU, for the viewing pupil
    (``shaders/luminance.glsl``: 16 x 16 work groups' sums of ``w . rgb`` of the decoded frame, ``w``
    the display's luminance weights).  The sums go into a ring of :data:`RING` buffers and are read
    :data:`RING` - 1 frames later, so nothing waits for the GPU: :meth:`latest` is that frame's mean
    (None before it exists)."""

    RING = 3

    def __init__(self, gpu: Gpu, weights: np.ndarray):
        self.gpu = gpu
        self.weights = tuple(float(w) for w in np.asarray(weights, np.float64))
        self.program = compile_compute(gpu.ctx, "luminance.glsl")
        self._ring: list[tuple["moderngl.Buffer", int, int] | None] = [None] * self.RING
        self.frames = 0

    def measure(self, linear: "moderngl.Texture") -> None:
        """Queue the reduction of this frame's decoded ``linear`` texture (W x H)."""
        W, H = linear.size
        groups = groups_2d((W, H))
        count = groups[0] * groups[1]
        slot = self.frames % self.RING
        held = self._ring[slot]
        buffer = held[0] if held is not None else None
        if buffer is None or buffer.size < 4 * count:
            if buffer is not None:
                buffer.release()
            buffer = self.gpu.ctx.buffer(reserve=4 * count)
        self._ring[slot] = (buffer, W * H, count)
        self.gpu.run("luminance", self.program, groups, sample={"u_linear": linear},
                     buffers={0: (buffer, "w")}, uniforms={"u_weights": self.weights, "u_size": (W, H)})
        self.frames += 1

    def latest(self) -> float | None:
        """The mean relative luminance of the frame measured :data:`RING` - 1 frames ago."""
        return None if self.frames < self.RING - 1 else self._read(self.frames - (self.RING - 1))

    def newest(self) -> float | None:
        """The mean relative luminance of the frame measured last, read now (this waits for the GPU:
        for a build's priming, never for an application's frame); None before any."""
        return None if self.frames < 1 else self._read(self.frames - 1)

    def _read(self, frame: int) -> float:
        buffer, pixels, count = self._ring[frame % self.RING]
        data = np.frombuffer(buffer.read(size=4 * count), np.float32)
        return float(data.astype(np.float64).sum() / max(pixels, 1))

    def release(self) -> None:
        release(self.program, *(h[0] for h in self._ring if h is not None))
        self._ring = [None] * self.RING


class PageLook:
    """A strided look at a frame's relative luminance for the page verdict (``band="auto"``,
    :class:`~vrcorrect.runtime.pupil_state.PupilState`; ``shaders/page_look.glsl``): every
    ``step``-th pixel of every ``step``-th row, at most ``side`` a side
    (:func:`~vrcorrect.physics.page.look_step`), into one buffer that :meth:`take` reads once the
    caller has let the GPU get to it (two frames later: nothing waits)."""

    def __init__(self, gpu: Gpu, weights: np.ndarray, side: int):
        self.gpu, self.side = gpu, int(side)
        self.weights = tuple(float(w) for w in np.asarray(weights, np.float64))
        self.program = compile_compute(gpu.ctx, "page_look.glsl")
        self.buffer: "moderngl.Buffer | None" = None
        self.shape: tuple[int, int] | None = None       # the pending look's (h, w); None: nothing pending

    def look(self, linear: "moderngl.Texture") -> None:
        """Queue the look at this frame's decoded ``linear`` texture (W x H)."""
        from ...physics.page import look_step  # start-up time: the optics load with the first eye

        W, H = linear.size
        step = look_step(H, W, self.side)
        w, h = -(-W // step), -(-H // step)
        if self.buffer is None or self.buffer.size < 4 * w * h:
            release(self.buffer)
            self.buffer = self.gpu.ctx.buffer(reserve=4 * w * h)
        self.gpu.run("page look", self.program, groups_2d((w, h)), sample={"u_linear": linear},
                     buffers={0: (self.buffer, "w")},
                     uniforms={"u_weights": self.weights, "u_out": (w, h), "u_step": step})
        self.shape = (h, w)

    def take(self) -> np.ndarray | None:
        """The pending look, ``(h, w)`` relative luminance with the picture's top row first (this
        waits for the GPU if it has not got there); None when nothing is pending."""
        if self.shape is None or self.buffer is None:
            return None
        h, w = self.shape
        self.shape = None
        y = np.frombuffer(self.buffer.read(size=4 * w * h), np.float32).reshape(h, w)
        return np.ascontiguousarray(y[::-1])

    def release(self) -> None:
        release(self.program, self.buffer)
        self.buffer, self.shape = None, None


class FrameBlend:
    """The per-frame blend weight (``shaders/blend.glsl``): two reductions and the blend.

    ``solution``: the projected-gradient guard, ``run``'s ``kd`` is the residual ``K x - T`` of the
    solution and ``delta`` the solution ``x`` itself (the blend is ``t + beta (x - t)``)."""

    def __init__(self, gpu: Gpu, size: Size, solution: bool = False):
        ctx = gpu.ctx
        self.gpu, self.size = gpu, size
        W, H = size
        self.groups = (math.ceil(W / GROUP), math.ceil(H / GROUP))
        extra = {"SOLUTION": None} if solution else {}
        self.p_partial = compile_compute(ctx, "blend.glsl", defines={"PARTIAL": None, **extra})
        self.p_final = compile_compute(ctx, "blend.glsl", defines={"FINAL": None})
        self.p_apply = compile_compute(ctx, "blend.glsl", defines={"APPLY": None, **extra})
        self.guard = GuardResult(ctx)
        self.partials = ctx.buffer(reserve=16 * self.groups[0] * self.groups[1])

    @property
    def result(self) -> "moderngl.Buffer":
        return self.guard.result

    def run(self, linear: "moderngl.Texture", r0: "moderngl.Texture", kd: "moderngl.Texture",
            delta: "moderngl.Texture", out: "moderngl.Texture") -> None:
        gpu = self.gpu
        gpu.run("blend sums", self.p_partial, (*self.groups, 1), sample={"u_r0": r0, "u_kd": kd},
                buffers={4: (self.partials, "w")})
        gpu.run("blend weight", self.p_final, (1, 1, 1),
                buffers={3: (self.guard.result, "w"), 4: (self.partials, "r")},
                uniforms={"u_count": self.groups[0] * self.groups[1]})
        self.guard.keep()
        gpu.run("blend", self.p_apply, (*self.groups, 1), sample={"u_linear_in": linear, "u_delta": delta},
                write={1: out}, buffers={3: (self.guard.result, "r")})

    def beta(self) -> float:
        return self.guard.beta()

    def objective_fraction(self, previous: bool = False) -> float | None:
        return self.guard.objective_fraction(previous)

    def release(self) -> None:
        release(self.p_partial, self.p_final, self.p_apply, self.guard, self.partials)


def objective_fraction_of(beta: float, s_rk: float, s_kk: float, s_rr: float) -> float | None:
    """The blended frame's objective as a fraction of the uncorrected one's from the guard's sums
    ``<r0, Kd>``, ``<Kd, Kd>``, ``<r0, r0>`` and its weight ``beta``: ``|r0 + beta Kd|^2 / |r0|^2``
    (``None`` for a perfect target)."""
    return None if s_rr <= 0 else max(0.0, 1.0 + (2.0 * beta * s_rk + beta * beta * s_kk) / s_rr)
