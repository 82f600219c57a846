"""The one-pass strategies: the ``wiener`` method's regularised inverse ``F`` applied once per
frame, then blended with the target (cheaper per frame than the iterations, further from the
optimum; selectable).

* ``method="fft"`` (:class:`FftInverse`): ``F`` with mirrored borders by FFT compute shaders on a
  5-smooth grid (:mod:`vrcorrect.runtime.fft`), ``O(log N)`` per pixel whatever the filter's
  size, the inverse not truncated; then ``x = t + beta (clip(F t) - t)`` with ``beta`` either the
  frame's own objective-optimal weight, computed on the GPU (``blend="frame"``, the default: two
  more FFT filterings and a reduction, so no frame is worse than uncorrected) or the weight chosen
  once per eye on the sample image (``blend="fixed"``).
* ``method="separable"`` (:class:`SeparableInverse`): the same inverse as filters designed on the
  CPU by :func:`vrcorrect.solvers.wiener.correction_filters`, a separable low-rank bank
  (:mod:`vrcorrect.runtime.filters`), ``width x rank`` taps per pixel (cheap for small kernels,
  costly for wide ones), blended by the fixed weight.

The regulariser and the fixed weight are chosen once per eye by the CPU ``wiener`` method
(:mod:`vrcorrect.runtime.eye_model`).

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from ...specs.vocabulary import Filter
from ..dispatch import Gpu
from ..fft import FftBankGL, fft_grid
from ..filters import SeparableBank
from ..gl import release
from ..shaders import compile_compute
from .base import GROUP, FrameBlend, Size, Strategy, float_texture, groups_2d
from .spectra import kernel_spectra

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["FftInverse", "SeparableInverse", "SeparableBankGL"]


@dataclass
class FftBuffers:
    """One image size's GPU state of the FFT inverse."""

    corrected: "moderngl.Texture"
    fft_correct: FftBankGL
    delta: "moderngl.Texture | None" = None      # blend="frame": clip(F t) - t, K t - T, K d
    r0: "moderngl.Texture | None" = None
    kd: "moderngl.Texture | None" = None
    fft_r0: FftBankGL | None = None
    fft_k: FftBankGL | None = None
    blend: FrameBlend | None = None

    def release(self) -> None:
        for f in fields(self):
            release(getattr(self, f.name))


class FftInverse(Strategy):
    name = Filter.FFT

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._sized: dict[Size, FftBuffers] = {}

    @property
    def per_frame_blend(self) -> bool:
        return self.options.per_frame_blend

    def _buffers(self, size: Size) -> FftBuffers:
        buf = self._sized.get(size)
        if buf is None:
            from ...solvers.wiener import inverse_spectrum  # start-up time: scipy with the first eye

            m, ctx = self.model, self.ctx
            grid = fft_grid(*size, m.margin)
            spectrum = inverse_spectrum(m.kernel, m.mu_rel, grid, m.reference)
            frame = self.per_frame_blend
            buf = FftBuffers(corrected=float_texture(ctx, size),
                             fft_correct=FftBankGL(ctx, spectrum, size, m.margin, border="mirror",
                                                   combine="delta" if frame else "correct"))
            if frame:
                Kf, Tf = kernel_spectra(m, grid)
                buf.delta, buf.r0, buf.kd = (float_texture(ctx, size) for _ in range(3))
                buf.fft_r0 = FftBankGL(ctx, Kf - Tf, size, m.margin, border="zero", combine="raw")
                buf.fft_k = FftBankGL(ctx, Kf, size, m.margin, border="zero", combine="raw")
                buf.blend = FrameBlend(self.gpu, size)
            self._sized[size] = buf
        return buf

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        b = self._buffers(tuple(linear.size))
        if b.blend is not None:                     # per-frame blend weight, on the GPU
            b.fft_correct.run(self.gpu, linear, b.delta)
            self.gpu.begin("guard")
            b.fft_r0.run(self.gpu, linear, b.r0)
            b.fft_k.run(self.gpu, b.delta, b.kd)
            b.blend.run(linear, b.r0, b.kd, b.delta, b.corrected)
        else:
            b.fft_correct.run(self.gpu, linear, b.corrected, beta=self.model.beta)
        return b.corrected

    def objective_fraction(self, size: Size, previous: bool = False) -> float | None:
        b = self._sized.get(size)
        return None if b is None or b.blend is None else b.blend.objective_fraction(previous)

    def blend_weight(self, size: Size) -> float | None:
        b = self._sized.get(size)
        return None if b is None or b.blend is None else b.blend.beta()

    def release(self) -> None:
        for b in self._sized.values():
            b.release()
        self._sized.clear()
        super().release()


class SeparableBankGL:
    """One separable bank's taps on the GPU and its two compute passes (``program``:
    ``correction.glsl`` for the correction, ``simulation.glsl`` for the forward model)."""

    def __init__(self, gpu: Gpu, program: str, bank: SeparableBank, border: str):
        ctx = gpu.ctx
        self.gpu, self.bank = gpu, bank
        C = bank.components
        self.layers = L = (C + 3) // 4
        S = bank.size
        rows = np.zeros((L * 4, S), np.float32)
        rows[:C] = bank.rows
        # (L, S, 4): texel (t, l) = the taps at offset t of components 4l..4l+3
        self.row_taps = ctx.texture((S, L), 4, np.ascontiguousarray(rows.reshape(L, 4, S).transpose(0, 2, 1)),
                                    dtype="f4")
        cols = np.zeros((3, L * 4, S), np.float32)
        cols[:, :C] = bank.cols[:, :, ::-1]           # GL rows run bottom-up: flip the vertical taps
        self.col_taps = ctx.texture((S, 3 * L), 4,
                                    np.ascontiguousarray(cols.reshape(3, L, 4, S).transpose(0, 1, 3, 2)), dtype="f4")
        for t in (self.row_taps, self.col_taps):
            t.filter = (ctx.NEAREST, ctx.NEAREST)
        select = np.zeros((L * 4, 3), np.float32)     # mat4x3 per layer: column c = one-hot channel
        select[np.arange(C), bank.channel] = 1.0
        defines = {"LAYERS": L, "RADIUS": bank.radius}
        if border == "zero":
            defines["BORDER_ZERO"] = None
        self.rows_prog = compile_compute(ctx, program, defines={**defines, "PASS_ROWS": None})
        self.cols_prog = compile_compute(ctx, program, defines={**defines, "PASS_COLS": None})
        self.rows_prog["u_select"].write(select.reshape(L, 4, 3).tobytes())
        self._rows: dict[Size, "moderngl.TextureArray"] = {}

    def rows_array(self, size: Size) -> "moderngl.TextureArray":
        arr = self._rows.get(size)
        if arr is None:
            arr = self._rows[size] = self.gpu.ctx.texture_array((*size, self.layers), 4, dtype="f4")
            arr.filter = (self.gpu.ctx.NEAREST, self.gpu.ctx.NEAREST)
        return arr

    def run(self, linear_in: "moderngl.Texture", out: "moderngl.Texture", uniforms: dict[str, float] | None = None) -> None:
        size = tuple(linear_in.size)
        rows = self.rows_array(size)
        groups = (-(-size[0] // GROUP), -(-size[1] // GROUP))
        self.gpu.run("separable rows", self.rows_prog, (*groups, self.layers),
                     sample={"u_linear_in": linear_in, "u_row_taps": self.row_taps}, write={1: rows})
        self.gpu.run("separable columns", self.cols_prog, groups_2d(size),
                     sample={"u_linear_in": linear_in, "u_rows_in": rows, "u_col_taps": self.col_taps},
                     write={2: out}, uniforms=uniforms)

    def release(self) -> None:
        release(self.row_taps, self.col_taps, self.rows_prog, self.cols_prog, *self._rows.values())
        self._rows.clear()


class SeparableInverse(Strategy):
    name = Filter.SEPARABLE

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.bank = SeparableBankGL(self.gpu, "correction.glsl", self.model.correction, "mirror")
        self._out: dict[Size, "moderngl.Texture"] = {}

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        size = tuple(linear.size)
        out = self._out.get(size)
        if out is None:
            out = self._out[size] = float_texture(self.ctx, size)
        self.bank.run(linear, out, {"u_beta": self.model.beta})
        return out

    def describe(self) -> dict[str, Any]:
        c = self.model.correction
        return {"filter_size": c.size, "ranks": list(c.ranks), "taps_per_pixel": c.taps_per_pixel,
                "rank_error": c.error}

    def release(self) -> None:
        self.bank.release()
        release(*self._out.values())
        self._out.clear()
        super().release()
