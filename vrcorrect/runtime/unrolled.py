"""The unrolled correction on onnxruntime (no torch): a model exported by
:mod:`vrcorrect.learn.unrolled_export` applied to one eye's image.

What the model needs besides the image is computed here with numpy, once per eye and size: the
target's cone image through the eye with glasses (:func:`vrcorrect.vision.forward.simulate_lms`),
the kernel's spectrum and its Gram matrix ``K^H K`` (what the data steps solve with)
(:func:`vrcorrect.learn.conditioning.unrolled_spectra`, float64 then float32) and the eye's
features (:func:`~vrcorrect.learn.conditioning.unrolled_features`), and where the stages start:
``fast``'s own start (:func:`vrcorrect.solvers.admm.fast_start`: a half-resolution level of ADMM
and its duals, where that level pays). The model returns the displayed image, linear RGB in [0, 1].

``vrcorrect correct --method learned --model FILE`` takes such a file as well as the older
learned models (:meth:`UnrolledModel.for_eye` has :class:`~vrcorrect.runtime.learned.LearnedModel`'s
shape). The real-time path uses it as the cold start of its iterations
(``CorrectorOptions.cold_start_model``, ``--cold-start``: :meth:`UnrolledEye.run` on textures) and
``vrcorrect bench unrolled`` measures it (:mod:`vrcorrect.studies.bench.unrolled`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..learn.conditioning import (
    UNROLLED_FORMAT,
    UNROLLED_FORMATS,
    UNROLLED_INPUTS,
    UNROLLED_INPUTS_V3,
    SamplingRanges,
    check_eye,
    kernel_distance_m,
    unrolled_features,
    unrolled_spectra,
)
from ..physics.kernel import EyeKernel
from ..plumbing.errors import InputError, ValidationError
from ..solvers.admm import fast_start
from ..solvers.problem import light_cap
from ..specs.display import DisplayProfile
from ..specs.prescription import EyeRx
from ..vision.forward import simulate_lms
from .learned import checked_session, model_metadata
from .onnx_backend import run_slot

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["UNROLLED_FORMAT", "UNROLLED_FORMATS", "is_unrolled_model", "UnrolledModel", "UnrolledEye"]



def is_unrolled_model(path: str | Path) -> bool:
    """True for a model exported by :mod:`vrcorrect.learn.unrolled_export`, of any format this
    module runs (:data:`UNROLLED_FORMATS`; ``InputError`` if the file cannot be loaded)."""
    return model_metadata(path).get("vrcorrect.format") in UNROLLED_FORMATS


class UnrolledModel:
    """An exported unrolled model and what its metadata says (stages, ranges, displays)."""

    def __init__(self, path: str | Path, providers: tuple[str, ...] | None = None):
        self.path = Path(path)
        self.session, meta = checked_session(self.path, providers, UNROLLED_FORMATS,
                                             "vrcorrect.learn.unrolled_export")
        names = tuple(i.name for i in self.session.get_inputs())
        expected = UNROLLED_INPUTS if meta["vrcorrect.format"] == UNROLLED_FORMAT else UNROLLED_INPUTS_V3
        if names != expected:
            raise ValidationError("model inputs", list(names), ", ".join(expected))
        self.takes_cap = "upper" in names
        """Whether the model holds a robust design's light cap at its stages (format v4)."""
        try:
            self.config: dict[str, Any] = json.loads(meta["vrcorrect.config"])
            ranges = json.loads(meta.get("vrcorrect.ranges") or "null")
            self.displays: list[str] | None = json.loads(meta.get("vrcorrect.displays") or "null")
        except (KeyError, ValueError) as exc:
            raise InputError(f"{self.path}: incomplete vrcorrect metadata ({exc})") from None
        self.ranges = SamplingRanges.from_dict(ranges) if ranges else SamplingRanges()
        self.metadata = meta
        self.reference = "glasses"                     # the target it was trained on: the eye with glasses
        self.providers = self.session.get_providers()

    def check(self, eye: EyeRx, display: DisplayProfile, distance_m: float | None = None) -> EyeRx:
        """Refuse, before any kernel is built, an eye outside the trained ranges or a display the
        model was not trained on; returns the eye as checked: an eye that can focus as one that
        cannot and sees the display (at ``distance_m``, else the display's own distance) alike
        (:func:`~vrcorrect.learn.conditioning.without_accommodation`)."""
        e = check_eye(eye, self.ranges, f"the model {self.path.name}",
                      display.distance_m if distance_m is None else distance_m)
        if self.displays is not None and display.name not in self.displays:
            raise ValidationError("display", display.name, f"one of {', '.join(self.displays)} (the displays the model "
                                  f"{self.path.name} was trained for); for others use --method wiener or fast")
        return e

    def for_eye(self, eye: EyeRx, display: DisplayProfile, kernel: EyeKernel,
                reference_kernel: EyeKernel | None, capped: bool = False) -> "UnrolledEye":
        """The model bound to one eye (``solve(problem, "learned", model=...)``'s ``BoundModel``);
        ``capped``: hold a robust design's light cap (:func:`~vrcorrect.solvers.problem.light_cap`)
        at every stage, where the model can (:attr:`takes_cap`; a v3 model runs uncapped)."""
        if reference_kernel is None:
            raise ValidationError("reference", "ideal", "glasses (the target the model was trained on)")
        return UnrolledEye(self, self.check(eye, display, kernel_distance_m(kernel)), kernel, reference_kernel, capped)

    def correct(self, image: np.ndarray, eye: EyeRx, kernel: EyeKernel, reference_kernel: EyeKernel,
                capped: bool = False) -> np.ndarray:
        """The displayed image ``(H, W, 3)`` float32 in [0, 1] for ``image`` (linear display RGB
        ``(H, W, 3)``) seen by ``eye`` through ``kernel`` (``reference_kernel``: the same eye with
        glasses, which sets the target; ``capped``: as :meth:`for_eye`). An eye outside the trained
        ranges is refused."""
        e = check_eye(eye, self.ranges, f"the model {self.path.name}", kernel_distance_m(kernel))
        img = _checked_image(image)
        return self._run(img, unrolled_features(e, kernel.size, self.ranges), unrolled_spectra(kernel.kernel, img.shape[:2]),
                         kernel, reference_kernel, capped and self.takes_cap)

    def _run(self, img: np.ndarray, features: np.ndarray, spectra: tuple[np.ndarray, np.ndarray, float],
             kernel: EyeKernel, reference_kernel: EyeKernel, capped: bool = False) -> np.ndarray:
        """The pass on a checked ``(H, W, 3)`` image, given the eye's features and the kernel's
        spectra on its grid (what depends on the eye and the size, not on the picture); ``capped`` only
        where the model :attr:`takes_cap` (the callers see to it)."""
        t_lms, _ = simulate_lms(img, reference_kernel)
        spectrum, gram, norm2 = spectra
        chw = np.ascontiguousarray(img.transpose(2, 0, 1))
        lms = np.ascontiguousarray(t_lms.transpose(2, 0, 1), np.float32)
        z0, d1, d2 = fast_start(kernel.kernel, chw, lms, capped=capped)
        feed = {"target_lms": lms[None], "z0": z0[None], "spectrum": spectrum[None], "gram": gram[None],
                "norm2": np.array([norm2], np.float32), "features": features[None],
                "target": chw[None], "d1": d1[None], "d2": d2[None]}
        if self.takes_cap:
            feed["upper"] = (light_cap(chw) if capped else np.ones_like(chw))[None]
        out = self.session.run(None, feed)[0][0]
        return np.ascontiguousarray(out.transpose(1, 2, 0), np.float32)


def _checked_image(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image, np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValidationError("image.shape", img.shape, "(height, width, 3)")
    return img


class UnrolledEye:
    """An :class:`UnrolledModel` bound to one eye and its kernels: :meth:`infer` maps a ``(3, H, W)``
    linear target to the displayed ``(3, H, W)``."""

    def __init__(self, model: UnrolledModel, eye: EyeRx, kernel: EyeKernel, reference_kernel: EyeKernel,
                 capped: bool = False):
        self.model, self.eye, self.kernel, self.reference_kernel = model, eye, kernel, reference_kernel
        self.capped = bool(capped) and model.takes_cap
        """Whether the light cap holds (asked for, and the model can)."""
        self._buffers: dict[tuple[int, int], np.ndarray] = {}
        # the eye is checked once (UnrolledModel.for_eye); its features once; the spectra once per size
        self._features = unrolled_features(eye, kernel.size, model.ranges)
        self._spectra: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, float]] = {}

    def infer(self, image_chw: np.ndarray) -> np.ndarray:
        img = _checked_image(np.moveaxis(np.asarray(image_chw, np.float32), 0, 2))
        size = img.shape[:2]
        if size not in self._spectra:
            self._spectra[size] = unrolled_spectra(self.kernel.kernel, size)
        out = self.model._run(img, self._features, self._spectra[size], self.kernel, self.reference_kernel, self.capped)
        return np.ascontiguousarray(np.moveaxis(out, 2, 0))

    def run(self, src_texture: "moderngl.Texture", dst_texture: "moderngl.Texture") -> None:
        """The pass on rgba32f textures in GL orientation (:func:`~vrcorrect.runtime.onnx_backend.run_slot`):
        the real-time path's learned cold start (:meth:`~vrcorrect.runtime.strategies.admm.AdmmStrategy.use_first_guess`)."""
        run_slot(self.infer, self._buffers, src_texture, dst_texture)

    def release(self) -> None:
        self._buffers.clear()
        self._spectra.clear()

