"""The GPU's FFT lines, and a 3x3 filter bank applied by FFT compute shaders (``shaders/fft_filter.glsl``).

**Lines.**  Every FFT pass of the real-time path (this bank's and the ADMM strategy's,
``shaders/admm.glsl``) transforms one line a work group with ``shaders/fft_line.glsl``: a Stockham
(self-sorting) mixed-radix FFT of any 5-smooth length up to 4096 (a line of complex float32 fills
OpenGL 4.3's least shared memory, 32 KiB), radix 2, 3, 4, 5 and 8 butterflies held in registers,
each thread owning ``per`` points, one exchange through shared memory between two stages and none
at the ends where the plan allows (:class:`LinePlan`, :func:`line_plan`); twiddle factors from a
table (:func:`twiddle_texture`, the ADMM passes) or computed (this bank).  The design follows
VkFFT's published one (a line in shared memory, butterflies in registers, few shared-memory
transfers, several lines a work group for coalesced reads); the code is this project's.
:func:`transform_lines` runs it alone on lines of a buffer (the tests hold it to numpy's FFT).

**The bank.**  The image sits on a periodic ``NX x NY`` grid (each side 5-smooth, at least the
image plus a margin on each side: :func:`fft_grid`) at offset ``(margin, margin)``; the grid
around it holds the image's mirrored repeat (``border="mirror"``) or black (``"zero"``).  Two
complex signals carry the three channels (R + iG, B); rows and columns are transformed (one
work group per line), each frequency multiplied by the 3x3 bank's spectrum, and transformed
back.  Cost per pixel ``O(log N)``, independent of the filter's size, and the
filter is not truncated: the GPU computes what
:func:`vrcorrect.solvers.wiener._exact_inverse_image` computes on the CPU, on the same grid.

GL orientation: textures hold rows bottom-up, so the bank's spectrum is uploaded for the
vertically flipped filter (``F(fx, -fy)``) and the image sits at GL row offset
``NY - H - margin``: GL grid row ``r`` is the CPU grid's row ``NY - 1 - r``, so the GPU's grid is
the vertical flip of the CPU's (image at ``(margin, margin)``) exactly, whatever surplus the grid
has beyond the image and its margins (``shaders/fft_filter.glsl``).  Layer 5: numpy and moderngl.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..plumbing.errors import ValidationError
from .dispatch import Gpu
from .gl import release
from .shaders import compile_compute

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["fft_grid", "FftBankGL", "MAX_FFT_SIZE", "MAX_INVOCATIONS", "MIN_SHARED_BYTES", "RADICES", "LinePlan",
           "values_per_thread", "line_radices", "line_plan", "twiddle_table", "twiddle_texture", "transform_lines"]

MAX_INVOCATIONS = 1024
"""Threads a work group may have (OpenGL 4.3's least ``GL_MAX_COMPUTE_WORK_GROUP_INVOCATIONS``)."""
MIN_SHARED_BYTES = 32768
"""Shared memory a work group may use (OpenGL 4.3's least ``GL_MAX_COMPUTE_SHARED_MEMORY_SIZE``): one
line of 4096 complex float32 points."""
RADICES = (8, 5, 4, 3, 2)
"""The butterflies of the line transforms (``shaders/fft_line.glsl``), held in registers: a line's
length must be 5-smooth (``2^a 3^b 5^c``)."""


@dataclass(frozen=True)
class LinePlan:
    """How one work group transforms a line of ``length`` points (``shaders/fft_line.glsl``): a
    Stockham (self-sorting) mixed-radix FFT in ``len(radices)`` stages, ``threads`` threads a line,
    each holding ``per`` points (thread ``i`` the points ``i + threads m``, ``m < per``) and doing
    ``ceil(per / r)`` radix-``r`` butterflies a stage in registers.  Between two stages the points
    cross through shared memory once (an exchange: a barrier, the stores, a barrier, the loads).  A
    first stage whose radix divides ``per`` reads the thread's own points from its registers and a
    last one whose radix divides ``per`` leaves them there (the column passes' case): ``exchanges``
    counts the crossings of such a transform."""

    length: int
    per: int
    radices: tuple[int, ...]

    @property
    def threads(self) -> int:
        return self.length // self.per

    @property
    def exchanges(self) -> int:
        first, last = self.radices[0], self.radices[-1]
        return len(self.radices) - 1 + (self.per % first != 0) + (self.per % last != 0)

    def sequence(self) -> str:
        """The transform written out for ``shaders/fft_line.glsl`` (its ``FFT_SEQUENCE``): one call a
        stage with its radix and the product of the radices before it as literals, so that every
        index a butterfly computes is a constant or one division by one; the first stage reads the
        thread's registers when its radix divides ``per``, the last leaves its output there when its
        radix does, and the points cross through shared memory before or after them where not."""
        calls, ns = [], 1
        last = len(self.radices) - 1
        if self.per % self.radices[0]:
            calls.append("fft_to_line(own, in_line);")
        for s, r in enumerate(self.radices):
            from_own = "!in_line" if s == 0 and self.per % r == 0 else "false"
            to_own = "!out_line" if s == last and self.per % r == 0 else "false"
            calls.append(f"fft_stage{r}({ns}, sign, {from_own}, {to_own}, own);")
            ns *= r
        if self.per % self.radices[-1]:
            calls.append("fft_from_line(own, out_line);")
        return " ".join(calls)

    def defines(self) -> dict[str, int | str]:
        """The GLSL defines of a program whose line is this one: ``LINE``, ``PER``, ``WG`` (the
        threads a line) and ``FFT_SEQUENCE`` (:meth:`sequence`)."""
        return {"LINE": self.length, "PER": self.per, "WG": self.threads, "FFT_SEQUENCE": self.sequence()}


def _factor_5_smooth(length: int) -> tuple[int, int, int]:
    n, powers = int(length), []
    for p in (2, 3, 5):
        k = 0
        while n % p == 0:
            n //= p
            k += 1
        powers.append(k)
    if n != 1 or length < 2:
        raise ValidationError("line length", length, "a 5-smooth length of at least 2 (2^a 3^b 5^c: the GPU's "
                                                     "mixed-radix butterflies are 2, 3, 4, 5 and 8)")
    return powers[0], powers[1], powers[2]


def values_per_thread(line: int, per: int) -> int:
    """Points of a ``line``-point line one thread holds, for ``per`` asked: the divisor of ``line``
    nearest ``per`` (by ratio; on a tie the larger) that keeps the work group within
    ``MAX_INVOCATIONS`` threads.  A power of two on a power-of-two line is kept as asked, raised where
    the work group would pass 1,024 threads and lowered to the line's length."""
    line, per = int(line), max(1, int(per))
    divisors = [d for d in range(1, line + 1) if line % d == 0 and line // d <= MAX_INVOCATIONS]
    return min(divisors, key=lambda d: (abs(math.log(d / per)), -d))


def _powers_of_two(a: int) -> list[tuple[int, ...]]:
    """Every way to write ``2^a`` as a product of radices 8, 4 and 2 (largest first)."""
    out: set[tuple[int, ...]] = set()

    def split(rest: int, parts: tuple[int, ...]) -> None:
        if rest == 0:
            out.add(tuple(sorted(parts, reverse=True)))
            return
        for k in (3, 2, 1):
            if k <= rest:
                split(rest - k, parts + (1 << k,))

    split(a, ())
    return sorted(out)


PLAN_VALUES_PER_THREAD = 4
"""The points a thread the radix order of a line is chosen for (:func:`line_radices`): the column
passes' default.  The order depends on the line's length alone, so that every work-group shape of a
pass computes the same values in the same order (its output equal to the last bit: only which thread
holds a value changes)."""


def line_radices(line: int) -> tuple[int, ...]:
    """The radix order of a ``line``-point transform: of the ways to factor it into radices 8, 5, 4, 3
    and 2, the one with the fewest shared-memory exchanges at :data:`PLAN_VALUES_PER_THREAD` points a
    thread (radices that divide the thread's points first and last, so that a transform from and to
    registers reads and leaves them there), then the fewest stages."""
    a, b, c = _factor_5_smooth(line)
    per = values_per_thread(line, PLAN_VALUES_PER_THREAD)
    best: tuple[tuple[int, int], tuple[int, ...]] | None = None
    for twos in _powers_of_two(a):
        radices = sorted(twos + (3,) * b + (5,) * c, reverse=True)
        ends = [r for r in radices if per % r == 0]
        first = ends[0] if ends else radices[0]
        rest = list(radices)
        rest.remove(first)
        last = next((r for r in sorted(rest) if per % r == 0), None) if len(ends) > 1 else None
        if last is None and rest:
            last = min(rest)
        if last is not None:
            rest.remove(last)
        order = (first, *rest) + ((last,) if last is not None else ())
        key = (LinePlan(int(line), per, order).exchanges, len(order))
        if best is None or key < best[0]:
            best = (key, order)
    assert best is not None
    return best[1]


def line_plan(line: int, per: int) -> LinePlan:
    """The :class:`LinePlan` of a ``line``-point line at ``per`` points a thread asked: the points a
    thread :func:`values_per_thread` gives, the radices :func:`line_radices` orders."""
    return LinePlan(int(line), values_per_thread(line, per), line_radices(line))


COMBINES = ("correct", "delta", "clip", "raw", "residual", "fista")
"""What the last pass writes: ``t + beta (clip(v) - t)``, ``clip(v) - t``, ``clip(v)``, ``v``,
``v - other`` (a residual ``K y - T``), or a FISTA update of the solution and its extrapolated point
from the gradient ``v = K^H (K y - T)`` (see ``shaders/fft_filter.glsl``)."""
MAX_FFT_SIZE = 4096                        # shared memory: 8 bytes per point (32 KiB, the GL minimum)


def twiddle_table(length: int) -> np.ndarray:
    """``(length, 2)`` float32: cos and sin of ``2 pi k / length`` for ``k < length``, computed in
    float64 (the line transforms' twiddle factors, read from a texture instead of computed)."""
    angles = 2.0 * np.pi * np.arange(int(length), dtype=np.float64) / int(length)
    return np.stack([np.cos(angles), np.sin(angles)], -1).astype(np.float32)


def twiddle_texture(ctx: "moderngl.Context", length: int) -> "moderngl.Texture":
    """:func:`twiddle_table` as a ``length x 1`` rg32f texture (nearest filtering)."""
    tex = ctx.texture((int(length), 1), 2, twiddle_table(length).tobytes(), dtype="f4")
    tex.filter = (ctx.NEAREST, ctx.NEAREST)
    return tex


def transform_lines(ctx: "moderngl.Context", lines: np.ndarray, per: int = 4, inverse: bool = False,
                    lines_per_group: int = 1, through: str = "") -> np.ndarray:
    """The unscaled FFT of each row of a ``(count, length)`` complex array by ``shaders/fft_lines.glsl``
    (the line transform of every pass, alone): ``per`` points a thread asked (:func:`line_plan`),
    ``lines_per_group`` lines a work group, ``through`` ``"in"`` or ``"out"`` to take the input from or
    leave the output in shared memory (as the row passes do); complex64 out."""
    data = np.ascontiguousarray(lines, np.complex64)
    count, length = data.shape
    if count % lines_per_group:
        raise ValidationError("lines", f"{count} lines", f"a multiple of lines_per_group ({lines_per_group})")
    plan = line_plan(length, per)
    defines: dict[str, int | str | None] = {**plan.defines(), "WG": plan.threads, "LINES": int(lines_per_group)}
    if inverse:
        defines["INVERSE"] = None
    if through:
        defines[{"in": "IN_LINE", "out": "OUT_LINE"}[through]] = None
    program = compile_compute(ctx, "fft_lines.glsl", defines=defines)
    buffer = ctx.buffer(data.view(np.float32).tobytes())
    twiddle = twiddle_texture(ctx, length)
    try:
        twiddle.use(0)
        program["u_twiddle"] = 0
        buffer.bind_to_storage_buffer(0)
        program.run(count // lines_per_group, 1, 1)
        ctx.memory_barrier()
        return np.frombuffer(buffer.read(), np.complex64).reshape(count, length).copy()
    finally:
        release(program, buffer, twiddle)


def fft_grid(width: int, height: int, margin: int) -> tuple[int, int]:
    """The grid ``(NY, NX)`` holding the image and ``margin`` on each side: each side the smallest
    5-smooth length (``2^a 3^b 5^c``, the line transforms' radices) of at least that and 16, at most
    :data:`MAX_FFT_SIZE`."""
    from ..solvers.spectral import smooth_length  # start-up time: scipy with the first bank

    ny = smooth_length(max(16, height + 2 * margin))
    nx = smooth_length(max(16, width + 2 * margin))
    if max(nx, ny) > MAX_FFT_SIZE:
        raise ValidationError("image size", f"{width}x{height} with a {margin} px margin",
                              f"at most {MAX_FFT_SIZE} px per side including the margins (a {nx}x{ny} grid "
                              f"here): an image of at most {MAX_FFT_SIZE - 2 * margin} px per side")
    return ny, nx


BANK_VALUES_PER_THREAD = 8
"""Points of a line a thread of the bank's row and column passes holds (:func:`line_plan`)."""


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
        defines: dict[str, int | str | None] = {"NX": nx, "NY": ny, "MARGIN": margin}
        if border == "zero":
            defines["BORDER_ZERO"] = None
        rows = {**defines, **line_plan(nx, BANK_VALUES_PER_THREAD).defines()}
        cols = {**defines, **line_plan(ny, BANK_VALUES_PER_THREAD).defines()}
        name = "fft_filter.glsl"
        self.p_rows = compile_compute(ctx, name, defines={**rows, "ROWS_FORWARD": None})
        self.p_cols = compile_compute(ctx, name, defines={**cols, "COLS": None})
        self.p_icols = compile_compute(ctx, name, defines={**cols, "COLS": None, "INVERSE": None})
        self.p_mul = {False: compile_compute(ctx, name, defines={**defines, "MULTIPLY": None})}
        if adjoint:
            self.p_mul[True] = compile_compute(ctx, name, defines={**defines, "MULTIPLY": None, "ADJOINT": None})
        self.p_irows = compile_compute(ctx, name, defines={**rows, "ROWS_INVERSE": None})
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
