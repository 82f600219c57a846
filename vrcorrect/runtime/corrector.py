"""The plugin: correct an eye's texture for that eye's prescription, in OpenGL.

(Over 700 lines because the per-frame GL work of three strategies and two backends reads best in one
class; what is designed on the CPU is in :mod:`vrcorrect.runtime.eye_model`.)

``Corrector(ctx, rx, display, eye, backend)`` is built once per prescription and
eye; ``apply(src_texture, dst_framebuffer)`` then runs every frame:

1. decode the source's sRGB code values to linear light (compute pass);
2. the correction in linear light, ``backend="glsl"``, by one of three strategies (``filter=``):
   ``"fista"`` (default): projected-gradient (FISTA) iterations on the true objective, spread
   over frames (below); ``"fft"`` (:mod:`vrcorrect.runtime.fft`): the ``wiener`` method's
   regularised inverse ``F`` with mirrored borders, then ``x = t + beta (clip(F t) - t)``, by FFT
   compute shaders on a power-of-two grid, ``O(log N)`` per pixel whatever the filter's size, the
   inverse not truncated (one pass: cheaper per frame, further from the optimum); ``"separable"``:
   the same inverse as filters designed on the CPU by
   :func:`vrcorrect.solvers.wiener.correction_filters`, a separable low-rank bank
   (:mod:`vrcorrect.runtime.filters`), ``width x rank`` taps per pixel (cheap for small kernels,
   costly for wide ones); ``backend="onnx"`` reads the linear image back, runs an ONNX model
   through onnxruntime and uploads the result (the learned model's slot,
   :mod:`vrcorrect.runtime.onnx_backend`);
3. encode to sRGB into the caller's framebuffer (fragment pass).

``filter="fista"`` minimises the CPU solvers' objective itself, ``||crop(K x) - T||^2`` with ``x``
in [0, 1], the convolution exact and linear with black outside the image (zero-filled power-of-two
FFT grid, cropped to the image: :func:`vrcorrect.solvers.objective`), ``T = K_ref t`` (glasses on)
or ``A t`` (ideal).  Each iteration is two FFT round trips, ``r = K y - T`` then ``K^H r`` (the
exact adjoint: the conjugate transpose of ``K``'s 3x3 spectrum, the same zero fill and crop),
then ``x' = clip(y - r' / ||K||^2, 0, 1)`` and FISTA's extrapolation ``y' = x' + w (x' - x)``:
the GPU twin of :func:`vrcorrect.solvers.wiener.projected_gradient` (one GL iteration equals one
CPU step to float precision).  Per eye and image size the solution ``x``, the extrapolated point
``y`` and the previous frame's target stay on the GPU, the momentum on the CPU; each frame runs
``iterations_per_frame`` iterations from the previous frame's solution moved by the change of the
target (``x + t - t_prev``, clipped: for a still source, exactly where FISTA stopped, so N frames
of k iterations are N k iterations).  When the caller knows the content's motion since the last
frame as a whole-pixel shift ``d`` (``apply(..., motion_px=(dx, dy))``: a pan, a scrolled screen;
estimated for CPU sources by :func:`vrcorrect.runtime.motion.estimate_shift`), the start is
reprojected, as asynchronous timewarp does: ``x(p) = clip(x(p - d) + t(p) - t_prev(p - d))`` and
the same for ``y`` where ``p - d`` lies inside the image, the new target ``t(p)`` on the pixels
the motion exposes (``shaders/fista.glsl``); ``d = (0, 0)`` is the plain warm start exactly.  The first frame of a size, a size change, a prescription
change (``adjust``, ``poll``) and :meth:`Corrector.reset` start cold, from the target.  The guard:
the displayed frame is ``t + beta (x - t)`` with the objective-optimal ``beta`` in [0, 1] computed
on the GPU (two more ``K`` round trips, ``K t - T`` and ``K x - T``, and a reduction), so no frame
is worse than uncorrected.  Per frame: ``2 k + 3`` FFT round trips.  ``simulate(corrected=True)``
runs a frame too (the state advances).

``simulate()`` runs the eye's forward model the same way (the bank ``A^-1 K``,
black outside the image): what the eye sees of the displayed image, for previews.

Why ``"fista"`` is the default: on a still view its warm start makes N frames of k iterations
N k iterations, so it reaches the box-constrained optimum (``fast``'s objective within 5 % after
5 frames at k = 4, ``vrcorrect bench realtime``) where the one-pass inverse stays far from it; the
default k = 4 is the smallest k within 5 % of ``fast`` by frame 5 and past it by frame 10 (a tenth
of a second at 90 Hz; k = 2 needs 10 frames to come within 5 %, k = 1 twenty), at 2 k + 3 = 11 FFT
round trips per frame (docs/benchmarks.md).

For ``"fft"`` and ``"separable"`` the regulariser and the blend weight are chosen once per eye by
the CPU ``wiener`` method on the bundled sample image (:mod:`vrcorrect.runtime.eye_model`, which
designs on the CPU what the GPU uploads, and says how the GPU result relates to ``wiener``'s).
All GPU objects are made at build time or
on the first frame of a given size; later frames allocate nothing.  ``poll()``
reloads the prescription file when it changes on disk and keeps the last good
state (with a message in ``status``) when the new file is invalid.

Layer 5: numpy, moderngl (and onnxruntime for that backend); never torch.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Union

import numpy as np

from ..plumbing.errors import ValidationError, VrcorrectError
from ..specs.display import DisplayProfile, get_display
from ..specs.prescription import EyeRx, Prescription, load_prescription
from .eye_model import (  # noqa: F401  (re-exported)
    BACKENDS,
    FILTERS,
    MAX_ITERATIONS_PER_FRAME,
    CorrectorOptions,
    EyeModel,
    build_eye_model,
    check_iterations,
)
from .fft import FftBankGL, fft_grid
from .filters import SeparableBank
from .gl import check_gl_errors, download_texture, fullscreen_triangle, release
from .onnx_backend import OnnxModel
from .shaders import compile_compute, compile_program

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from .learned import LearnedEye, LearnedModel

__all__ = ["CorrectorOptions", "EyeModel", "Corrector", "RxSnapshot", "BACKENDS", "build_eye_model"]

log = logging.getLogger(__name__)

_GROUP = 16                                     # local_size of filter_bank.glsl


class _FrameBlend:
    """The per-frame blend weight (``shaders/blend.glsl``): two reductions and the blend.

    ``solution``: the projected-gradient guard, ``run``'s ``kd`` is the residual ``K x - T`` of the
    solution and ``delta`` the solution ``x`` itself (the blend is ``t + beta (x - t)``)."""

    def __init__(self, ctx: "moderngl.Context", size: tuple[int, int], solution: bool = False):
        self.ctx, self.size = ctx, size
        W, H = size
        self.groups = (math.ceil(W / 16), math.ceil(H / 16))
        extra = {"SOLUTION": None} if solution else {}
        self.p_partial = compile_compute(ctx, "blend.glsl", defines={"PARTIAL": None, **extra})
        self.p_final = compile_compute(ctx, "blend.glsl", defines={"FINAL": None})
        self.p_apply = compile_compute(ctx, "blend.glsl", defines={"APPLY": None, **extra})
        self.result = ctx.buffer(reserve=16)
        self.partials = ctx.buffer(reserve=16 * self.groups[0] * self.groups[1])
        # each frame's sums are copied on the GPU into a ring: the previous frame's can be read
        # while this frame's work is still queued (no wait for the GPU)
        self.history = [ctx.buffer(reserve=16) for _ in range(2)]
        self.frames = 0

    def run(self, linear: "moderngl.Texture", r0: "moderngl.Texture", kd: "moderngl.Texture",
            delta: "moderngl.Texture", out: "moderngl.Texture") -> None:
        ctx = self.ctx
        self.result.bind_to_storage_buffer(3)
        self.partials.bind_to_storage_buffer(4)
        r0.use(0)
        kd.use(1)
        self.p_partial["u_r0"] = 0
        self.p_partial["u_kd"] = 1
        self.p_partial.run(*self.groups, 1)
        ctx.memory_barrier()
        self.p_final["u_count"] = self.groups[0] * self.groups[1]
        self.p_final.run(1, 1, 1)
        ctx.memory_barrier()
        ctx.copy_buffer(self.history[self.frames % 2], self.result)
        self.frames += 1
        linear.use(0)
        delta.use(1)
        self.p_apply["u_linear_in"] = 0
        self.p_apply["u_delta"] = 1
        out.bind_to_image(1, read=False, write=True)
        self.p_apply.run(*self.groups, 1)
        ctx.memory_barrier()

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
        beta, s_rk, s_kk, s_rr = (float(v) for v in np.frombuffer(data, np.float32))
        return None if s_rr <= 0 else max(0.0, 1.0 + (2.0 * beta * s_rk + beta * beta * s_kk) / s_rr)

    def release(self) -> None:
        release(self.p_partial, self.p_final, self.p_apply, self.result, self.partials, *self.history)


class _BankGL:
    """One separable bank's taps on the GPU and its two compute programs."""

    def __init__(self, ctx: "moderngl.Context", program: str, bank: SeparableBank, border: str):
        self.ctx, self.bank = ctx, bank
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

    def run(self, linear_in: "moderngl.Texture", rows_array: "moderngl.TextureArray", out: "moderngl.Texture",
            uniforms: dict[str, float] | None = None) -> None:
        W, H = linear_in.size
        ctx = self.ctx
        linear_in.use(0)
        self.row_taps.use(1)
        self.rows_prog["u_linear_in"] = 0
        self.rows_prog["u_row_taps"] = 1
        rows_array.bind_to_image(1, read=False, write=True)
        self.rows_prog.run(math.ceil(W / _GROUP), math.ceil(H / _GROUP), self.layers)
        ctx.memory_barrier()
        linear_in.use(0)
        rows_array.use(2)
        self.col_taps.use(3)
        p = self.cols_prog
        p["u_linear_in"] = 0
        p["u_rows_in"] = 2
        p["u_col_taps"] = 3
        for name, value in (uniforms or {}).items():
            if name in p:
                p[name] = value
        out.bind_to_image(2, read=False, write=True)
        p.run(math.ceil(W / _GROUP), math.ceil(H / _GROUP), 1)
        ctx.memory_barrier()

    def release(self) -> None:
        release(self.row_taps, self.col_taps, self.rows_prog, self.cols_prog)


@dataclass(frozen=True, eq=False)
class RxSnapshot:
    """A prescription file read once: what it held, and the file's stamp (modification time and
    size) taken just before the read.  An application that corrects several eyes reads the file
    once and gives this to every eye's :class:`Corrector`, so all are built from one parse however
    long the builds take; each corrector's :meth:`Corrector.poll` then sees any later change
    (an edit made during the builds included) and handles it as hot reload does, keeping the
    last good prescription when the new file is invalid."""

    prescription: Prescription
    path: Path | None          # None: not from a file (nothing to watch)
    stamp: tuple[int, int] | None

    @classmethod
    def read(cls, path: str | os.PathLike[str]) -> "RxSnapshot":
        path = Path(path)
        stamp = _file_stamp(path)
        return cls(load_prescription(path), path, stamp)


RxSource = Union[str, "os.PathLike[str]", Prescription, RxSnapshot]
"""What :class:`Corrector` takes as ``rx``: a prescription JSON path, a prescription, or a snapshot."""

_Slot = Union[OnnxModel, "LearnedEye"]            # what runs the ONNX backend's frames


def _load_rx(rx: RxSource) -> RxSnapshot:
    if isinstance(rx, RxSnapshot):
        return rx
    if isinstance(rx, Prescription):
        return RxSnapshot(rx, None, None)
    if isinstance(rx, (str, os.PathLike)):
        return RxSnapshot.read(rx)
    raise ValidationError("rx", type(rx).__name__, "a prescription JSON path, a Prescription or an RxSnapshot")


def _check_eye_model(model: EyeModel, base: EyeRx, side: str) -> None:
    """A prebuilt model must be of this prescription's eye (as given, or with the axis wrapped into
    [0, 180) as :meth:`Corrector._rebuild` designs it)."""
    if not isinstance(model, EyeModel):
        raise ValidationError("eye_model", type(model).__name__, "an EyeModel (build_eye_model)")
    if model.eye not in (base, base.with_changes(axis_deg=base.axis_deg % 180.0)):
        raise ValidationError("eye_model.eye", _eye_text(model.eye),
                              f"a model of this prescription's {side} eye ({_eye_text(base)})")


def _eye_text(e: EyeRx) -> str:
    return (f"sphere {e.sphere_D:+g} D, cylinder {e.cylinder_D:+g} D, axis {e.axis_deg:g} deg, "
            f"pupil {e.pupil_diameter_mm:g} mm" + (", higher order" if e.higher_order is not None else ""))


def _file_stamp(path: Path) -> tuple[int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_mtime_ns, st.st_size)


class Corrector:
    """Corrects one eye's texture for its prescription (see the module docstring).

    Parameters
    ----------
    ctx
        A moderngl context with OpenGL >= 4.3 (compute shaders).
    rx
        Prescription JSON path (watched by :meth:`poll`), a :class:`~vrcorrect.specs.prescription.Prescription`,
        or an :class:`RxSnapshot` (a file read once for several eyes; watched from the moment it was
        read).
    display
        Display preset name, profile path or :class:`~vrcorrect.specs.display.DisplayProfile`.
    eye
        ``"right"`` or ``"left"``.
    backend
        ``"glsl"`` (the wiener fallback) or ``"onnx"`` (a model through onnxruntime; needs ``model=``;
        nothing is designed for the GLSL strategies then, ``filter=`` only picks :meth:`simulate`'s bank).
    eye_model
        A prebuilt :class:`EyeModel` for this eye, display and options (from :func:`build_eye_model`,
        e.g. on a worker thread): the first build uploads it instead of designing it here, so
        construction does only the GL work.  Its ``eye`` must be this prescription's eye for
        ``eye`` (``ValidationError`` otherwise); later rebuilds (:meth:`adjust`, :meth:`poll`)
        design their own.
    **options
        Fields of :class:`CorrectorOptions`.
    """

    POLL_INTERVAL_S = 0.25

    def __init__(self, ctx: "moderngl.Context", rx: RxSource, display: str | os.PathLike[str] | DisplayProfile,
                 eye: str, backend: str = "glsl", *, eye_model: EyeModel | None = None, **options: Any):
        if backend not in BACKENDS:
            raise ValidationError("backend", backend, "one of " + ", ".join(BACKENDS))
        if eye not in ("right", "left"):
            raise ValidationError("eye", eye, "'right' or 'left'")
        if ctx.version_code < 430:
            raise ValidationError("ctx", f"OpenGL {ctx.version_code}", "a context with OpenGL 4.3 or newer")
        self.ctx, self.eye_name, self.backend = ctx, eye, backend
        self.options = CorrectorOptions(backend=backend, **options)
        self.display = display if isinstance(display, DisplayProfile) else get_display(display)
        if self.display.transfer != "srgb":
            raise ValidationError("display transfer", f"{self.display.transfer} ({self.display.name})",
                                  "srgb (the real-time path encodes sRGB only so far)")
        snapshot = _load_rx(rx)
        self.prescription, self.rx_path, self._stamp = snapshot.prescription, snapshot.path, snapshot.stamp
        if eye_model is not None:                           # refused before any GL object is made
            _check_eye_model(eye_model, self.prescription.eye(eye), eye)
        self._last_poll = time.monotonic()
        self.enabled = True
        self.status = ""
        self.timings_ms: dict[str, float] = {}
        self.profile: Callable[[str], None] | None = None   # called with each stage's name once issued
        self._offset = (0.0, 0.0, 0.0)                      # live sphere, cylinder, axis changes
        self._sized: dict[tuple[int, int], dict[str, Any]] = {}
        self._decode = {srgb: compile_compute(ctx, "correction.glsl", defines={"PASS_DECODE": None, "LAYERS": 1,
                                                                          "RADIUS": 0,
                                                                          **({"SOURCE_SRGB": None} if srgb else {})})
                        for srgb in (True, False)}
        self._present = compile_program(ctx, "passthrough.glsl", defines={"ENCODE_SRGB": None})
        self._present_vao = fullscreen_triangle(ctx, self._present)
        self._onnx: _Slot | None = None
        self._learned: LearnedModel | None = None
        if backend == "onnx":
            from .learned import LearnedModel, is_learned_model  # start-up time: loads the optics and solvers

            if not self.options.model:
                raise ValidationError("model", None, "an ONNX model path for backend 'onnx'")
            if is_learned_model(self.options.model):        # one model for many eyes: bound per eye
                self._learned = LearnedModel(self.options.model)
            else:
                self._onnx = OnnxModel(self.options.model)
        self._correction_bank: _BankGL | None = None   # filter="separable" (the GLSL backend's correction)
        self._simulation_bank: _BankGL | None = None   # filter="separable" (simulate)
        self.model: EyeModel                           # set by _rebuild below
        self._iterations = self.options.iterations_per_frame
        self._fista_start = compile_compute(ctx, "fista.glsl") \
            if self.options.filter == "fista" and backend == "glsl" else None
        self._step = 0.0                               # filter="fista": the gradient step 1 / ||K||^2
        self._warm_size: tuple[int, int] | None = None   # size whose FISTA state the next frame continues
        self._momentum = 1.0
        self._motion_gl: tuple[int, int] = (0, 0)         # the next frame's reprojection, GL texels
        self._rebuild(self.prescription.eye(eye), prebuilt=eye_model)
        check_gl_errors(ctx, "Corrector build")

    # ------------------------------------------------------------------ state

    @property
    def iterations_per_frame(self) -> int:
        """``filter="fista"``: projected-gradient iterations per frame (live; 0 to 256)."""
        return self._iterations

    @iterations_per_frame.setter
    def iterations_per_frame(self, value: int) -> None:
        self._iterations = check_iterations(value)

    def reset(self) -> None:
        """Make the next frame a cold start (``filter="fista"``: iterations from the target, momentum
        reset), as a scene cut needs.  A size change, :meth:`adjust` and a reload do it too."""
        self._warm_size = None
        self._momentum = 1.0

    @property
    def eye_rx(self) -> EyeRx:
        """This eye's prescription as corrected now (file plus live changes)."""
        return self.model.eye

    @property
    def live_offset(self) -> tuple[float, float, float]:
        """The live changes :meth:`adjust` made, ``(sphere_D, cylinder_D, axis_deg)``, on top of the file's."""
        return self._offset

    def _with_offset(self, base: EyeRx) -> EyeRx:
        ds, dc, da = self._offset
        return base.with_changes(sphere_D=base.sphere_D + ds, cylinder_D=base.cylinder_D + dc,
                                 axis_deg=(base.axis_deg + da) % 180.0)

    def _rebuild(self, base_eye: EyeRx, prebuilt: EyeModel | None = None) -> None:
        from ..solvers.wiener import spectral_norm_squared  # start-up time: scipy loads with the first eye

        eye = self._with_offset(base_eye)
        if self._learned is not None:               # an eye outside the trained range: refused before the work
            self._learned.check(eye, self.display)
        model = prebuilt if prebuilt is not None else build_eye_model(eye, self.display, self.options)
        if self._learned is not None:
            bound = self._learned.for_eye(model.eye, self.display, model.kernel, model.reference)
            if self._onnx is not None:
                self._onnx.release()
            self._onnx = bound
        old = (self._correction_bank, self._simulation_bank)
        self._correction_bank = None if model.correction is None else \
            _BankGL(self.ctx, "correction.glsl", model.correction, "mirror")
        self._simulation_bank = None if model.simulation is None else \
            _BankGL(self.ctx, "simulation.glsl", model.simulation, "zero")
        self.model = model
        self._step = float(np.float32(1.0 / spectral_norm_squared(model.kernel.kernel)))   # 1 / ||K||^2
        for b in old:
            if b is not None:
                b.release()
        self._release_sized()                      # per-size work depends on the eye: remade on use
        self.reset()

    def _release_sized(self) -> None:
        for res in self._sized.values():
            for v in res.values():
                v.release() if isinstance(v, (FftBankGL, _FrameBlend)) else release(v)
        self._sized.clear()

    def adjust(self, sphere_D: float = 0.0, cylinder_D: float = 0.0, axis_deg: float = 0.0) -> None:
        """Change this eye's prescription live by these amounts and rebuild (the file is unchanged).

        Raises ``ValidationError`` (and keeps the current state) when the result is out of range.
        """
        previous = self._offset
        self._offset = (previous[0] + sphere_D, previous[1] + cylinder_D, previous[2] + axis_deg)
        try:
            self._rebuild(self.prescription.eye(self.eye_name))
        except VrcorrectError:
            self._offset = previous
            raise

    def poll(self) -> bool:
        """Reload the prescription if its file changed (checked at most every 0.25 s).

        Returns True when a new prescription was loaded.  An unreadable or invalid file leaves
        the last good state in place and says why in :attr:`status`.
        """
        if self.rx_path is None:
            return False
        now = time.monotonic()
        if now - self._last_poll < self.POLL_INTERVAL_S:
            return False
        self._last_poll = now
        stamp = _file_stamp(self.rx_path)
        if stamp == self._stamp:
            return False
        self._stamp = stamp
        try:
            rx = load_prescription(self.rx_path)
            self._rebuild(rx.eye(self.eye_name))
        except VrcorrectError as exc:
            self.status = f"{self.rx_path}: not reloaded, keeping the last good prescription: {exc}"
            log.warning(self.status)
            return False
        self.prescription = rx
        self.status = ""
        log.info("%s: reloaded (%s eye)", self.rx_path, self.eye_name)
        return True

    # ------------------------------------------------------------------ frames

    def _resources(self, size: tuple[int, int]) -> dict[str, Any]:
        res = self._sized.get(size)
        if res is None:
            ctx = self.ctx
            W, H = size

            def tex() -> "moderngl.Texture":
                t = ctx.texture(size, 4, dtype="f4")
                t.filter = (ctx.NEAREST, ctx.NEAREST)
                return t

            res = {"linear": tex(), "corrected": tex(), "seen": tex()}
            if self._fista_start is not None:
                res.update(x=tex(), y=tex(), t_prev=tex(), target=tex(), r=tex(), r0=tex(), kd=tex(),
                           x_src=tex(), y_src=tex(), t_prev_src=tex())   # a shifted warm start's sources
            elif self._per_frame_blend:
                res.update(delta=tex(), r0=tex(), kd=tex())
            if self._simulation_bank is not None:
                banks = (b for b in (self._correction_bank, self._simulation_bank) if b is not None)
                rows = ctx.texture_array((W, H, max(b.layers for b in banks)), 4, dtype="f4")
                rows.filter = (ctx.NEAREST, ctx.NEAREST)
                res["rows"] = rows
            else:
                res.update(self._fft_banks(size))
            self._sized[size] = res
        return res

    @property
    def _per_frame_blend(self) -> bool:
        """The GLSL backend's FFT strategy computes the blend weight of every frame on the GPU."""
        return self.backend == "glsl" and self.options.per_frame_blend

    def _fft_banks(self, size: tuple[int, int]) -> dict[str, Any]:
        """The FFT strategy's banks for this image size (spectra computed on the CPU once per size):
        the forward model for :meth:`simulate`, and what the GLSL backend's correction needs."""
        from ..solvers.wiener import centred_kernel, inverse_spectrum  # start-up time (see _rebuild)

        m = self.model
        margin = m.margin
        grid = fft_grid(*size, margin)
        k = m.kernel
        Kf = np.fft.fft2(centred_kernel(k.kernel, grid), axes=(2, 3))                    # K(f), once
        sim = np.einsum("ik,kjyx->ijyx", np.linalg.inv(k.matrix), Kf)                     # A^-1 K(f)
        out: dict[str, Any] = {"fft_sim": FftBankGL(self.ctx, sim, size, margin, border="zero", combine="clip")}
        if m.identity or self.backend != "glsl":
            return out
        # the target's spectrum: T = K_ref t (glasses) or A t (ideal)
        Tf = (np.fft.fft2(centred_kernel(m.reference.kernel, grid), axes=(2, 3)) if m.reference is not None
              else np.broadcast_to(k.matrix[:, :, None, None], Kf.shape))
        if self._fista_start is not None:
            # K y - T and K^H r (exact linear convolutions, black outside)
            out["fft_k"] = FftBankGL(self.ctx, Kf, size, margin, border="zero", combine=("residual", "fista"),
                                     adjoint=True)
            out["fft_target"] = FftBankGL(self.ctx, Tf, size, margin, border="zero", combine="raw")
            out["blend"] = _FrameBlend(self.ctx, size, solution=True)
            return out
        spectrum = inverse_spectrum(k, m.mu_rel, grid, m.reference)
        frame = self._per_frame_blend
        out["fft_correct"] = FftBankGL(self.ctx, spectrum, size, margin, border="mirror",
                                       combine="delta" if frame else "correct")
        if frame:
            out["fft_r0"] = FftBankGL(self.ctx, Kf - Tf, size, margin, border="zero", combine="raw")
            out["fft_k"] = FftBankGL(self.ctx, Kf, size, margin, border="zero", combine="raw")
            out["blend"] = _FrameBlend(self.ctx, size)
        return out

    def fft_grid_for(self, size: tuple[int, int]) -> tuple[tuple[int, int], int]:
        """The FFT strategy's ``(NY, NX)`` grid and margin for an image of ``size`` (W, H)."""
        return fft_grid(*size, self.model.margin), self.model.margin

    def _decode_source(self, src: "moderngl.Texture") -> dict[str, Any]:
        res = self._resources(tuple(src.size))
        srgb = src.dtype == "f1"
        prog = self._decode[srgb]
        src.use(0)
        prog["u_source"] = 0
        res["linear"].bind_to_image(0, read=False, write=True)
        W, H = src.size
        prog.run(math.ceil(W / _GROUP), math.ceil(H / _GROUP), 1)
        self.ctx.memory_barrier()
        return res

    def _correct(self, res: dict[str, Any]) -> "moderngl.Texture":
        if not self.enabled:
            return res["linear"]
        if self._onnx is not None:
            self._onnx.run(res["linear"], res["corrected"])
        elif self.model.identity:
            return res["linear"]
        elif self._correction_bank is not None:
            self._correction_bank.run(res["linear"], res["rows"], res["corrected"], {"u_beta": self.model.beta})
        elif self._fista_start is not None:
            self._fista_frame(res)
        elif "blend" in res:                        # per-frame blend weight, on the GPU
            res["fft_correct"].run(res["linear"], res["delta"])
            res["fft_r0"].run(res["linear"], res["r0"])
            res["fft_k"].run(res["delta"], res["kd"])
            res["blend"].run(res["linear"], res["r0"], res["kd"], res["delta"], res["corrected"])
        else:
            res["fft_correct"].run(res["linear"], res["corrected"], beta=self.model.beta)
        return res["corrected"]

    def _fista_frame(self, res: dict[str, Any]) -> None:
        """``k`` projected-gradient (FISTA) iterations on the true objective, warm-started from the
        previous frame's solution, then the guard (module docstring)."""
        from ..solvers.wiener import fista_momentum  # start-up time (see _rebuild; already loaded here)

        ctx = self.ctx
        linear = res["linear"]
        W, H = size = tuple(linear.size)
        cold = self._warm_size != size
        shift = (0, 0) if cold else self._motion_gl
        self._motion_gl = (0, 0)
        if cold:
            self._momentum = 1.0
        state = ("x", "y", "t_prev")
        if shift != (0, 0):
            # The previous state moves to the *_src textures (a swap: nothing is allocated) and the
            # shader writes the reprojected state into the others: read and write must differ.
            # FISTA's extrapolated point y moves with x and the momentum is kept (not reset): after
            # the move, y - x is the same step as before, only displaced with the content, so the
            # extrapolation is still a good one; the CPU twin (bench realtime's "reprojected"
            # strategy, and test_runtime_motion) reaches fast's objective faster this way than a
            # warm start without reprojection.  Exposed pixels restart from the target (x = y = t).
            for name in state:
                res[name], res[name + "_src"] = res[name + "_src"], res[name]
        prog = self._fista_start
        linear.use(0)
        prog["u_linear_in"] = 0
        prog["u_cold"] = cold
        prog["u_shift"] = shift
        for unit, name in enumerate(state):
            res[name].bind_to_image(unit, read=True, write=True)
            res[name + "_src" if shift != (0, 0) else name].bind_to_image(unit + 3, read=True, write=False)
        prog.run(math.ceil(W / _GROUP), math.ceil(H / _GROUP), 1)
        ctx.memory_barrier()
        self._warm_size = size
        k, T = res["fft_k"], res["target"]
        res["fft_target"].run(linear, T)
        self._mark("start")
        step = self._step
        for _ in range(self._iterations):
            k.run(res["y"], res["r"], combine="residual", other=T)                    # K y - T
            self._momentum, weight = fista_momentum(self._momentum)
            k.run(res["r"], res["y"], combine="fista", adjoint=True, solution=res["x"],   # x, y updated
                  step=step, weight=float(np.float32(weight)))
        self._mark("iterations")
        k.run(linear, res["r0"], combine="residual", other=T)                        # guard: K t - T
        k.run(res["x"], res["kd"], combine="residual", other=T)                      # K x - T
        res["blend"].run(linear, res["r0"], res["kd"], res["x"], res["corrected"])
        self._mark("guard")

    def solution(self, size: tuple[int, int]) -> np.ndarray | None:
        """``filter="fista"``: the current solution ``x`` for images of ``size`` (W, H) before the
        guard's blend, linear RGB ``(H, W, 3)`` float32 rows top first (reads it back: a sync)."""
        res = self._sized.get(tuple(size))
        return None if res is None or "x" not in res else download_texture(res["x"])[..., :3].copy()

    def last_objective_fraction(self, size: tuple[int, int]) -> float | None:
        """The last frame's objective as a fraction of uncorrected (per-frame blend and ``"fista"``;
        reads it back: a sync)."""
        res = self._sized.get(tuple(size))
        return res["blend"].objective_fraction() if res is not None and "blend" in res else None

    def previous_objective_fraction(self, size: tuple[int, int]) -> float | None:
        """The objective of the frame before the last, as a fraction of uncorrected, read without
        waiting for the GPU (each frame's sums are copied into a two-slot ring on the GPU; this
        reads the slot the last frame did not write): what a live panel shows, one frame late.
        ``None`` before the second frame of ``size``, for a perfect target, or without a per-frame
        guard (``filter="separable"``, ``blend="fixed"``, the identity)."""
        res = self._sized.get(tuple(size))
        return res["blend"].objective_fraction(previous=True) if res is not None and "blend" in res else None

    def last_blend(self, size: tuple[int, int]) -> float | None:
        """The blend weight of the last frame of ``size`` (per-frame mode; reads it back: a sync)."""
        res = self._sized.get(tuple(size))
        return res["blend"].beta() if res is not None and "blend" in res else None

    def _present_to(self, texture: "moderngl.Texture", dst: "moderngl.Framebuffer",
                    viewport: tuple[int, int, int, int] | None) -> None:
        texture.use(0)
        self._present["u_source"] = 0
        dst.use()
        vp = viewport if viewport is not None else (0, 0, *dst.size)
        dst.viewport = vp
        self._present_vao.render(mode=self.ctx.TRIANGLES, vertices=3)

    def _set_motion(self, motion_px: tuple[float, float] | None) -> None:
        """Keep ``motion_px`` = ``(dx, dy)`` (image pixels, x to the right, y down, rounded to whole
        pixels; ``None``: no motion) for this frame's warm start, in GL texel coordinates (rows
        bottom first, so y flips)."""
        if motion_px is None:
            self._motion_gl = (0, 0)
            return
        try:
            dx, dy = (float(v) for v in motion_px)
        except (TypeError, ValueError):
            raise ValidationError("motion_px", motion_px, "None or (dx, dy) in pixels") from None
        if not (math.isfinite(dx) and math.isfinite(dy)):
            raise ValidationError("motion_px", motion_px, "finite (dx, dy) in pixels")
        big = 1 << 20
        self._motion_gl = (int(round(min(max(dx, -big), big))), -int(round(min(max(dy, -big), big))))

    def apply(self, src_texture: "moderngl.Texture", dst_framebuffer: "moderngl.Framebuffer", viewport: tuple[int, int, int, int] | None = None,
              motion_px: tuple[float, float] | None = None) -> None:
        """Correct ``src_texture`` (RGBA8 sRGB code values, or float linear light) into
        ``dst_framebuffer`` (sRGB-encoded), in ``viewport`` (GL x, y, width, height) or all of it.

        ``motion_px``: with ``filter="fista"``, the content's displacement since the previous frame,
        ``(dx, dy)`` in image pixels (x to the right, y down; ``new(p) ~ previous(p - d)``), rounded
        to whole pixels: the warm start is the previous solution reprojected by it (module
        docstring).  ``None`` or ``(0, 0)``: the plain warm start.  Other filters ignore it.  On a
        scene cut call :meth:`reset` instead."""
        t0 = time.perf_counter()
        self._set_motion(motion_px)
        res = self._decode_source(src_texture)
        self._mark("decode")
        out = self._correct(res)
        self._mark("correct")
        self._present_to(out, dst_framebuffer, viewport)
        self._mark("present")
        self.timings_ms = {"correct": 1e3 * (time.perf_counter() - t0)}

    def _mark(self, stage: str) -> None:
        """Tell :attr:`profile` (when set) that ``stage``'s GL work has been issued: ``apply`` marks
        ``decode``, ``correct`` and ``present``; ``filter="fista"`` also ``start`` (warm start and the
        target ``T``), ``iterations`` and ``guard`` within ``correct``.  A benchmark's hook calls
        ``ctx.finish()`` there and reads the clock (``vrcorrect bench realtime``)."""
        if self.profile is not None:
            self.profile(stage)

    def simulate(self, src_texture: "moderngl.Texture", dst_framebuffer: "moderngl.Framebuffer", viewport: tuple[int, int, int, int] | None = None,
                 corrected: bool = True, motion_px: tuple[float, float] | None = None) -> None:
        """What this eye sees of ``src_texture`` as displayed (after the correction when
        ``corrected`` and the correction is enabled), sRGB-encoded into ``dst_framebuffer``;
        ``motion_px`` as for :meth:`apply`."""
        t0 = time.perf_counter()
        self._set_motion(motion_px)
        res = self._decode_source(src_texture)
        shown = self._correct(res) if corrected else res["linear"]
        if self._simulation_bank is not None:
            self._simulation_bank.run(shown, res["rows"], res["seen"])
        else:
            res["fft_sim"].run(shown, res["seen"])
        self._present_to(res["seen"], dst_framebuffer, viewport)
        self.timings_ms = {"simulate": 1e3 * (time.perf_counter() - t0)}

    def describe(self) -> dict[str, Any]:
        """What was built: prescription, regulariser, blend, strategy and its cost figures."""
        m = self.model
        info = {"eye": self.eye_name, "sphere_D": m.eye.sphere_D, "cylinder_D": m.eye.cylinder_D,
                "axis_deg": m.eye.axis_deg, "display": self.display.name, "backend": self.backend,
                "filter": self.options.filter, "kernel_size": m.kernel.size, "mu_rel": m.mu_rel, "beta": m.beta,
                "identity": m.identity, "margin": m.margin, "build_seconds": m.build_seconds,
                "notes": list(m.notes)}
        if self.options.filter == "fista":
            info["iterations_per_frame"] = self._iterations
        if m.correction is not None:
            info.update(filter_size=m.correction.size, ranks=list(m.correction.ranks),
                        taps_per_pixel=m.correction.taps_per_pixel, rank_error=m.correction.error)
        if m.simulation is not None:
            info.update(simulation_size=m.simulation.size, simulation_ranks=list(m.simulation.ranks))
        return info

    def release(self) -> None:
        for b in (self._correction_bank, self._simulation_bank):
            if b is not None:
                b.release()
        self._release_sized()
        release(self._present_vao, self._present, *self._decode.values(), self._fista_start)
        if self._onnx is not None:
            self._onnx.release()
