"""``backend="onnx"``: a model corrects each frame through onnxruntime (read the linear image back,
run, upload the result): a plain model of the slot's contract (:class:`~vrcorrect.runtime.
onnx_backend.OnnxModel`) or the learned model bound to this eye (:class:`~vrcorrect.runtime.
learned.LearnedEye`).  The read-back and the upload are counted as transfers.

Layer 5: numpy, moderngl, onnxruntime; never torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Union

from ...specs.vocabulary import Backend
from ..dispatch import resource_bytes
from ..gl import release
from ..onnx_backend import OnnxModel
from .base import Size, Strategy, float_texture

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ..learned import LearnedEye

__all__ = ["OnnxStrategy"]

Slot = Union[OnnxModel, "LearnedEye"]


class OnnxStrategy(Strategy):
    name = Backend.ONNX

    def __init__(self, *args: Any, slot: Slot, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.slot = slot
        self._out: dict[Size, "moderngl.Texture"] = {}

    def correct(self, linear: "moderngl.Texture", motion_gl: tuple[int, int]) -> "moderngl.Texture":
        size = tuple(linear.size)
        out = self._out.get(size)
        if out is None:
            out = self._out[size] = float_texture(self.ctx, size)
        self.slot.run(linear, out)
        self.gpu.transfer("onnx read-back and upload", read=resource_bytes(linear), written=resource_bytes(out))
        return out

    def release(self) -> None:
        self.slot.release()
        release(*self._out.values())
        self._out.clear()
        super().release()
