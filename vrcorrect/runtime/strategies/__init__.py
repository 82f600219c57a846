"""The real-time correction strategies: one class per method, each owning its GPU programs and its
per-size buffers, each running its passes through :class:`~vrcorrect.runtime.dispatch.Gpu` (so a
frame's cost is counted from its dispatches).

* :mod:`.admm` - ``"admm"`` (the default): ADMM iterations spread over frames.
* :mod:`.foveated` - ``"admm"`` with ``fovea_deg``: the same on a window around the gaze.
* :mod:`.fista` - ``"fista"``: projected-gradient (FISTA) iterations spread over frames.
* :mod:`.onepass` - ``"fft"`` and ``"separable"``: the regularised inverse in one pass.
* :mod:`.onnx` - ``backend="onnx"``: a model through onnxruntime.
* :mod:`.preview` - the forward model, for :meth:`~vrcorrect.runtime.corrector.Corrector.simulate`.

:func:`make_strategy` picks one for an eye model and the corrector's options.

Layer 5 (inside the runtime): numpy, moderngl, onnxruntime; never torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ...plumbing.errors import ValidationError
from ...specs.vocabulary import Filter
from .admm import AdmmStrategy
from .base import Decoder, Encoder, FrameBlend, Strategy
from .fista import FistaStrategy
from .foveated import FoveatedStrategy
from .onepass import FftInverse, SeparableInverse
from .onnx import OnnxStrategy
from .preview import Preview

if TYPE_CHECKING:  # pragma: no cover - typing only
    from ..dispatch import Gpu
    from ..eye_model import CorrectorOptions, EyeModel
    from .onnx import Slot

__all__ = ["Strategy", "Encoder", "Decoder", "FrameBlend", "Identity", "Preview", "make_strategy", "STRATEGIES"]


class Identity(Strategy):
    """Nothing to correct (the eye is sharp at this display, or sees as well as with its glasses):
    the target is shown as it is."""

    name = "identity"

    def correct(self, linear: Any, motion_gl: tuple[int, int]) -> Any:
        return linear


STRATEGIES: dict[str, type[Strategy]] = {Filter.ADMM: AdmmStrategy, Filter.FISTA: FistaStrategy,
                                         Filter.FFT: FftInverse, Filter.SEPARABLE: SeparableInverse}
"""The GLSL backend's strategy for each ``method``."""


def make_strategy(gpu: "Gpu", model: "EyeModel", options: "CorrectorOptions", encoder: Encoder, decoder: Decoder,
                  slot: "Slot | None" = None, ppd: float | None = None) -> Strategy:
    """The strategy that corrects ``model``'s eye with ``options`` (``slot``: the ONNX backend's model;
    ``ppd``: the display's pixels per degree, for ``options.fovea_deg``)."""
    if slot is not None:
        return OnnxStrategy(gpu, model, options, encoder, decoder, slot=slot)
    if model.identity:
        return Identity(gpu, model, options, encoder, decoder)
    if options.fovea_deg is not None and options.filter == Filter.ADMM:
        if ppd is None:
            raise ValidationError("ppd", ppd, "the display's pixels per degree (for fovea_deg)")
        from ...solvers.foveated import fovea_pixels  # start-up time: scipy with the first eye

        radius_px, band_px = fovea_pixels(options.fovea_deg, ppd)
        return FoveatedStrategy(gpu, model, options, encoder, decoder, radius_px=radius_px, band_px=band_px,
                                periphery=options.fovea_periphery)
    return STRATEGIES[options.filter](gpu, model, options, encoder, decoder)
