"""A 3x3 filter bank applied by FFT compute shaders (``shaders/fft_filter.glsl``).

The image sits on a periodic ``NX x NY`` grid (powers of two, at least the image plus a
margin on each side) at offset ``(margin, margin)``; the grid around it holds the image's
mirrored repeat (``border="mirror"``) or black (``"zero"``).  Two complex signals carry the
three channels (R + iG, B); rows and columns are transformed by radix-2 FFTs in shared
memory (one workgroup per line), each frequency multiplied by the 3x3 bank's spectrum, and
transformed back.  Cost per pixel ``O(log N)``, independent of the filter's size, and the
filter is not truncated: the GPU computes what
:func:`vrcorrect.solvers.wiener._exact_inverse_image` computes on the CPU, on the same grid.

GL orientation: textures hold rows bottom-up, so the bank's spectrum is uploaded for the
vertically flipped filter (``F(fx, -fy)``); the grid fill and the crop are symmetric under
the flip (see the notes in the code).  Layer 5: numpy and moderngl.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..plumbing.errors import ValidationError
from .dispatch import Gpu
from .gl import release
from .shaders import compile_compute

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["fft_grid", "FftBankGL", "MAX_FFT_SIZE"]

COMBINES = ("correct", "delta", "clip", "raw", "residual", "fista")
"""What the last pass writes: ``t + beta (clip(v) - t)``, ``clip(v) - t``, ``clip(v)``, ``v``,
``v - other`` (a residual ``K y - T``), or a FISTA update of the solution and its extrapolated point
from the gradient ``v = K^H (K y - T)`` (see ``shaders/fft_filter.glsl``)."""
MAX_FFT_SIZE = 4096                        # shared memory: 8 bytes per point (32 KiB, the GL minimum)


def fft_grid(width: int, height: int, margin: int) -> tuple[int, int]:
    """The power-of-two grid ``(NY, NX)`` holding the image and ``margin`` on each side."""
    ny = 1 << max(4, math.ceil(math.log2(height + 2 * margin)))
    nx = 1 << max(4, math.ceil(math.log2(width + 2 * margin)))
    if max(nx, ny) > MAX_FFT_SIZE:
        raise ValidationError("image size", f"{width}x{height} with a {margin} px margin",
                              f"at most {MAX_FFT_SIZE} px per side including the margins")
    return ny, nx


def gl_spectrum(spectrum_image: np.ndarray) -> np.ndarray:
    """``(3, 3, NY, NX)`` spectrum of a filter in image orientation -> the spectrum of the
    vertically flipped filter (GL orientation): ``F(fx, -fy)``."""
    ny = spectrum_image.shape[2]
    return spectrum_image[:, :, (-np.arange(ny)) % ny, :]


class FftBankGL:
    """One bank at one grid: the spectrum on the GPU, the five compute passes, the work images.

    ``combine`` is the last pass's mode (:data:`COMBINES`), or a tuple of modes that :meth:`run`
    chooses from (the first is the default); ``adjoint`` also builds the product with the bank's
    conjugate transpose (``K^H`` from ``K``'s spectrum: with ``border="zero"``, the exact adjoint
    of the bank's linear convolution).  Everything is compiled and allocated here, none per run.
    """

    def __init__(self, ctx: "moderngl.Context", spectrum_image: np.ndarray, image_size: tuple[int, int], margin: int,
                 border: str = "mirror", combine: str | tuple[str, ...] = "correct", adjoint: bool = False):
        if border not in ("mirror", "zero"):
            raise ValidationError("border", border, "'mirror' or 'zero'")
        combines = (combine,) if isinstance(combine, str) else tuple(combine)
        if not combines or any(c not in COMBINES for c in combines):
            raise ValidationError("combine", combine, "one or more of " + ", ".join(COMBINES))
        W, H = image_size
        ny, nx = spectrum_image.shape[2:]
        if (ny, nx) != fft_grid(W, H, margin):
            raise ValidationError("spectrum", f"grid {nx}x{ny}", f"the grid of fft_grid({W}, {H}, {margin})")
        self.ctx, self.size, self.margin, self.grid = ctx, (W, H), margin, (ny, nx)
        self.combine = combines[0]
        defines = {"NX": nx, "NY": ny, "LOG2_MAX": int(math.log2(max(nx, ny))), "LOG2_MAX_X": int(math.log2(nx)),
                   "LOG2_MAX_Y": int(math.log2(ny)), "MARGIN": margin}
        if border == "zero":
            defines["BORDER_ZERO"] = None
        name = "fft_filter.glsl"
        self.p_rows = compile_compute(ctx, name, defines={**defines, "ROWS_FORWARD": None})
        self.p_cols = compile_compute(ctx, name, defines={**defines, "COLS": None})
        self.p_icols = compile_compute(ctx, name, defines={**defines, "COLS": None, "INVERSE": None})
        self.p_mul = {False: compile_compute(ctx, name, defines={**defines, "MULTIPLY": None})}
        if adjoint:
            self.p_mul[True] = compile_compute(ctx, name, defines={**defines, "MULTIPLY": None, "ADJOINT": None})
        self.p_irows = compile_compute(ctx, name, defines={**defines, "ROWS_INVERSE": None})
        self.p_combine = {c: compile_compute(ctx, name, defines={**defines, "COMBINE": None,
                                                                  **({} if c == "raw" else {"COMBINE_" + c.upper(): None})})
                          for c in combines}
        bank = gl_spectrum(spectrum_image).reshape(9, ny, nx)
        data = np.empty((9, ny, nx, 2), np.float32)
        data[..., 0], data[..., 1] = bank.real, bank.imag
        self.bank = ctx.texture_array((nx, ny, 9), 2, data.tobytes(), dtype="f4")
        self.spec = ctx.texture_array((nx, ny, 2), 2, dtype="f4")
        self.spec_out = ctx.texture_array((nx, ny, 2), 2, dtype="f4")
        self.filtered = ctx.texture_array((W, H, 2), 2, dtype="f4")
        for t in (self.bank, self.spec, self.spec_out, self.filtered):
            t.filter = (ctx.NEAREST, ctx.NEAREST)

    def run(self, gpu: Gpu, linear_in: "moderngl.Texture", out: "moderngl.Texture", beta: float = 1.0, *,
            combine: str | None = None, adjoint: bool = False, other: "moderngl.Texture | None" = None,
            solution: "moderngl.Texture | None" = None, step: float = 0.0, weight: float = 0.0) -> None:
        """``linear_in`` (rgba32f, W x H) -> ``out`` (rgba32f): filtered (by the bank, or its
        conjugate transpose with ``adjoint``), then combined (``combine``, default the bank's own);
        the six passes run through ``gpu`` (counted there).

        ``"residual"`` subtracts ``other`` (rgba32f); ``"fista"`` takes ``linear_in`` as the
        residual, ``out`` as the extrapolated point ``y`` and ``solution`` as ``x`` and updates both
        in place with the gradient step ``step`` and the momentum weight ``weight``.
        """
        ny, nx = self.grid
        W, H = self.size
        mode = self.combine if combine is None else combine
        if mode not in self.p_combine or adjoint not in self.p_mul:
            raise ValidationError("combine", f"{mode}{' (adjoint)' if adjoint else ''}",
                                  "a mode this bank was built for: " + ", ".join(self.p_combine))
        gpu.run("fft rows", self.p_rows, (ny, 2, 1), sample={"u_linear_in": linear_in}, write={0: self.spec})
        gpu.run("fft columns", self.p_cols, (nx, 2, 1), modify={0: self.spec})
        gpu.run("spectral product", self.p_mul[adjoint], (math.ceil(nx / 16), math.ceil(ny / 16), 1),
                sample={"u_bank": self.bank}, read={0: self.spec}, write={1: self.spec_out}, round_trip=True)
        gpu.run("inverse fft columns", self.p_icols, (nx, 2, 1), modify={0: self.spec_out})
        gpu.run("inverse fft rows", self.p_irows, (ny, 2, 1), read={0: self.spec_out}, write={1: self.filtered},
                uniforms={"u_size": (W, H)})
        p = self.p_combine[mode]
        groups = (math.ceil(W / 16), math.ceil(H / 16), 1)
        # only the correct and delta combines read the target's texels; the others take its size
        size_only = {} if mode in ("correct", "delta") else {"u_linear_in": 0}
        if mode == "fista":
            gpu.run("combine " + mode, p, groups, sample={"u_linear_in": linear_in}, read={0: self.filtered},
                    modify={1: out, 2: solution}, uniforms={"u_step": float(step), "u_weight": float(weight)},
                    rows=size_only)
        else:
            sample = {"u_linear_in": linear_in}
            if mode == "residual":
                sample["u_other"] = other
            gpu.run("combine " + mode, p, groups, sample=sample, read={0: self.filtered}, write={1: out},
                    uniforms={"u_beta": float(beta)}, rows=size_only)

    def release(self) -> None:
        release(self.p_rows, self.p_cols, self.p_icols, *self.p_mul.values(), self.p_irows,
                *self.p_combine.values(), self.bank, self.spec, self.spec_out, self.filtered)
