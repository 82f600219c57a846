"""``method="admm"`` (the default): ADMM iterations on the true objective, spread over frames.

``fast``'s exact iteration (the boundary-aware split with its per-frequency 3x3 solve,
over-relaxed), continued from frame to frame with its duals, on the GPU (``shaders/admm.glsl``).
The mathematics, the warm start, the guard and the storage precision are stated once, on the CPU
twin the GPU is held to (:class:`vrcorrect.solvers.realtime.AdmmFrames`: one GL iteration equals
one CPU iteration to float tolerance, ``tests/test_runtime_admm.py``).  Per frame:
``iterations_per_frame + 2`` FFT round trips (the target ``T = K_ref t``, the iterations, the
guard's ``K z`` and ``K t``; none for ``T`` with the ideal target ``A t``), each round trip as few
passes as the data allow:

* the spectral product is fused into the column pass (column FFTs, the 3x3 products, inverse column
  FFTs: one read and one write of the grid's spectra), and ``G = (K^H K + n I)^-1`` is computed
  there from ``K`` instead of read;
* the per-pixel work is fused into the row passes (the inverse row FFTs of one iteration, the
  update of the state, the forward row FFTs of the next);
* spectra are real-to-complex (half the columns), the kernels' spectra too;
* the grid is 5-smooth on each side (:func:`~vrcorrect.solvers.realtime.admm_grid`), and a line is
  transformed by a mixed-radix Stockham FFT (``shaders/fft_line.glsl``: radix 2, 3, 4, 5 and 8
  butterflies in registers, one pass through shared memory between two stages, the plan
  :func:`vrcorrect.runtime.fft.line_plan`); twiddle factors come from a table of each line's length;
* ``precision="half"`` (the default) stores every texture in 16-bit floats (arithmetic in 32
  bits): half the bytes of ``"single"``, the objective unchanged to 1e-3 (the tests say by how
  much).

The state (``w``, ``q`` on the grid), the decoded target and ``T`` are double-buffered: each frame
reads the last frame's and writes the other (a reprojected warm start reads other texels than it
writes), so nothing is copied and nothing is allocated after the first frame of a size.

A cold frame (the first of a size, a cut, a new prescription) starts, where a half-resolution level
pays, from ``cold_iterations`` ADMM iterations at half resolution: a second, unguarded
:class:`AdmmStrategy` for the kernels 2x2 pixel blocks see (:attr:`AdmmStrategy.coarse`), fed the
target's block means (``POOL``); what its iterations added to their own cold start the start pass
upsamples and adds to this one's.  A reprojected warm start leaves the edge band where it is
(:func:`vrcorrect.solvers.realtime.edge_band`).

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ...plumbing.errors import ValidationError
from ...specs.vocabulary import Filter, Precision
from .. import fft
from ..dispatch import resource_bytes
from ..gl import fullscreen_triangle, release
from ..shaders import compile_compute, compile_program
from ..eye_model import band_switches
from .base import GuardResult, IterativeStrategy, Size, float_texture, groups_2d
from .spectra import coarse_model, model_spectra

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ..eye_model import EyeModel

__all__ = ["AdmmStrategy", "values_per_thread", "column_lines"]

MAX_INVOCATIONS = fft.MAX_INVOCATIONS
MIN_SHARED_BYTES = fft.MIN_SHARED_BYTES
values_per_thread = fft.values_per_thread


def column_lines(ny: int, per: int, lines: int) -> int:
    """Spectrum columns one work group of a column pass transforms together for ``ny``-point columns
    at ``per`` values a thread (as compiled: :func:`values_per_thread`): ``lines``, halved until the
    lines (a ``vec2`` a point) fit ``MIN_SHARED_BYTES`` and the threads ``MAX_INVOCATIONS``."""
    n = max(1, int(lines))
    while n > 1 and (n * ny * 8 > MIN_SHARED_BYTES or n * (ny // per) > MAX_INVOCATIONS):
        n //= 2
    return n


EARLY_STOP_TOLERANCE = 1e-3
"""A still view is converged when two frames' guarded objectives agree to this (relative): the
passes are then given no work until the target changes (``CorrectorOptions.early_stop``)."""
KINDS = ("rows_target", "cols_target", "rows_start", "cols_admm", "rows_update", "rows_last", "rows_guard_input",
         "cols_guard", "rows_guard", "guard_final")
"""The passes' kinds, each with its work groups in the early stop's indirect arguments."""


@dataclass
class AdmmBuffers:
    """One image size's GPU state of the ADMM strategy (pairs: this frame's and the last one's)."""

    grid: tuple[int, int]                      # (NY, NX)
    t: list["moderngl.Texture"]                # decoded targets
    T: list["moderngl.Texture"]                # the target retina inside the image
    w: list["moderngl.Texture"]                # the state on the grid
    q: list["moderngl.Texture"]
    spec: "moderngl.TextureArray"              # row and column spectra, HX x NY x 6
    kernel: "moderngl.TextureArray"            # K's half spectrum, HX x NY x 9
    reference: "moderngl.TextureArray | None"  # K_ref's (None: the ideal target A t)
    twiddle_x: "moderngl.Texture"              # the row passes' twiddle factors (NX points)
    twiddle_y: "moderngl.Texture"              # the column passes' (NY points)
    partials: "moderngl.Buffer"
    changed: "moderngl.Buffer"                 # set by the decode's comparison with the last target
    history: "moderngl.Buffer"                 # the last two frames' guarded objectives
    args: "moderngl.Buffer"                    # the passes' work groups, written by PLAN
    guard: GuardResult
    out: "moderngl.Texture"                    # the previews' blended frame
    programs: dict[str, "moderngl.ComputeShader"]
    present: "moderngl.Program"
    present_vao: "moderngl.VertexArray"
    current: int = 0                           # which of the w, q and T pairs holds the state
    warm: bool = False
    last_t: int = 0                            # which of the t pair holds the last frame's target
    next_t: int = 1                            # the slot this frame's target is decoded into
    compared: bool = False                     # this frame's decode compared the target with the last
    frames: int = field(default=0)
    skipped: int = 0                           # frames the GPU was told to skip (early stop) so far
    values_per_thread: tuple[tuple[str, int], ...] = ()   # each pass's, as compiled (work_groups, per line)
    column_lines: int = 1                      # spectrum columns a column pass's work group transforms, as compiled
    column_groups: int = 0                     # a column pass's work groups: ceil(HX / column_lines)

    def release(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, list):
                release(*value)
            elif isinstance(value, dict):
                release(*value.values())
            elif hasattr(value, "release"):
                value.release()


class AdmmStrategy(IterativeStrategy):
    name = Filter.ADMM
    cold_extra_iterations = 0     # run beyond iterations_per_frame on a cold frame (a foveated window's, its periphery's)

    def __init__(self, *args: Any, coarse_level: bool = False, fovea: bool = False, cap: bool | None = None,
                 cap_switch: bool | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.fovea = fovea
        """A foveated frame's sub-image (:mod:`vrcorrect.runtime.strategies.foveated`): the data term
        holds on :attr:`window_gl` only and the rest of the image is held to the target (``FOVEA``
        in ``admm.glsl``); no coarse level."""
        self.cap = bool(getattr(self.model.design, "capped", False)) if cap is None else bool(cap)
        """The box's upper end is the target's light cap (``LIGHT_CAP``; the twin's ``AdmmFrames(cap=True)``):
        by default where the eye model's design is capped (``Design.capped``), as ``fast`` caps its problem."""
        self.cap_switch = (not fovea and band_switches(self.options)) if cap_switch is None else bool(cap_switch)
        """The cap is a uniform (``CAP_UNIFORM``), so that :meth:`swap_model` can go on with a design whose
        band has no cap, or has one (``--band auto``: a page's band and the default's), without new programs."""
        self.window_gl: tuple[int, int, int, int] = (0, 0, 0, 0)
        """With ``fovea``: the window ``(x0, y0, x1, y1)`` in GL texels of the image, half open."""
        self.hold: "moderngl.Texture | None" = None
        """With ``fovea``: what the view shows on the ring (the image's size; None: the target)."""
        from ...solvers.problem import LIGHT_CAP_FLOOR, light_cap  # start-up time: scipy with the first eye
        from ...solvers.realtime import ADMM_RELAXATION, admm_weights  # (as above)

        self._light_cap, self._cap_floor = light_cap, LIGHT_CAP_FLOOR
        self._cap_define = {"LIGHT_CAP": "u_cap_floor", "CAP_UNIFORM": None} if self.cap_switch else \
            {"LIGHT_CAP": LIGHT_CAP_FLOOR} if self.cap else {}
        m = self.model
        self.half = self.options.precision == Precision.HALF
        keep, n = admm_weights(m.kernel.kernel)                        # as the CPU twin's
        self.keep = float(np.float32(keep))
        self.box_weight = float(np.float32(n))                          # the shader's u_norm2: n of the data step
        self.alpha = float(np.float32(ADMM_RELAXATION))
        self._sized: dict[Size, AdmmBuffers] = {}
        self._last: AdmmBuffers | None = None
        self.coarse_level = coarse_level
        """This is the coarse level of a cold start: no guard (its state is all that is used), and its
        passes count in its caller's stage."""
        self.coarse: AdmmStrategy | None = None
        """The cold frames' half-resolution level, made on the first cold frame that uses it."""
        self.cold_start: Callable[["moderngl.Texture"], "moderngl.Texture"] | None = None
        """A first guess for a cold frame (the first of a size, a cut, a new prescription): called
        with the decoded target, returns a texture of the same size, linear light in [0, 1], that
        the iterations start from instead of the target (the learned model's single pass,
        :meth:`use_first_guess`)."""
        self._guesses: dict[Size, "moderngl.Texture"] = {}

    def use_first_guess(self, slot: Any) -> None:
        """Start every cold frame from ``slot``'s pass (``slot.run(src, dst)`` on rgba32f textures: the learned cold
        start, :class:`~vrcorrect.runtime.unrolled.UnrolledEye`) instead of the half-resolution level: :attr:`cold_start`
        reads the decoded target back, runs the slot, uploads its result into a texture kept per size (transfers)."""
        def start(linear: "moderngl.Texture") -> "moderngl.Texture":
            size = tuple(linear.size)
            out = self._guesses.get(size)
            if out is None:
                out = self._guesses[size] = float_texture(self.ctx, size)
            slot.run(linear, out)
            self.gpu.transfer("learned cold start: read-back and upload", read=resource_bytes(linear),
                              written=resource_bytes(out))
            return out

        self.cold_start = start

    def reset(self) -> None:
        for b in self._sized.values():
            b.warm = False

    # ------------------------------------------------------------------ per size

    def _buffers(self, size: Size) -> AdmmBuffers:
        b = self._sized.get(size)
        if b is None:
            b = self._sized[size] = self._make(size)
        return b

    def grid(self, size: Size) -> tuple[int, int]:
        """The ``(NY, NX)`` grid of ``size`` images (:func:`~vrcorrect.solvers.realtime.admm_grid`),
        refused past :data:`MAX_ADMM_GRID` naming the size, the grid and the largest image allowed."""
        from ...solvers.realtime import admm_grid  # start-up time (as above)

        m = self.model
        W, H = size
        ksize = m.margin                             # a pupil bank's widest kernel: a switch keeps the grid
        ny, nx = admm_grid(W, H, ksize)
        if max(nx, ny) > MAX_ADMM_GRID:
            raise ValidationError("image size", f"{W}x{H} with a {ksize} px kernel",
                                  f"a grid of at most {MAX_ADMM_GRID} px per side (the image plus the kernel "
                                  f"less one, rounded up to a 5-smooth length: {nx}x{ny} here), i.e. an image of "
                                  f"at most {MAX_ADMM_GRID - ksize + 1} px per side for this eye")
        return ny, nx

    def compile_passes(self, size: Size) -> tuple[dict[str, "moderngl.ComputeShader"], dict[str, int], int]:
        """Compile (and link) every compute pass of ``size`` frames, allocating nothing else: the
        programs by kind, each row or column pass's values a thread as compiled, and a column pass's
        lines a work group.  (A test links them at every grid class up to 4096 without the memory a
        frame of that size takes.)"""
        ctx, m = self.ctx, self.model
        W, H = size
        ny, nx = self.grid(size)
        defines: dict[str, Any] = {"NX": nx, "NY": ny, "HX": nx // 2 + 1, "IMG_W": W, "IMG_H": H,
                                   "MAX_PASSES": len(KINDS)}
        if self.half:
            defines["HALF"] = None
        if m.reference is None:
            defines["IDEAL"] = None
        if self.fovea:
            defines["FOVEA"] = None
        defines.update(self._cap_define)
        per_pass = self.options.work_groups.table(self.coarse_level)    # shape only, never a value
        compiled: dict[str, int] = {}
        col_plan = fft.line_plan(ny, per_pass["COLUMNS"])
        col_lines = column_lines(ny, col_plan.per, self.options.work_groups.lines(self.coarse_level))

        def program(pass_: str, **extra: None) -> "moderngl.ComputeShader":
            lines: dict[str, Any] = {}
            if pass_ == "COLUMNS" or pass_.startswith("ROWS"):
                plan = col_plan if pass_ == "COLUMNS" else fft.line_plan(nx, per_pass.get(pass_, 8))
                if pass_ in per_pass:
                    compiled[pass_] = plan.per
                lines = plan.defines()
                if pass_ == "COLUMNS":
                    lines["LINES"] = col_lines
            return compile_compute(ctx, "admm.glsl", defines={**defines, **lines, pass_: None, **extra})

        programs: dict[str, "moderngl.ComputeShader"] = {}
        try:
            for kind, pass_, extra in (("rows_start", "ROWS_START", {}), ("cols_admm", "COLUMNS", {"MODE_ADMM": None}),
                                       ("pool", "POOL", {}), ("rows_update", "ROWS_UPDATE", {}),
                                       ("rows_last", "ROWS_UPDATE", {"LAST": None}),
                                       ("rows_guard_input", "ROWS_UPDATE", {"LAST": None, "NO_UPDATE": None}),
                                       ("cols_guard", "COLUMNS", {"MODE_GUARD": None}), ("rows_guard", "ROWS_GUARD", {}),
                                       ("guard_final", "GUARD_FINAL", {}), ("blend", "BLEND", {}), ("plan", "PLAN", {}),
                                       *((("rows_target", "ROWS_TARGET", {}), ("cols_target", "COLUMNS", {"MODE_TARGET": None}))
                                         if m.reference is not None else ())):
                programs[kind] = program(pass_, **extra)
        except BaseException:
            release(*programs.values())
            raise
        return programs, compiled, col_lines

    def _make(self, size: Size) -> AdmmBuffers:
        ctx, m = self.ctx, self.model
        W, H = size
        ny, nx = grid = self.grid(size)
        hx = nx // 2 + 1
        dtype = "f2" if self.half else "f4"
        programs, compiled, col_lines = self.compile_passes(size)
        present = compile_program(ctx, "admm_present.glsl", defines=self._cap_define)

        spectra = model_spectra(m, grid, dtype)

        def spectrum_array(data: np.ndarray) -> "moderngl.TextureArray":
            arr = ctx.texture_array((hx, ny, 9), 2, data.tobytes(), dtype=dtype)
            arr.filter = (ctx.NEAREST, ctx.NEAREST)
            return arr

        spec = ctx.texture_array((hx, ny, 6), 2, dtype=dtype)
        spec.filter = (ctx.NEAREST, ctx.NEAREST)
        return AdmmBuffers(
            grid=grid, t=[float_texture(ctx, size, dtype) for _ in range(2)],
            T=[float_texture(ctx, size, dtype) for _ in range(2)],
            w=[float_texture(ctx, (nx, ny), dtype) for _ in range(2)],
            q=[float_texture(ctx, (nx, ny), dtype) for _ in range(2)],
            spec=spec, kernel=spectrum_array(spectra[0]),
            reference=None if m.reference is None else spectrum_array(spectra[1]),
            twiddle_x=fft.twiddle_texture(ctx, nx), twiddle_y=fft.twiddle_texture(ctx, ny),
            partials=ctx.buffer(reserve=16 * H), changed=ctx.buffer(np.zeros(4, np.uint32).tobytes()),
            history=ctx.buffer(np.full(4, -1.0, np.float32).tobytes()), args=ctx.buffer(reserve=12 * len(KINDS)),
            guard=GuardResult(ctx),
            out=float_texture(ctx, size), programs=programs, present=present,
            present_vao=fullscreen_triangle(ctx, present), values_per_thread=tuple(sorted(compiled.items())),
            column_lines=col_lines, column_groups=-(-hx // col_lines))

    # ------------------------------------------------------------------ frames

    def decode_target(self, size: Size) -> "moderngl.Texture":
        b = self._buffers(size)
        b.next_t = 1 - b.last_t
        return b.t[b.next_t]

    def decode(self, src: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        """Decode into the slot the last target is not in; on a plain warm frame with the early stop
        on, compare with the last target (the plan's "changed")."""
        size = tuple(src.size)
        target = self.decode_target(size)
        b = self._sized[size]
        b.compared = self.options.early_stop and b.warm and tuple(motion_gl) == (0, 0)
        self.decoder.run(src, target, (b.t[b.last_t], b.changed) if b.compared else None)
        return target

    def _uses_coarse(self, size: Size) -> bool:
        from ...solvers.admm import coarse_level_pays  # start-up time (as above)

        return not self.fovea and self.options.cold_iterations > 0 and coarse_level_pays(size[1], size[0], self.model.kernel.size)

    def _coarse_start(self, linear: "moderngl.Texture") -> AdmmBuffers:
        """A cold frame's coarse level: the target's block means into the coarse strategy, its
        ``cold_iterations`` iterations from a cold start; returns its buffers (``w``, ``q`` current)."""

        if self.coarse is None:
            model = coarse_model(self.model)
            options = replace(self.options, iterations_per_frame=self.options.cold_iterations, early_stop=False,
                              cold_iterations=0)
            self.coarse = AdmmStrategy(self.gpu, model, options, self.encoder, self.decoder, coarse_level=True,
                                       cap=self.cap, cap_switch=self.cap_switch)
        W, H = linear.size
        size = ((W + 1) // 2, (H + 1) // 2)
        c = self.coarse
        target = c.decode_target(size)
        b = self._sized[(W, H)]
        self.gpu.run("pool: coarse target", b.programs["pool"], groups_2d(size), sample={"u_t": linear},
                     write={1: target})
        c.reset()
        c.correct(target, (0, 0))
        return c._sized[size]

    def _begin(self, stage: str) -> None:
        if not self.coarse_level:
            self.gpu.begin(stage)

    def _run(self, b: AdmmBuffers, kind: str, name: str, groups: int, **bindings: Any) -> None:
        """One pass; on a plain warm frame with the early stop on, its work groups come from the
        plan (``KINDS``)."""
        indirect = (b.args, 12 * KINDS.index(kind)) if b.compared else None
        if self.cap_switch:
            bindings["uniforms"] = {**bindings.get("uniforms", {}), **self._cap_uniform()}
        self.gpu.run(name, b.programs[kind], (groups, 1, 1), indirect=indirect, **bindings)

    def _cap_uniform(self) -> dict[str, float]:
        """With :attr:`cap_switch`: the cap's floor now (``light_cap.glsl``; 1 is no cap)."""
        return {"u_cap_floor": float(self._cap_floor) if self.cap else 1.0} if self.cap_switch else {}

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        gpu = self.gpu
        size = tuple(linear.size)
        b = self._buffers(size)
        W, H = size
        ny, nx = b.grid
        cols = b.column_groups                  # a column pass's work groups
        if linear is not b.t[b.next_t]:
            raise ValidationError("linear", "a texture not from decode_target", "this strategy's decode target")
        cold = self.last_cold = not b.warm
        shifted = not cold and tuple(motion_gl) != (0, 0)
        # a shifted start reads the last state from the other textures of each pair; otherwise the
        # state is updated in place (and a frame the plan skips leaves it as it was)
        old, new = (b.current, 1 - b.current) if shifted else (b.current, b.current)
        t_prev = b.t[b.last_t]
        twiddle = {"u_twiddle": b.twiddle_x}            # the row passes' table; the column passes': col_tw
        col_tw = {"u_twiddle": b.twiddle_y}
        k = self.iterations_per_frame + (self.cold_extra_iterations if cold else 0)
        if b.compared:
            self._begin("plan")
            groups = {"rows_target": H, "cols_target": cols, "rows_start": ny, "cols_admm": cols, "rows_update": ny,
                      "rows_last": ny, "rows_guard_input": H, "cols_guard": cols, "rows_guard": H, "guard_final": 1}
            gpu.run("plan (early stop)", b.programs["plan"], (1, 1, 1),
                    buffers={5: (b.changed, "rw"), 6: (b.history, "r"), 7: (b.args, "w")},
                    uniforms={"u_passes": len(KINDS), "u_groups": tuple(groups[kind] for kind in KINDS),
                              "u_tolerance": EARLY_STOP_TOLERANCE})
        if b.reference is not None:
            self._begin("target")
            self._run(b, "rows_target", "rows: target t", H, sample={**twiddle, "u_t": linear}, write={0: b.spec},
                      rows={0: (H, 3)})
            self._run(b, "cols_target", "columns: T = K_ref t", cols, sample={**col_tw, "u_kernel": b.reference},
                      modify={0: b.spec}, uniforms={"u_rows_in": H, "u_rows_out": ny}, rows={0: (H, 3)},
                      written={0: (ny, 3)}, round_trip=True)
        self._begin("start")
        sample = {**twiddle, "u_t": linear}
        held = {"u_hold": self.hold if self.hold is not None else linear} if self.fovea else {}
        sample.update(held)
        images: dict[str, dict[int, Any]] = {"write": {}, "read": {}, "modify": {}}
        if b.reference is not None:               # reads T's spectra (3 layers), writes the reflections' (6)
            images["modify"][0] = b.spec
        else:
            images["write"][0] = b.spec
        start_given = cold and self.cold_start is not None
        coarse = cold and not start_given and self._uses_coarse(size)
        coarse_size = (0, 0)
        if start_given:
            self._begin("cold start")
            sample["u_start"] = self.cold_start(linear)
            self._begin("start")
        elif coarse:
            self._begin("cold start")
            cb = self._coarse_start(linear)
            images["read"].update({2: cb.w[cb.current], 3: cb.q[cb.current]})
            sample.update(u_t_prev=cb.t[cb.last_t], u_T_prev=cb.T[cb.current])
            coarse_size = ((W + 1) // 2, (H + 1) // 2)
            self._begin("start")
        if cold:
            images["write"].update({1: b.T[new], 4: b.w[new], 5: b.q[new]})
        elif shifted:
            sample.update(u_t_prev=t_prev, u_T_prev=b.T[old])
            images["write"].update({1: b.T[new], 4: b.w[new], 5: b.q[new]})
            images["read"].update({2: b.w[old], 3: b.q[old]})
        else:
            sample["u_t_prev"] = t_prev
            images["modify"].update({1: b.T[new], 4: b.w[new], 5: b.q[new]})
        idle = {k: v for k, v in (("u_t_prev", t_prev), ("u_T_prev", b.T[old]), ("u_start", b.out)) if k not in sample}
        idle.update({u: v for u, v in ((2, b.w[old]), (3, b.q[old])) if u not in images["read"]})  # same formats every frame
        self._run(b, "rows_start", "rows: T, warm start, reflections", ny, sample=sample, idle=idle,
                  uniforms={"u_cold": cold, "u_in_place": not shifted, "u_start_given": start_given,
                            "u_shift": motion_gl if shifted else (0, 0),
                            "u_band": self._band(motion_gl) if shifted else (0, 0),
                            "u_coarse": coarse, "u_coarse_size": coarse_size,
                            "u_keep": self.keep, "u_win": self.window_gl,
                            "u_matrix": tuple(float(v) for v in self.model.kernel.matrix.T.ravel())},
                  rows={0: (ny, 3)}, written={0: (ny, 6)}, **images)
        self._begin("iterations")
        capped = {"u_t": linear} if self.cap or self.cap_switch else {}          # the light cap's target
        if self.coarse_level:                     # the state is the result: every iteration a plain update
            for _ in range(k):
                self._run(b, "cols_admm", "columns: ADMM solve", cols, sample={**col_tw, "u_kernel": b.kernel},
                          modify={0: b.spec}, uniforms={"u_rows_in": ny, "u_rows_out": ny, "u_norm2": self.box_weight},
                          round_trip=True)
                self._run(b, "rows_update", "rows: update, reflections", ny, sample={**twiddle, "u_T": b.T[new], **capped},
                          modify={0: b.spec, 2: b.w[new], 3: b.q[new]},
                          uniforms={"u_keep": self.keep, "u_alpha": self.alpha})
            b.current, b.last_t, b.warm = new, b.next_t, True
            return linear
        for i in range(k):
            self._run(b, "cols_admm", "columns: ADMM solve", cols, sample={**col_tw, "u_kernel": b.kernel},
                      modify={0: b.spec}, uniforms={"u_rows_in": ny, "u_rows_out": ny, "u_norm2": self.box_weight},
                      round_trip=True)
            last = i == k - 1
            sample = {**twiddle, "u_T": b.T[new], **held, **capped}
            if last:
                sample["u_t"] = linear
            self._run(b, "rows_last" if last else "rows_update",
                      "rows: update" + (", guard input" if last else ", reflections"), ny, sample=sample,
                      modify={0: b.spec, 2: b.w[new], 3: b.q[new]},
                      uniforms={"u_keep": self.keep, "u_alpha": self.alpha, "u_win": self.window_gl},
                      written={0: (H, 6)} if last else None)
        if k == 0:
            self._run(b, "rows_guard_input", "rows: guard input", H, sample={**twiddle, "u_t": linear, **held},
                      read={3: b.q[new]}, write={0: b.spec}, rows={0: (H, 6), 3: H}, uniforms={"u_win": self.window_gl})
        self._begin("guard")
        self._run(b, "cols_guard", "columns: K z, K t", cols, sample={**col_tw, "u_kernel": b.kernel},
                  modify={0: b.spec}, uniforms={"u_rows_in": H, "u_rows_out": H}, rows={0: (H, 6)},
                  written={0: (H, 6)}, round_trip=True)
        self._run(b, "rows_guard", "rows: guard sums", H, sample={**twiddle, "u_T": b.T[new]}, read={0: b.spec},
                  buffers={4: (b.partials, "w")}, rows={0: (H, 6)})
        self._run(b, "guard_final", "guard weight", 1,
                  buffers={3: (b.guard.result, "w"), 4: (b.partials, "r"), 6: (b.history, "rw")},
                  uniforms={"u_reset": cold})
        b.guard.keep()
        b.current, b.last_t, b.warm = new, b.next_t, True
        b.frames += 1
        self._last = b
        return linear

    def _band(self, motion_gl: tuple[int, int]) -> tuple[int, int]:
        """The edge band's width on each axis for a motion (the twin's, :func:`~vrcorrect.solvers.realtime.edge_band`)."""
        from ...solvers.realtime import edge_band_widths  # start-up time: scipy with the first eye

        return edge_band_widths(motion_gl, self.model.kernel.size // 2)

    def present(self, shown: "moderngl.Texture", dst: "moderngl.Framebuffer",
                viewport: tuple[int, int, int, int] | None) -> None:
        b = self._last
        size = tuple(shown.size)
        vp = viewport if viewport is not None else (0, 0, *dst.size)
        self.gpu.draw("blend and encode", b.present_vao, b.present, dst, vp,
                      sample={"u_t": shown, "u_q": b.q[b.current]}, uniforms={"u_size": size, **self._cap_uniform()},
                      buffers={3: b.guard.result}, rows={"u_q": size[1]})

    def shown_texture(self, shown: "moderngl.Texture") -> "moderngl.Texture":
        b = self._last
        size = tuple(shown.size)
        held = {"u_hold": self.hold if self.hold is not None else shown} if self.fovea else {}
        self.gpu.run("blend", b.programs["blend"], groups_2d(size), sample={"u_t": shown, "u_q": b.q[b.current], **held},
                     write={1: b.out}, buffers={3: (b.guard.result, "r")}, rows={"u_q": size[1]},
                     uniforms={"u_win": self.window_gl, **self._cap_uniform()})
        return b.out

    # ------------------------------------------------------------------ read-backs

    def objective_fraction(self, size: Size, previous: bool = False) -> float | None:
        b = self._sized.get(size)
        return None if b is None or not b.frames else b.guard.objective_fraction(previous)

    def blend_weight(self, size: Size) -> float | None:
        b = self._sized.get(size)
        return None if b is None or not b.frames else b.guard.beta()

    def solution(self, size: Size) -> np.ndarray | None:
        b = self._sized.get(size)
        if b is None or not b.frames:
            return None
        W, H = size
        q = np.frombuffer(b.q[b.current].read(), np.float16 if self.half else np.float32)
        q = q.reshape(b.grid[0], b.grid[1], 4)[:H, :W, :3].astype(np.float32)
        t = np.frombuffer(b.t[b.last_t].read(), np.float16 if self.half else np.float32) if self.cap else None
        top = 1.0 if t is None else self._light_cap(t.reshape(H, W, 4)[:, :, :3].astype(np.float32))
        return np.ascontiguousarray(np.clip(q, 0.0, top)[::-1])

    def spectra_grids(self) -> tuple[tuple[tuple[int, int], str, bool], ...]:
        """The grids (``(NY, NX)``, texture dtype, coarse level or not) whose kernel spectra a switch of
        design rewrites: what a pupil bank precomputes (:func:`model_spectra` on each)."""
        dtype = "f2" if self.half else "f4"
        out = [(b.grid, dtype, self.coarse_level) for b in self._sized.values()]
        if self.coarse is not None:
            out += list(self.coarse.spectra_grids())
        return tuple(out)

    def swap_model(self, model: "EyeModel") -> bool:
        """Go on with another design of the same eye (a pupil bank's switch,
        :mod:`vrcorrect.runtime.pupil_bank`): the kernels' spectra are rewritten on every size's
        buffers (from ``model.spectra``, which the bank computed off the render thread, where it has
        them), and the state, the grids and the programs stay, so the iteration goes on from where it
        was; the plan is told the frame changed, so the early stop looks again.  False (nothing done)
        when the design does not fit the grids, or its cap differs and :attr:`cap_switch` is off (the
        caller installs it instead).  With :attr:`cap_switch` the cap follows the design's."""
        if model.margin > self.model.margin and self._sized:
            return False
        cap = bool(getattr(model.design, "capped", False))
        if cap != self.cap and not self.cap_switch:
            return False
        dtype = "f2" if self.half else "f4"
        for b in self._sized.values():
            K, R = model_spectra(model, b.grid, dtype, self.coarse_level)
            b.kernel.write(K.tobytes())
            if b.reference is not None:
                if R is None:
                    return False
                b.reference.write(R.tobytes())
            b.changed.write(np.ones(4, np.uint32).tobytes())
            b.history.write(np.full(4, -1.0, np.float32).tobytes())
        self.model, self.cap = model, cap
        if self.coarse is not None:
            self.coarse.swap_model(coarse_model(model))
        return True

    def describe(self) -> dict[str, Any]:
        rt = self.iterations_per_frame + 1 + (self.model.reference is not None)
        return {"iterations_per_frame": self.iterations_per_frame, "precision": self.options.precision,
                "fft_round_trips_per_frame": rt, "early_stop": self.options.early_stop,
                "cold_iterations": self.options.cold_iterations}

    def release(self) -> None:
        for b in self._sized.values():
            b.release()
        self._sized.clear()
        self._last = None
        if self.coarse is not None:           # its buffers only: the encoder and decoder are shared
            self.coarse.release()
            self.coarse = None
        release(*self._guesses.values())
        self._guesses.clear()
        super().release()


MAX_ADMM_GRID = 4096
"""Largest FFT grid side (the line a work group transforms sits in shared memory: 32 KiB at 4096)."""

