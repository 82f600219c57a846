"""The plugin: correct an eye's texture for that eye's prescription, in OpenGL.

``Corrector(ctx, rx, display, eye, backend)`` is built once per prescription and eye;
``apply(src_texture, dst_framebuffer)`` then runs every frame.  It is a thin facade:

1. **decode** the source's sRGB code values (or float linear light) into the strategy's linear
   texture (compute pass);
2. **correct** it with the strategy of the eye (:mod:`vrcorrect.runtime.strategies`): ``"admm"``
   (the default: ADMM iterations on the true objective spread over frames), ``"fista"``
   (projected-gradient iterations spread over frames), ``"fft"`` or ``"separable"`` (the
   regularised inverse in one pass), or with ``backend="onnx"`` a model through onnxruntime;
3. **present**: encode to sRGB into the caller's framebuffer (a fragment pass; a strategy may fuse
   its last step into it).

Every pass runs through :class:`~vrcorrect.runtime.dispatch.Gpu`: attach a
:class:`~vrcorrect.runtime.dispatch.CostLedger` (:attr:`Corrector.ledger`) and each frame's
dispatches, FFT round trips and bytes are counted from the passes themselves (``vrcorrect bench
cost``).

What is designed on the CPU per eye (the kernel; for the one-pass methods the regulariser, the
blend and the filters) is an :class:`~vrcorrect.runtime.eye_model.EyeModel`; the corrector turns a
model into a strategy on the GL thread (:meth:`Corrector.install`).  The prescription (the file,
its stamp, the live changes) has one owner, an :class:`~vrcorrect.runtime.eye_source.EyeSource`:
the application's, shared by its correctors and designing off the render thread (the mirror, the
overlay, ``xr``; give it as ``rx``), or the corrector's own synchronous one, which
:meth:`Corrector.poll` and :meth:`Corrector.adjust` drive for a library user.

``simulate()`` runs the eye's forward model (the bank ``A^-1 K``, black outside the image): what
the eye sees of the displayed image, for previews.

Layer 5: numpy, moderngl (and onnxruntime for that backend); never torch.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from ..plumbing.errors import ValidationError, VrcorrectError
from ..specs.display import DisplayProfile, get_display
from ..specs.prescription import EyeRx, Prescription
from ..specs.vocabulary import ITERATIONS_PER_FRAME, ITERATIVE_FILTERS, Backend, Eye, either, names, one_of
from .budget import FrameBudget, GpuTimer, radius_ladder
from .dispatch import CostLedger, Gpu
from .eye_model import CorrectorOptions, EyeModel, as_options, build_eye_model, check_iterations  # noqa: F401  (re-exported)
from .eye_source import EyeSource
from .fft import fft_grid
from .gl import check_gl_errors, release
from .onnx_backend import OnnxModel
from .pupil_state import PupilState
from .rx_snapshot import RxSource, eye_text
from .strategies import Decoder, Encoder, Preview, Strategy, make_strategy
from .strategies.base import float_texture
from .strategies.foveated import MIN_FOVEA_DEG

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from .learned import LearnedModel
    from .unrolled import UnrolledModel

__all__ = ["CorrectorOptions", "EyeModel", "Corrector", "build_eye_model", "runs_iterations"]

log = logging.getLogger(__name__)


def check_eye_model(model: EyeModel, base: EyeRx, side: str) -> None:
    """A prebuilt model must be of this prescription's eye (as given, or with the axis wrapped into
    [0, 180) as :meth:`Corrector.adjust` designs it)."""
    if not isinstance(model, EyeModel):
        raise ValidationError("eye_model", type(model).__name__, "an EyeModel (build_eye_model)")
    if model.eye not in (base, base.with_changes(axis_deg=base.axis_deg % 180.0)):
        raise ValidationError("eye_model.eye", eye_text(model.eye),
                              f"a model of this prescription's {side} eye ({eye_text(base)})")


class Corrector:
    """Corrects one eye's texture for its prescription (see the module docstring).

    Parameters
    ----------
    ctx
        A moderngl context with OpenGL >= 4.3 (compute shaders).
    rx
        The application's :class:`~vrcorrect.runtime.eye_source.EyeSource` (shared by its correctors:
        it owns the prescription, and the application polls it and :meth:`install`\\ s what it
        designs); or, for a corrector with a synchronous source of its own (:meth:`poll`,
        :meth:`adjust`), a prescription JSON path (watched by :meth:`poll`), a
        :class:`~vrcorrect.specs.prescription.Prescription`, or an
        :class:`~vrcorrect.runtime.rx_snapshot.RxSnapshot` (a file read once; watched from the moment
        it was read).
    display
        Display preset name, profile path or :class:`~vrcorrect.specs.display.DisplayProfile`.
    eye
        ``"right"`` or ``"left"``.
    backend
        ``"glsl"`` (the strategies of ``filter=``) or ``"onnx"`` (a model through onnxruntime; needs
        ``model=``; ``filter=`` then only picks :meth:`simulate`'s bank).
    eye_model
        A prebuilt :class:`EyeModel` for this eye, display and options (from :func:`build_eye_model`,
        e.g. on a worker thread): the first build uploads it instead of designing it here, so
        construction does only the GL work.  Its ``eye`` must be this prescription's eye for
        ``eye`` (``ValidationError`` otherwise).
    options, **fields
        The :class:`CorrectorOptions`, made or as their fields (not both).
    first_luminance, first_band
        With ``pupil="auto"``: the first frame's mean relative luminance and, with ``band="auto"``, its
        band (``"page"`` or ``"default"``, :func:`~vrcorrect.runtime.pupil_bank.codes_band`), so that
        the first design is the first frame's (None: a mid-grey frame's light, the default band).
    """

    def __init__(self, ctx: "moderngl.Context", rx: RxSource | EyeSource, display: str | os.PathLike[str] | DisplayProfile,
                 eye: str, backend: str = Backend.GLSL, *, eye_model: EyeModel | None = None,
                 options: CorrectorOptions | None = None, first_luminance: float | None = None,
                 first_band: str | None = None, **fields: Any):
        if backend not in names(Backend):
            raise ValidationError("backend", backend, one_of(Backend))
        if eye not in names(Eye):
            raise ValidationError("eye", eye, either(Eye))
        if ctx.version_code < 430:
            raise ValidationError("ctx", f"OpenGL {ctx.version_code}", "a context with OpenGL 4.3 or newer")
        self.ctx, self.eye_name, self.backend = ctx, eye, backend
        if options is not None and fields:
            raise ValidationError("options", ", ".join(fields), "CorrectorOptions or its fields, not both")
        self.options = as_options(backend, options if options is not None else fields)
        self.display = display if isinstance(display, DisplayProfile) else get_display(display)
        if self.display.transfer != "srgb":
            raise ValidationError("display transfer", f"{self.display.transfer} ({self.display.name})",
                                  "srgb (the real-time path encodes sRGB only so far)")
        self._owns_source = not isinstance(rx, EyeSource)
        self.source: EyeSource = rx if isinstance(rx, EyeSource) else \
            EyeSource(rx, self.display, self.options, eyes=(eye,), check=self.check_eye, design=self._design,
                      worker=False)
        """The prescription's owner (module docstring)."""
        if eye not in self.source.eyes:
            raise ValidationError("eye", eye, f"an eye of the shared EyeSource ({', '.join(self.source.eyes)})")
        if eye_model is not None:                           # refused before any GL object is made
            check_eye_model(eye_model, self.source.eye_rx(eye) if eye in self.source.offsets
                            else self.prescription.eye(eye), eye)
        self.enabled = True
        self.status = ""
        self.timings_ms: dict[str, float] = {}
        self.gpu = Gpu(ctx)
        self.gaze_deg: tuple[float, float] = self.options.gaze_deg
        """Where the eye looks, degrees from the view's centre ``(x, y)``, x right, y up (OpenXR's view
        space): the window's centre with ``fovea_deg`` (set it before each :meth:`apply`)."""
        self.budget: FrameBudget | None = None
        """With ``budget_ms``: what holds the frame's GPU time at the budget (its choice: ``describe()``)."""
        self._timer: GpuTimer | None = None
        if self.options.budget_ms is not None:
            self._timer = GpuTimer()
            self.budget = FrameBudget(self.options.budget_ms, radius_ladder(self.options.fovea_deg, MIN_FOVEA_DEG),
                                      ITERATIONS_PER_FRAME, start=max(self.options.iterations_per_frame, 1))
        self.decoder = Decoder(self.gpu)
        self.encoder = Encoder(self.gpu)
        self._seen: dict[tuple[int, int], "moderngl.Texture"] = {}
        self._onnx: OnnxModel | None = None
        self._learned: LearnedModel | UnrolledModel | None = None
        if backend == Backend.ONNX:
            from .learned import LEARNED_FORMAT, LearnedModel, model_metadata  # start-up time: optics, solvers
            from .unrolled import UNROLLED_FORMATS, UnrolledModel  # start-up time: optics, solvers

            if not self.options.model:
                raise ValidationError("model", None, "an ONNX model path for backend 'onnx'")
            fmt = model_metadata(self.options.model).get("vrcorrect.format")
            if fmt == LEARNED_FORMAT:                       # one model for many eyes: bound per eye
                self._learned = LearnedModel(self.options.model)
            elif fmt in UNROLLED_FORMATS:                  # the unrolled correction alone, every frame
                self._learned = UnrolledModel(self.options.model)
            else:
                self._onnx = OnnxModel(self.options.model)
        self.model: EyeModel                                # set by install below
        self.strategy: Strategy | None = None
        self.preview: Preview | None = None
        self._motion_gl: tuple[int, int] = (0, 0)           # the next frame's reprojection, GL texels
        self._cold_model: "UnrolledModel | None" = None
        if self.options.cold_start_model is not None:
            from .unrolled import UnrolledModel  # start-up time: onnxruntime, only when asked for

            self._cold_model = UnrolledModel(self.options.cold_start_model)
        eye_rx = self.source.eye_rx(eye)
        self.check_eye(eye_rx)                              # an eye outside the learned range: refused first
        self.frame_time_s: float | None = None
        """The time between frames for the pupil's dynamics (``pupil="auto"``): None, the wall clock
        between :meth:`apply` calls; a batch render sets its clip's frame time."""
        self._pupil: PupilState | None = None
        if self.options.pupil == "auto":
            self._pupil = PupilState(self, first_luminance, first_band)
        if eye_model is None:
            pupil = None if self._pupil is None else self._pupil.first_entry(eye_rx)
            eye_model = build_eye_model(eye_rx, self.display, self.options, pupil_mm=pupil, age_years=self.age_years,
                                        kernels=None if self._pupil is None else self._pupil.kernels,
                                        band="default" if self._pupil is None else self._pupil.band)
        self.install(eye_model)
        check_gl_errors(ctx, "Corrector build")

    @property
    def prescription(self) -> Prescription:
        """The last good prescription (its owner's, :attr:`source`)."""
        return self.source.prescription

    @property
    def rx_path(self) -> "os.PathLike[str] | None":
        """The prescription file the source watches (``None``: not from a file)."""
        return self.source.path

    @property
    def age_years(self) -> float | None:
        """The wearer's age for the pupil's formula: the options', else the prescription's."""
        return self.options.age_years if self.options.age_years is not None else self.prescription.age_years

    def keep_pupil_designs(self, env: Mapping[str, str] | None = None) -> None:
        """Keep the pupil bank's designs (``pupil="auto"``) between runs in the cache folder of ``env``
        (:mod:`~vrcorrect.runtime.eye_cache`; None: this process's environment), and use those kept:
        an application started again follows the light without designing again (the OpenXR layer)."""
        if self._pupil is not None:
            self._pupil.cache_env = dict(os.environ if env is None else env)

    def follow_light_now(self, wait_s: float, stopped: Callable[[], bool] = lambda: False) -> float | None:
        """``pupil="auto"``: switch now to the design for the light of the frame just corrected, waiting at
        most ``wait_s`` for the bank's worker to design it (:meth:`PupilState.follow_now
        <vrcorrect.runtime.pupil_state.PupilState.follow_now>`; a build's priming, never an
        application's frame).  Returns the light's design's pupil, now in use, or None (not in use)."""
        return None if self._pupil is None else self._pupil.follow_now(wait_s, stopped)

    @property
    def pupil_status(self) -> str:
        """The viewing pupil now, in words (``layer status``, the mirror's text): empty for a fixed pupil."""
        return "" if self._pupil is None else self._pupil.status()

    # ------------------------------------------------------------------ the eye

    @property
    def ledger(self) -> CostLedger | None:
        """Where every pass's cost is recorded (``None``: not recorded)."""
        return self.gpu.ledger

    @ledger.setter
    def ledger(self, value: CostLedger | None) -> None:
        self.gpu.ledger = value

    @property
    def profile(self) -> Any:
        """Called with each stage's name once its GL work is issued (``decode``, the strategy's
        stages, ``present``): a benchmark's hook calls ``ctx.finish()`` there and reads the clock."""
        return self.gpu.profile

    @profile.setter
    def profile(self, hook: Any) -> None:
        self.gpu.profile = hook

    @property
    def iterations_per_frame(self) -> int:
        """The iterative methods' iterations per frame (live; 0 to 256)."""
        return self.options.iterations_per_frame

    @iterations_per_frame.setter
    def iterations_per_frame(self, value: int) -> None:
        value = check_iterations(value)
        if value != self.options.iterations_per_frame:
            self.options = replace(self.options, iterations_per_frame=value)   # the count's one place
        if self.strategy is not None and self.strategy.iterative:
            self.strategy.iterations_per_frame = value

    def reset(self) -> None:
        """Make the next frame a cold start (the iterative methods: from the target), as a scene cut
        needs.  A size change, :meth:`adjust`, :meth:`install` and a reload do it too.  With
        ``band="auto"`` the next frame is looked at at once (:meth:`PupilState.cut
        <vrcorrect.runtime.pupil_state.PupilState.cut>`)."""
        if self.strategy is not None:
            self.strategy.reset()
        if self._pupil is not None:
            self._pupil.cut()

    @property
    def eye_rx(self) -> EyeRx:
        """This eye's prescription as corrected now (file plus live changes)."""
        return self.model.eye

    @property
    def live_offset(self) -> tuple[float, float, float]:
        """The live changes in the model corrected with now, ``(sphere_D, cylinder_D, axis_deg)`` on
        top of the file's (:meth:`EyeSource.handed_offset <vrcorrect.runtime.eye_source.EyeSource.handed_offset>`)."""
        return self.source.handed_offset(self.eye_name)

    def check_eye(self, eye: EyeRx) -> None:
        """Refuse (``ValidationError``) an eye this corrector cannot correct: outside the learned
        model's range with that backend; any eye otherwise."""
        kernels = self.options.kernel_options
        distance = kernels.optics.viewing_distance_m if kernels is not None else None  # None: the display's
        if self._learned is not None:
            self._learned.check(eye, self.display, distance)
        if self._cold_model is not None:
            self._cold_model.check(eye, self.display, distance)

    def install(self, model: EyeModel) -> None:
        """Correct with ``model`` from the next frame on (GL work only: what the CPU designs is in
        the model; the prescription it is from is the source's).  The old strategy is released and
        the next frame starts cold."""
        self._new_strategy(model)
        if self._pupil is not None:
            self._pupil.installed(model)

    def _new_strategy(self, model: EyeModel) -> None:
        """Make the strategy and preview of ``model`` and release the old ones (what :meth:`install`
        and a switch that cannot swap in place share)."""
        if not isinstance(model, EyeModel):
            raise ValidationError("eye_model", type(model).__name__, "an EyeModel (build_eye_model)")
        slot = None
        # a robust design's light cap holds in the unrolled model too (a model that has the input for it)
        capped = bool(getattr(model.design, "capped", False))
        if self._learned is not None:
            slot = self._learned.for_eye(model.eye, self.display, model.kernel, model.reference, capped=capped)
        elif self._onnx is not None:
            slot = self._onnx
        old = (self.strategy, self.preview)
        self.strategy = make_strategy(self.gpu, model, self.options, self.encoder, self.decoder, slot,
                                      ppd=self.display.pixels_per_degree)
        if self._cold_model is not None and not model.identity and hasattr(self.strategy, "use_first_guess"):
            self.strategy.use_first_guess(self._cold_model.for_eye(model.eye, self.display, model.kernel,
                                                                   model.reference, capped=capped))
        self.preview = Preview(self.gpu, model)
        self.model = model
        release(*old)

    def switch_design(self, model: EyeModel) -> None:
        """Correct with another design of the same eye from the next frame (a pupil bank's switch): the
        iterative default goes on from its state with the new kernels' spectra (nothing built on this
        thread but the upload); another strategy is installed anew (a cold start)."""
        swap = getattr(self.strategy, "swap_model", None)
        if swap is not None and swap(model):
            self.model = model
            self.preview.release()
            self.preview = Preview(self.gpu, model)
        else:
            self._new_strategy(model)            # a switch all the same (the status counts it), by a new strategy
        if self._pupil is not None:
            self._pupil.installed(model, switched=True)

    def adjust(self, sphere_D: float = 0.0, cylinder_D: float = 0.0, axis_deg: float = 0.0) -> None:
        """Change this eye's prescription live by these amounts and rebuild now, on this thread (the
        file is unchanged).  A corrector with its own source only: with a shared
        :class:`~vrcorrect.runtime.eye_source.EyeSource` the application asks the source
        (:meth:`EyeSource.adjust <vrcorrect.runtime.eye_source.EyeSource.adjust>`, designed off the
        render thread) and installs what it hands over.

        Raises ``ValidationError`` (and keeps the current state) when the result is out of range.
        """
        self._own_source("adjust")
        ds, dc, da = self.source.offsets.get(self.eye_name, (0.0, 0.0, 0.0))
        self.source.adjust(self.eye_name, (ds + sphere_D, dc + cylinder_D, da + axis_deg))
        updates, messages = self.source.take()
        self._install_updates(updates)
        if messages:
            raise VrcorrectError(messages[0])

    def poll(self) -> bool:
        """Reload the prescription if its file changed (checked at most every 0.25 s), now, on this
        thread (a corrector with its own source only, as :meth:`adjust`).

        Returns True when a new prescription was loaded.  An unreadable or invalid file leaves
        the last good state in place and says why in :attr:`status`.
        """
        self._own_source("poll")
        updates, messages = self.source.poll()
        self._install_updates(updates)
        if messages:
            self.status = messages[-1]
            return False
        if updates:
            self.status = ""
            log.info("%s: reloaded (%s eye)", self.rx_path, self.eye_name)
        return bool(updates)

    def _own_source(self, what: str) -> None:
        if not self._owns_source:
            raise ValidationError(f"Corrector.{what}", "a corrector of a shared EyeSource",
                                  f"a corrector with its own source (the application calls EyeSource.{what} "
                                  "and installs what it hands over)")

    def _install_updates(self, updates) -> None:
        for u in updates:
            if u.eye == self.eye_name:
                self.install(u.model)

    def _design(self, eye: str, eye_rx: EyeRx, rx: Prescription) -> EyeModel:
        """How its own source designs this eye: for the pupil it sees now (``pupil="auto"``), with
        the options as they are now."""
        age = self.options.age_years if self.options.age_years is not None else rx.age_years
        return build_eye_model(eye_rx, self.display, self.options, pupil_mm=self._design_pupil(), age_years=age)

    def _design_pupil(self) -> float | None:
        """The pupil a rebuilt model is designed for: the current one with ``pupil="auto"``."""
        return self._pupil.current if self._pupil is not None else None

    # ------------------------------------------------------------------ frames

    def fft_grid_for(self, size: tuple[int, int]) -> tuple[tuple[int, int], int]:
        """The FFT strategies' ``(NY, NX)`` grid and margin for an image of ``size`` (W, H)."""
        return fft_grid(*size, self.model.margin), self.model.margin

    def _decode_source(self, src: "moderngl.Texture") -> "moderngl.Texture":
        self.strategy.look(self.gaze_deg, tuple(src.size), self.display.pixels_per_degree)
        self.gpu.begin("decode")
        return self.strategy.decode(src, self._motion_gl)

    def _decode_and_follow(self, src: "moderngl.Texture") -> "moderngl.Texture":
        """The frame in linear light, its light measured and followed (``pupil="auto"``).  A switch of
        the pupil's design that installs a new strategy (one without ``swap_model``: the filters) releases
        the old one and the texture it decoded into, so the frame is decoded again by the new one."""
        linear = self._decode_source(src)
        if self._pupil is not None:
            strategy = self.strategy
            self._pupil.frame(linear)
            if self.strategy is not strategy:
                linear = self._decode_source(src)
        return linear

    def _correct(self, linear: "moderngl.Texture") -> "moderngl.Texture":
        self.gpu.begin("correct")
        motion, self._motion_gl = self._motion_gl, (0, 0)
        return self.strategy.correct(linear, motion)

    def solution(self, size: tuple[int, int]) -> np.ndarray | None:
        """The iterative methods' current solution for images of ``size`` (W, H) before the
        guard's blend, linear RGB ``(H, W, 3)`` float32 rows top first (reads it back: a sync)."""
        return self.strategy.solution(tuple(size))

    def last_objective_fraction(self, size: tuple[int, int]) -> float | None:
        """The last frame's objective as a fraction of uncorrected (the methods with a per-frame
        guard; reads it back: a sync)."""
        return self.strategy.objective_fraction(tuple(size))

    def previous_objective_fraction(self, size: tuple[int, int]) -> float | None:
        """The objective of the frame before the last, as a fraction of uncorrected, read without
        waiting for the GPU (each frame's sums are copied into a two-slot ring on the GPU; this
        reads the slot the last frame did not write): what a live panel shows, one frame late.
        ``None`` before the second frame of ``size``, for a perfect target, or without a per-frame
        guard (``filter="separable"``, ``blend="fixed"``, the identity)."""
        return self.strategy.objective_fraction(tuple(size), previous=True)

    def last_blend(self, size: tuple[int, int]) -> float | None:
        """The blend weight of the last frame of ``size`` (per-frame guards; reads it back: a sync)."""
        return self.strategy.blend_weight(tuple(size))

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

    def apply(self, src_texture: "moderngl.Texture", dst_framebuffer: "moderngl.Framebuffer",
              viewport: tuple[int, int, int, int] | None = None,
              motion_px: tuple[float, float] | None = None) -> None:
        """Correct ``src_texture`` (RGBA8 sRGB code values, or float linear light) into
        ``dst_framebuffer`` (sRGB-encoded), in ``viewport`` (GL x, y, width, height) or all of it.

        ``motion_px``: with an iterative method, the content's displacement since the previous
        frame, ``(dx, dy)`` in image pixels (x to the right, y down; ``new(p) ~ previous(p - d)``),
        rounded to whole pixels: the warm start is the previous solution reprojected by it.
        ``None`` or ``(0, 0)``: the plain warm start.  Other methods ignore it.  On a scene cut call
        :meth:`reset` instead."""
        t0 = time.perf_counter()
        self.gpu.longest = (0.0, "")
        if self.budget is not None:
            self._budget_frame()
        self._set_motion(motion_px)
        linear = self._decode_and_follow(src_texture)
        if self.enabled:
            shown = self._correct(linear)
            if self._timer is not None and self.strategy.last_cold:        # its cold work: off the budget's line
                self._timer.retag(replace(self._timer.tag, cold=True))
            self.gpu.begin("present")
            self.strategy.present(shown, dst_framebuffer, viewport)
        else:
            self.gpu.begin("present")
            self.encoder.present(linear, dst_framebuffer, viewport)
        self.gpu.end()
        if self._timer is not None:
            self._timer.end()
        self.timings_ms = {"correct": 1e3 * (time.perf_counter() - t0)}

    def _budget_frame(self) -> None:
        """The budget's choice for this frame (the frame two before, timed, feeds it first)."""
        budget, timer = self.budget, self._timer
        done = timer.take()
        if done is not None:
            budget.observe(*done)
        choice = budget.choose()
        if choice.fovea_deg != self.options.fovea_deg:       # a move of the radius: a new window, cold
            self.options = replace(self.options, fovea_deg=choice.fovea_deg)
            self.install(self.model)
            log.info("%s eye: the budget moved the fovea to %.3g deg", self.eye_name, choice.fovea_deg)
        if choice.iterations != self.options.iterations_per_frame:
            self.iterations_per_frame = choice.iterations
        timer.begin(choice)

    def simulate(self, src_texture: "moderngl.Texture", dst_framebuffer: "moderngl.Framebuffer",
                 viewport: tuple[int, int, int, int] | None = None, corrected: bool = True,
                 motion_px: tuple[float, float] | None = None) -> None:
        """What this eye sees of ``src_texture`` as displayed (after the correction when
        ``corrected`` and the correction is enabled), sRGB-encoded into ``dst_framebuffer``;
        ``motion_px`` as for :meth:`apply`."""
        t0 = time.perf_counter()
        self._set_motion(motion_px)
        linear = self._decode_and_follow(src_texture)
        shown = self.strategy.shown_texture(self._correct(linear)) if corrected and self.enabled else linear
        self.gpu.begin("simulate")
        size = tuple(linear.size)
        seen = self._seen.get(size)
        if seen is None:
            seen = self._seen[size] = float_texture(self.ctx, size)
        self.preview.run(shown, seen)
        self.gpu.begin("present")
        self.encoder.present(seen, dst_framebuffer, viewport)
        self.gpu.end()
        self.timings_ms = {"simulate": 1e3 * (time.perf_counter() - t0)}

    def describe(self) -> dict[str, Any]:
        """What was built: prescription, regulariser, blend, strategy and its cost figures."""
        m = self.model
        info = {"eye": self.eye_name, "sphere_D": m.eye.sphere_D, "cylinder_D": m.eye.cylinder_D,
                "axis_deg": m.eye.axis_deg, "accommodation_D": m.eye.accommodation_D,
                "accommodative_lag_D": m.eye.accommodative_lag_D, "pupil_mm": m.pupil_mm, "pupil": self.options.pupil,
                "pupil_status": self.pupil_status, "robust": self.options.robust, "band": m.band,
                "band_option": self.options.band, "display": self.display.name,
                "backend": self.backend,
                "filter": self.options.filter, "strategy": self.strategy.name, "kernel_size": m.kernel.size,
                "mu_rel": m.mu_rel, "beta": m.beta, "identity": m.identity, "margin": m.margin,
                "build_seconds": m.build_seconds, "notes": list(m.notes)}
        info.update(self.strategy.describe())
        if self.budget is not None:
            info["budget"] = self.budget.describe()
        if m.simulation is not None:
            info.update(simulation_size=m.simulation.size, simulation_ranks=list(m.simulation.ranks))
        return info

    def release(self) -> None:
        if self._timer is not None:
            self._timer.release()
            self._timer = None
        if self._pupil is not None:
            self._pupil.release()
        release(self.strategy, self.preview, self.encoder, self.decoder, *self._seen.values())
        self._seen.clear()
        if self._owns_source:
            self.source.close()
        if self._onnx is not None:
            self._onnx.release()


def runs_iterations(corrector: Corrector) -> bool:
    """True if ``corrector`` runs iterations spread over frames (GLSL, ``filter`` ``"admm"`` or
    ``"fista"``)."""
    return corrector.backend == Backend.GLSL and corrector.options.filter in ITERATIVE_FILTERS
