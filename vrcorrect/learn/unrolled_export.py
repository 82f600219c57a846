"""Export a trained unrolled model (:mod:`vrcorrect.learn.unrolled`) to ONNX for onnxruntime
(torch, onnx, onnxscript: torch's dynamo exporter, which writes the FFTs as ONNX ``DFT`` ops).

The graph: inputs ``target_lms``, ``z0``, ``target`` and the start's duals ``d1``, ``d2``
(:func:`vrcorrect.solvers.admm.fast_start`) and ``upper``, the box's top per pixel (ones, or a
robust design's light cap, :func:`vrcorrect.solvers.problem.light_cap`) float32 ``(1, 3, H, W)``; ``spectrum`` and
``gram`` (``K^H K``) float32 ``(1, 3, 3, P0, P1 // 2 + 1, 2)``; ``norm2`` ``(1,)``; ``features`` ``(1, 5)``
(:func:`vrcorrect.learn.conditioning.unrolled_features`). Output ``displayed`` ``(1, 3, H, W)`` in
[0, 1]. ``H``, ``W``, ``P0`` and ``P1`` are dynamic: one file serves every image size and kernel.
Metadata (``vrcorrect.*``): the format, the stages, the training ranges and displays, the
training report's held-out figures.

Every export is checked: onnxruntime's output must equal torch's within :data:`TOLERANCE` on a
random case of odd size, other than the traced one, or nothing is written.
"""

from __future__ import annotations

import io
import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import check_writable
from .conditioning import N_UNROLLED_FEATURES, UNROLLED_FORMAT, UNROLLED_INPUTS
from .export import stamp_and_write
from .unrolled import UnrolledADMM, UnrolledConfig, kernel_spectra
from .unrolled_train import load_unrolled

FORMAT = UNROLLED_FORMAT               # the format and its inputs: one contract with the runtime (conditioning)
OPSET = 18
TOLERANCE = 1e-4
INPUTS = UNROLLED_INPUTS
OUTPUT = "displayed"


@dataclass(frozen=True)
class UnrolledExport:
    path: Path
    max_abs_error: float
    metadata: dict[str, str]
    bytes: int


def _case(H: int, W: int, kernel_size: int, seed: int) -> tuple[torch.Tensor, ...]:
    rng = np.random.default_rng(seed)
    k = rng.random((3, 3, kernel_size, kernel_size))
    k /= 3 * k.sum(axis=(-2, -1), keepdims=True)
    spectrum, gram, norm2 = kernel_spectra([k], (H, W))
    t = torch.from_numpy(rng.random((1, 3, H, W), dtype=np.float32))
    z0 = torch.from_numpy(rng.random((1, 3, H, W), dtype=np.float32))
    d1, d2 = (torch.from_numpy(rng.normal(0, 0.05, (1, 3, H, W)).astype(np.float32)) for _ in range(2))
    upper = torch.from_numpy(rng.uniform(0.2, 1.0, (1, 3, H, W)).astype(np.float32))
    return (torch.from_numpy(rng.random((1, 3, H, W), dtype=np.float32)), z0, spectrum, gram, norm2,
            torch.from_numpy(rng.uniform(-1, 1, (1, N_UNROLLED_FEATURES)).astype(np.float32)), t, d1, d2, upper)


def onnx_bytes(model: UnrolledADMM) -> bytes:
    """The model as ONNX (dynamic image and grid sizes; no metadata)."""
    from torch.export import Dim  # on use: torch (the learn extra; heavy)

    h, w = Dim("H", min=8, max=8192), Dim("W", min=8, max=8192)
    p0, f1 = Dim("P0", min=8, max=16384), Dim("F1", min=5, max=8193)
    image, spec = {2: h, 3: w}, {3: p0, 4: f1}
    shapes = {"t_lms": image, "z0": image, "spectrum": spec, "gram": spec, "norm2": None, "features": None,
              "target": image, "d1": image, "d2": image, "upper": image}
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(model.eval(), _case(40, 52, 7, 0), buf, dynamo=True, opset_version=OPSET,
                          dynamic_shapes=shapes, input_names=list(INPUTS), output_names=[OUTPUT], verbose=False)
    return buf.getvalue()


def check_against_torch(model: UnrolledADMM, data: bytes, size: tuple[int, int] = (37, 61), kernel_size: int = 9
                        ) -> float:
    """Largest absolute difference between onnxruntime on ``data`` and torch on a random case of
    ``size`` (not the traced one).  The case is fed by the file's own input names, in order, so a file
    of an older format (without the last inputs: v3 has no ``upper``) is checked as it is run."""
    import onnxruntime as ort  # optional: the learn and realtime extras

    session = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    args = _case(*size, kernel_size, seed=1)[:len(names)]
    out = session.run(None, {name: a.numpy() for name, a in zip(names, args)})[0]
    with torch.no_grad():
        ref = model.eval()(*args).numpy()
    return float(np.max(np.abs(out - ref)))


def export_unrolled(checkpoint: str | Path, out: str | Path, force: bool = False) -> UnrolledExport:
    """Export ``checkpoint`` (``unrolled.pt``, with ``report.json`` beside it when there is one) to
    ``out``, checked against torch; nothing is written when the check fails."""
    import onnx  # optional: the learn extra

    out = Path(out)
    if out.suffix.lower() != ".onnx":
        raise ValidationError("output", str(out), "a path ending in .onnx")
    check_writable(out, force=force)
    model = load_unrolled(checkpoint)
    data = onnx_bytes(model)
    error = check_against_torch(model, data)
    if not error <= TOLERANCE:
        raise InputError(f"{checkpoint}: onnxruntime differs from torch by {error:.3g} (> {TOLERANCE:g}); not written")
    report_path = Path(checkpoint).with_name("report.json")
    report = json.loads(report_path.read_text()) if report_path.is_file() else {}
    meta = {"vrcorrect.format": FORMAT, "vrcorrect.version": __version__,
            "vrcorrect.config": json.dumps(model.config.as_dict()),
            "vrcorrect.inputs": ",".join(INPUTS), "vrcorrect.opset": str(OPSET),
            "vrcorrect.ranges": json.dumps(report.get("config", {}).get("ranges")),
            "vrcorrect.displays": json.dumps(report.get("config", {}).get("displays")),
            "vrcorrect.train": json.dumps({k: report.get(k) for k in ("config", "image_px", "images", "machine",
                                                                       "steps", "seconds", "parameters",
                                                                       "share_of_fast_gain", "held_out")})}
    blob = stamp_and_write(onnx.load_from_string(data), meta, out, force, "vrcorrect unrolled correction: inputs "
                           + ", ".join(INPUTS) + "; output displayed (1,3,H,W). See vrcorrect.runtime.unrolled.")
    return UnrolledExport(path=out, max_abs_error=error, metadata=meta, bytes=len(blob))


def model_from_onnx(path: str | Path) -> tuple[UnrolledADMM, dict[str, str]]:
    """The torch model an exported file holds (its learned settings read back from the graph's
    initializers, by name) and the file's ``vrcorrect.*`` metadata: what re-exports a model of an
    older format with the same weights (tools/reexport_unrolled.py).  Checked against the file on a
    random case, as an export is; a weight not found by its name is refused, naming it."""
    import onnx  # optional: the learn extra
    from onnx import numpy_helper  # optional: the learn extra

    proto = onnx.load(str(path))
    meta = {p.key: p.value for p in proto.metadata_props}
    if not meta.get("vrcorrect.format", "").startswith("vrcorrect-unrolled-"):
        raise ValidationError("model", str(path), "an ONNX model exported by vrcorrect.learn.unrolled_export")
    model = UnrolledADMM(UnrolledConfig(**json.loads(meta["vrcorrect.config"])))
    found = {i.name: numpy_helper.to_array(i) for i in proto.graph.initializer}
    state = {}
    for name, value in model.state_dict().items():
        # the shared stage settings are exported expanded to the batch: (1, stages, 3)
        array = found["expand"][0] if name == "stage_base" and name not in found else found.get(name)
        if array is None or array.shape != tuple(value.shape):
            raise ValidationError("model", str(path), f"an initializer {name} of shape {tuple(value.shape)}")
        state[name] = torch.from_numpy(np.array(array, np.float32))
    model.load_state_dict(state)
    error = check_against_torch(model, proto.SerializeToString())
    if not error <= TOLERANCE:
        raise InputError(f"{path}: the weights read back differ from the file by {error:.3g} (> {TOLERANCE:g})")
    return model, meta
