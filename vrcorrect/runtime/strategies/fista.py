"""``method="fista"``: projected-gradient (FISTA) iterations on the true objective, spread over
frames (selectable; ADMM, :mod:`.admm`, is the default iteration).

It minimises the CPU solvers' objective itself, ``||crop(K x) - T||^2`` with ``x`` in [0, 1], the
convolution exact and linear with black outside the image (zero-filled 5-smooth FFT grid,
cropped to the image: :func:`vrcorrect.solvers.objective`), ``T = K_ref t`` (glasses on) or
``A t`` (ideal).  Each iteration is two FFT round trips, ``r = K y - T`` then ``K^H r`` (the exact
adjoint: the conjugate transpose of ``K``'s 3x3 spectrum, the same zero fill and crop), then
``x' = clip(y - r' / ||K||^2, 0, 1)`` and FISTA's extrapolation ``y' = x' + w (x' - x)``: the GPU
twin of :func:`vrcorrect.solvers.fista.projected_gradient` (one GL iteration equals one CPU step
to float precision).  Per image size the solution ``x``, the extrapolated point ``y`` and the
previous frame's target stay on the GPU, the momentum on the CPU; each frame runs
``iterations_per_frame`` iterations from the previous frame's solution moved by the change of the
target (``x + t - t_prev``, clipped: for a still source, exactly where FISTA stopped, so N frames of
k iterations are N k iterations).  With the content's motion since the last frame as a whole-pixel
shift ``d`` the start is reprojected, as asynchronous timewarp does: ``x(p) = clip(x(p - d) + t(p) -
t_prev(p - d))`` and the same for ``y`` where ``p - d`` lies inside the image, the new target ``t(p)``
on the pixels the motion exposes (``shaders/fista.glsl``).  The first frame of a size and
:meth:`FistaStrategy.reset` start cold, from the target.  The guard: the displayed frame is
``t + beta (x - t)`` with the objective-optimal ``beta`` in [0, 1] computed on the GPU (two more
``K`` round trips, ``K t - T`` and ``K x - T``, and a reduction), so no frame is worse than
uncorrected.  Per frame: ``2 k + 3`` FFT round trips.

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from ...specs.vocabulary import Filter
from ..fft import FftBankGL, fft_grid
from ..gl import download_texture, release
from ..shaders import compile_compute
from .base import FrameBlend, IterativeStrategy, Size, float_texture, groups_2d
from .spectra import kernel_spectra

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["FistaStrategy"]


@dataclass
class FistaBuffers:
    """One image size's GPU state of the FISTA strategy."""

    x: "moderngl.Texture"
    y: "moderngl.Texture"
    t_prev: "moderngl.Texture"
    x_src: "moderngl.Texture"            # the previous state while a shifted warm start is written
    y_src: "moderngl.Texture"
    t_prev_src: "moderngl.Texture"
    target: "moderngl.Texture"           # T
    r: "moderngl.Texture"                # K y - T, then the gradient's input
    r0: "moderngl.Texture"               # K t - T (the guard)
    kd: "moderngl.Texture"               # K x - T (the guard)
    corrected: "moderngl.Texture"
    fft_k: FftBankGL
    fft_target: FftBankGL
    blend: FrameBlend

    def release(self) -> None:
        for f in fields(self):
            release(getattr(self, f.name))


class FistaStrategy(IterativeStrategy):
    name = Filter.FISTA

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        from ...solvers.fista import fista_momentum  # start-up time: scipy with the first eye
        from ...solvers.spectral import spectral_norm_squared  # the same

        self._next_momentum = fista_momentum
        self.start = compile_compute(self.ctx, "fista.glsl")
        self.step = float(np.float32(1.0 / spectral_norm_squared(self.model.kernel.kernel)))   # 1 / ||K||^2
        self._sized: dict[Size, FistaBuffers] = {}
        self._warm_size: Size | None = None        # size whose state the next frame continues
        self._momentum = 1.0

    def reset(self) -> None:
        self._warm_size = None
        self._momentum = 1.0

    def _buffers(self, size: Size) -> FistaBuffers:
        buf = self._sized.get(size)
        if buf is None:
            m = self.model
            grid = fft_grid(*size, m.margin)
            Kf, Tf = kernel_spectra(m, grid)
            tex = [float_texture(self.ctx, size) for _ in range(11)]
            buf = self._sized[size] = FistaBuffers(
                *tex,
                # K y - T and K^H r (exact linear convolutions, black outside)
                fft_k=FftBankGL(self.ctx, Kf, size, m.margin, border="zero", combine=("residual", "fista"),
                                adjoint=True),
                fft_target=FftBankGL(self.ctx, Tf, size, m.margin, border="zero", combine="raw"),
                blend=FrameBlend(self.gpu, size, solution=True))
        return buf

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        gpu = self.gpu
        gpu.begin("start")
        size = tuple(linear.size)
        b = self._buffers(size)
        cold = self._warm_size != size
        shift = (0, 0) if cold else motion_gl
        if cold:
            self._momentum = 1.0
        if shift != (0, 0):
            # The previous state moves to the *_src textures (a swap: nothing is allocated) and the
            # shader writes the reprojected state into the others: read and write must differ.
            # FISTA's extrapolated point y moves with x and the momentum is kept (not reset): after
            # the move, y - x is the same step as before, only displaced with the content, so the
            # extrapolation is still a good one.  Exposed pixels restart from the target (x = y = t).
            b.x, b.x_src = b.x_src, b.x
            b.y, b.y_src = b.y_src, b.y
            b.t_prev, b.t_prev_src = b.t_prev_src, b.t_prev
            images = {"write": {0: b.x, 1: b.y, 2: b.t_prev}, "read": {3: b.x_src, 4: b.y_src, 5: b.t_prev_src}}
        elif cold:
            images = {"write": {0: b.x, 1: b.y, 2: b.t_prev}}
        else:
            images = {"modify": {0: b.x, 1: b.y, 2: b.t_prev}}
        gpu.run("warm start", self.start, groups_2d(size), sample={"u_linear_in": linear},
                uniforms={"u_cold": cold, "u_shift": shift}, **images)
        self._warm_size = size
        b.fft_target.run(gpu, linear, b.target)
        gpu.begin("iterations")
        for _ in range(self.iterations_per_frame):
            b.fft_k.run(gpu, b.y, b.r, combine="residual", other=b.target)                    # K y - T
            self._momentum, weight = self._next_momentum(self._momentum)
            b.fft_k.run(gpu, b.r, b.y, combine="fista", adjoint=True, solution=b.x,            # x, y updated
                        step=self.step, weight=float(np.float32(weight)))
        gpu.begin("guard")
        b.fft_k.run(gpu, linear, b.r0, combine="residual", other=b.target)                    # K t - T
        b.fft_k.run(gpu, b.x, b.kd, combine="residual", other=b.target)                       # K x - T
        b.blend.run(linear, b.r0, b.kd, b.x, b.corrected)
        return b.corrected

    def objective_fraction(self, size: Size, previous: bool = False) -> float | None:
        b = self._sized.get(size)
        return None if b is None else b.blend.objective_fraction(previous)

    def blend_weight(self, size: Size) -> float | None:
        b = self._sized.get(size)
        return None if b is None else b.blend.beta()

    def solution(self, size: Size) -> np.ndarray | None:
        b = self._sized.get(size)
        return None if b is None else download_texture(b.x)[..., :3].copy()

    def describe(self) -> dict[str, Any]:
        return {"iterations_per_frame": self.iterations_per_frame, "fft_round_trips_per_frame": 2 * self.iterations_per_frame + 3}

    def release(self) -> None:
        for b in self._sized.values():
            b.release()
        self._sized.clear()
        release(self.start)
        super().release()
