"""The ONNX slot: an eye texture through an ONNX model with onnxruntime (read back, run, upload).

The model contract (what the learned model of the U-Net issue exports):

* one input, float32 ``(1, 3, H, W)`` (or with dynamic ``H``/``W``): linear display RGB in
  [0, 1], rows top first (image orientation);
* one output of the same shape: the linear RGB to display (clipped to [0, 1] here).

The learned model (:mod:`vrcorrect.runtime.learned`: three inputs, the eye among them) goes
through the same slot (:func:`run_slot`) bound to the Corrector's eye.

``OnnxModel.run(src, dst)`` takes and fills rgba32f textures in GL orientation: it
reads ``src`` back, flips it to image orientation, runs the session on the CPU
provider (or CUDA where onnxruntime has it), flips back and writes ``dst``.  The
read-back and upload buffers are allocated once per size.

Layer 5: numpy and onnxruntime only.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..plumbing.errors import InputError, ValidationError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl
    import onnx

__all__ = ["OnnxModel", "run_slot", "small_onnx_model", "write_one_minus_x_model"]


class OnnxModel:
    """An onnxruntime session with the model contract checked at load."""

    def __init__(self, path: str | Path, providers: tuple[str, ...] | None = None):
        try:
            import onnxruntime as ort  # optional dependency (the realtime extra): needed only to load a model
        except ImportError as exc:  # pragma: no cover - the realtime extra is installed in CI
            raise InputError(f"onnxruntime is not installed ({exc}); pip install -e '.[realtime]'") from None
        p = Path(path)
        if not p.is_file():
            raise InputError(f"{p}: no such ONNX model file")
        available = ort.get_available_providers()
        chosen = [x for x in (providers or ("CUDAExecutionProvider", "CPUExecutionProvider")) if x in available]
        try:
            self.session = ort.InferenceSession(str(p), providers=chosen or ["CPUExecutionProvider"])
        except Exception as exc:                          # onnxruntime raises its own exception types
            raise InputError(f"{p}: not a loadable ONNX model ({type(exc).__name__}: {exc})") from None
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if len(inputs) != 1 or len(outputs) != 1:
            raise ValidationError("model", f"{len(inputs)} inputs and {len(outputs)} outputs",
                                  "exactly one input and one output")
        shape = inputs[0].shape
        if len(shape) != 4 or shape[1] != 3 or inputs[0].type != "tensor(float)":
            raise ValidationError("model input", f"{inputs[0].type} {shape}", "float32 of shape (1, 3, H, W)")
        self.path = p
        self.input_name = inputs[0].name
        self.fixed_hw: tuple[int, int] | None = (shape[2], shape[3]) if all(isinstance(d, int) for d in shape[2:]) \
            else None
        self.providers: list[str] = self.session.get_providers()
        self._buffers: dict[tuple[int, int], np.ndarray] = {}

    def infer(self, image_chw: np.ndarray) -> np.ndarray:
        """Run on a ``(3, H, W)`` float32 image; returns ``(3, H, W)`` float32 clipped to [0, 1]."""
        H, W = image_chw.shape[1:]
        if self.fixed_hw is not None and self.fixed_hw != (H, W):
            raise ValidationError("image size", f"{W}x{H}", f"{self.fixed_hw[1]}x{self.fixed_hw[0]} (the model's fixed size)")
        out = self.session.run(None, {self.input_name: image_chw[None]})[0]
        if out.shape != (1, 3, H, W):
            raise ValidationError("model output", f"shape {out.shape}", f"(1, 3, {H}, {W})")
        return np.clip(out[0], 0.0, 1.0).astype(np.float32, copy=False)

    def run(self, src_texture: "moderngl.Texture", dst_texture: "moderngl.Texture") -> None:
        """rgba32f ``src`` -> model -> rgba32f ``dst`` (same size, GL orientation)."""
        run_slot(self.infer, self._buffers, src_texture, dst_texture)

    def release(self) -> None:
        self._buffers.clear()


def run_slot(infer: Callable[[np.ndarray], np.ndarray], buffers: dict[tuple[int, int], np.ndarray],
             src_texture: "moderngl.Texture", dst_texture: "moderngl.Texture") -> None:
    """The slot's frame: read the rgba32f (or rgba16f: the real-time path's half-precision target)
    ``src`` back, flip it to image orientation, ``infer`` ``(3, H, W) -> (3, H, W)``, flip back and
    write the rgba32f ``dst``; one buffer per size in ``buffers``."""
    W, H = src_texture.size
    buf = buffers.get((W, H))
    if buf is None:
        buf = buffers[(W, H)] = np.empty((H, W, 4), np.float32)
    if src_texture.dtype == "f2":
        buf[...] = np.frombuffer(src_texture.read(), np.float16).reshape(H, W, 4)
    elif src_texture.dtype == "f4" and src_texture.components == 4:
        src_texture.read_into(buf)
    else:
        raise ValidationError("texture", f"{src_texture.components} x {src_texture.dtype}", "rgba32f or rgba16f")
    chw = np.ascontiguousarray(buf[::-1, :, :3].transpose(2, 0, 1))            # image orientation
    out = infer(chw)
    buf[..., :3] = out.transpose(1, 2, 0)[::-1]
    buf[..., 3] = 1.0
    dst_texture.write(buf)


def small_onnx_model(graph: "onnx.GraphProto") -> "onnx.ModelProto":
    """A hand-built ``graph`` (``onnx.helper``) as a checked model of opset 17 and IR version 8,
    which onnxruntime 1.17 and later read (needs the ``onnx`` package)."""
    import onnx  # optional dependency (tests and benchmarks only)
    from onnx import helper  # the same optional dependency

    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def write_one_minus_x_model(path: str | Path) -> None:
    """Write a trivial model of the slot's contract, ``y = 1 - x`` on float32 ``(1, 3, H, W)``
    with dynamic ``H`` and ``W`` (needs the ``onnx`` package): to exercise and time the slot
    before a learned model exists."""
    import onnx  # optional dependency (tests and benchmarks only)
    from onnx import TensorProto, helper  # the same optional dependency

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, "H", "W"])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, "H", "W"])
    one = helper.make_tensor("one", TensorProto.FLOAT, [], [1.0])
    graph = helper.make_graph([helper.make_node("Sub", ["one", "x"], ["y"])], "one_minus_x", [x], [y], [one])
    onnx.save(small_onnx_model(graph), str(path))
