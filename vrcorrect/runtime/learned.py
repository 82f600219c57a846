"""The learned correction on the real-time path: an exported model with onnxruntime (no torch).

Why a second kind of ONNX model beside :mod:`vrcorrect.runtime.onnx_backend`'s one-input
contract: one learned model serves every eye in its training range, so the eye is an input,
not a constant.  The exported graph (:mod:`vrcorrect.learn.export`) has three inputs -
``image`` and ``precorrected`` float32 ``(N, 3, H, W)``, ``eye`` float32 ``(N, 4)``; a fourth,
``gradient`` ``(N, 3, H, W)``, for models trained with it - and one output ``displayed`` of
the image's shape; its metadata (``vrcorrect.format`` = ``vrcorrect-learned-v1``) carries the
training ranges, the display, the reference and the pre-correction's settings.  Baking one eye into the graph instead would need a per-user
export (kernel build, filter design and an export with torch on the user's machine) and an
in-graph mirrored convolution as wide as the eye's inverse filter; feeding the eye keeps
one shipped file and lets a prescription change take effect at the next frame.

This module is that contract's runtime side, backwards compatible with the slot:

* :func:`is_learned_model` tells the two kinds apart from the file's metadata (a one-input
  model is the slot's old contract, used as before);
* :class:`LearnedModel` loads a learned model, checks its inputs and metadata;
  :meth:`LearnedModel.for_eye` refuses an eye outside the trained range or a display other
  than the trained one (naming the range and suggesting ``wiener`` or ``fast``) and returns a
  :class:`LearnedEye`, whose :meth:`LearnedEye.infer` has the slot's signature: a
  ``(3, H, W)`` linear RGB image in, the displayed ``(3, H, W)`` out.  The pre-correction
  channels are computed here with numpy (projected-gradient steps by FFT, or for models
  trained with ``precorrection_steps = 0`` the ``wiener`` method's filters).

The Corrector's ``onnx`` backend binds such a model to its eye (:meth:`LearnedModel.for_eye`,
again at every prescription change) and runs :meth:`LearnedEye.run` in the slot.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ..learn.conditioning import SamplingRanges, check_eye, eye_features, kernel_distance_m, model_inputs
from ..physics.kernel import EyeKernel, build_kernel, build_reference_kernel
from ..plumbing.errors import InputError, ValidationError
from ..solvers.fista import GradientPlan, gradient_plan
from ..specs.display import DisplayProfile
from ..specs.prescription import EyeRx
from .model_path import DEFAULT_MODEL, model_for_backend  # noqa: F401  (re-exported)
from .onnx_backend import run_slot

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl
    import onnxruntime

LEARNED_FORMAT = "vrcorrect-learned-v1"
INPUTS = ("image", "precorrected", "eye")
#: The optional fourth input (models trained with ``gradient_input``).
GRADIENT_INPUT = "gradient"


#: onnxruntime's execution providers on a GPU, in the order a session prefers them (the CPU's after them).
GPU_PROVIDERS = ("CUDAExecutionProvider", "ROCMExecutionProvider", "DmlExecutionProvider")


def gpu_provider(available: Sequence[str] | None = None) -> str | None:
    """The first of :data:`GPU_PROVIDERS` that onnxruntime offers on this machine (``available``: its
    ``get_available_providers()``, asked when not given); ``None`` where it offers none or is not installed."""
    if available is None:
        try:
            import onnxruntime as ort  # optional dependency (the realtime extra)
        except ImportError:
            return None
        available = ort.get_available_providers()
    return next((p for p in GPU_PROVIDERS if p in available), None)


def _session(path: Path, providers: tuple[str, ...] | None) -> "onnxruntime.InferenceSession":
    try:
        import onnxruntime as ort  # optional dependency (the realtime extra): needed only to load a model
    except ImportError as exc:  # pragma: no cover - the realtime extra is installed in CI
        raise InputError(f"onnxruntime is not installed ({exc}); pip install -e '.[realtime]'") from None
    if not path.is_file():
        raise InputError(f"{path}: no such ONNX model file")
    available = ort.get_available_providers()
    chosen = [x for x in (providers or GPU_PROVIDERS + ("CPUExecutionProvider",)) if x in available]
    try:
        return ort.InferenceSession(str(path), providers=chosen or ["CPUExecutionProvider"])
    except Exception as exc:                              # onnxruntime raises its own exception types
        raise InputError(f"{path}: not a loadable ONNX model ({type(exc).__name__}: {exc})") from None


def checked_session(path: Path, providers: tuple[str, ...] | None, fmt: str | tuple[str, ...], made_by: str
                    ) -> tuple["onnxruntime.InferenceSession", dict[str, str]]:
    """An onnxruntime session on ``path`` and its ``vrcorrect.*`` metadata, refused unless the
    metadata says ``vrcorrect.format = fmt`` (or one of ``fmt``'s formats; ``made_by``: what writes
    that format, for the error)."""
    session = _session(path, providers)
    meta = dict(session.get_modelmeta().custom_metadata_map)
    formats = (fmt,) if isinstance(fmt, str) else fmt
    if meta.get("vrcorrect.format") not in formats:
        raise ValidationError("model", str(path), f"an ONNX model exported by {made_by} (metadata vrcorrect.format "
                              f"= {' or '.join(formats)})")
    return session, meta


def model_metadata(path: str | Path) -> dict[str, str]:
    """The ``metadata_props`` of an ONNX file (``InputError`` if it cannot be loaded)."""
    return dict(_session(Path(path), ("CPUExecutionProvider",)).get_modelmeta().custom_metadata_map)


def is_learned_model(path: str | Path) -> bool:
    """True for a model exported by :mod:`vrcorrect.learn.export` (eye-conditioned, its format in the metadata)."""
    return model_metadata(path).get("vrcorrect.format") == LEARNED_FORMAT


class LearnedModel:
    """A learned-correction ONNX model and what its metadata says about it."""

    takes_cap = False
    """This format has no input for a robust design's light cap (the unrolled model's has)."""

    def __init__(self, path: str | Path, providers: tuple[str, ...] | None = None):
        self.path = Path(path)
        self.session, meta = checked_session(self.path, providers, LEARNED_FORMAT, "tools/export_onnx.py")
        inputs = {i.name: i for i in self.session.get_inputs()}
        if set(inputs) - {GRADIENT_INPUT} != set(INPUTS) or len(self.session.get_outputs()) != 1:
            raise ValidationError("model inputs", sorted(inputs), "image, precorrected, eye (and optionally "
                                  "gradient), one output")
        self.gradient_input = GRADIENT_INPUT in inputs
        try:
            self.ranges = SamplingRanges.from_dict(json.loads(meta["vrcorrect.ranges"]))
            self.display: dict[str, Any] = json.loads(meta["vrcorrect.display"])
            self.mu_rel = float(meta["vrcorrect.precorrection_mu_rel"])
            self.precorrection_steps = int(meta.get("vrcorrect.precorrection_steps", "0"))
            self.reference = meta.get("vrcorrect.reference", "glasses")
        except (KeyError, ValueError) as exc:
            raise InputError(f"{self.path}: incomplete vrcorrect metadata ({exc})") from None
        self.metadata = meta
        self.providers = self.session.get_providers()

    def check(self, eye: EyeRx, display: DisplayProfile, distance_m: float | None = None) -> EyeRx:
        """Refuse, before any kernel is built, an eye outside the trained range or a display other
        than the trained one (one line naming the range and suggesting ``wiener`` or ``fast``);
        returns the eye as checked, one that can focus as one that cannot and sees the display (at
        ``distance_m``, else its own distance) alike."""
        e = check_eye(eye, self.ranges, f"the model {self.path.name}",
                      display.distance_m if distance_m is None else distance_m)
        if display.name != self.display.get("name"):
            raise ValidationError("display", display.name, f"{self.display.get('name')} (the display the model "
                                  f"{self.path.name} was trained for); for other displays use --method wiener or fast")
        return e

    def for_eye(self, eye: EyeRx, display: DisplayProfile, kernel: EyeKernel | None = None,
                reference_kernel: EyeKernel | None = None, capped: bool = False) -> "LearnedEye":
        """The model bound to one eye on ``display`` (kernels built here unless given).  ``capped``
        is accepted as :meth:`UnrolledModel.for_eye <vrcorrect.runtime.unrolled.UnrolledModel.for_eye>`
        takes it and has no effect (:attr:`takes_cap` is False): this model's output is in [0, 1].

        Raises
        ------
        ValidationError
            The eye is outside the trained range, or the display is not the trained one.
        """
        e = self.check(eye, display, None if kernel is None else kernel_distance_m(kernel))
        kernel = kernel if kernel is not None else build_kernel(e, display)
        if reference_kernel is None and self.reference == "glasses":
            reference_kernel = build_reference_kernel(e, display)
        return LearnedEye(self, e, kernel, reference_kernel)


class LearnedEye:
    """One eye's learned correction: ``infer(image_chw) -> displayed_chw`` (the slot's signature)."""

    def __init__(self, model: LearnedModel, eye: EyeRx, kernel: EyeKernel, reference_kernel: EyeKernel | None):
        self.model, self.eye, self.kernel, self.reference_kernel = model, eye, kernel, reference_kernel
        self.capped = False
        """This format never holds a light cap (:attr:`LearnedModel.takes_cap`)."""
        self.features = eye_features(eye, model.ranges)[None]
        self._buffers: dict[tuple[int, int], np.ndarray] = {}
        self._plans: dict[tuple[int, int], GradientPlan] = {}

    def precorrected(self, image_chw: np.ndarray) -> np.ndarray:
        """The pre-correction channels ``(3, H, W)`` the model is fed with."""
        return self.inputs(image_chw)[0]

    def inputs(self, image_chw: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The pre-correction channels ``(3, H, W)`` and, for a model that takes it, the gradient
        step there (``(3, H, W)``, else ``None``).

        The kernel's spectrum for the projected-gradient steps is computed at the first frame
        of each size and kept (the last two sizes: a mirror and a headset eye, say).
        """
        hwc = np.moveaxis(np.asarray(image_chw, np.float32), 0, 2)
        plan = None
        grad = self.model.gradient_input
        if grad or (self.model.precorrection_steps > 0 and self.kernel.size > 1):
            size = hwc.shape[:2]
            plan = self._plans.get(size)
            if plan is None:
                plan = gradient_plan(self.kernel, size)
                while len(self._plans) >= 2:
                    self._plans.pop(next(iter(self._plans)))
                self._plans[size] = plan
        pre, g = model_inputs(hwc, self.kernel, self.reference_kernel, self.model.mu_rel,
                              self.model.precorrection_steps, grad, plan)

        def chw(a: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(np.moveaxis(a, 2, 0))

        return chw(pre), None if g is None else chw(g)

    def infer(self, image_chw: np.ndarray) -> np.ndarray:
        """Run on a ``(3, H, W)`` float32 linear RGB image; returns ``(3, H, W)`` float32 in [0, 1]."""
        x = np.ascontiguousarray(image_chw, dtype=np.float32)
        if x.ndim != 3 or x.shape[0] != 3:
            raise ValidationError("image", f"shape {x.shape}", "(3, H, W)")
        pre, g = self.inputs(x)
        feeds = {"image": x[None], "precorrected": pre[None], "eye": self.features}
        if g is not None:
            feeds[GRADIENT_INPUT] = g[None]
        out = self.model.session.run(None, feeds)[0]
        return np.clip(out[0], 0.0, 1.0).astype(np.float32, copy=False)

    def run(self, src_texture: "moderngl.Texture", dst_texture: "moderngl.Texture") -> None:
        """The ONNX slot's frame (rgba32f textures, GL orientation): see :func:`run_slot`."""
        run_slot(self.infer, self._buffers, src_texture, dst_texture)

    def release(self) -> None:
        self._buffers.clear()
        self._plans.clear()
