"""Export a trained checkpoint to ONNX for onnxruntime (torch, onnx, onnxruntime).

The graph (opset :data:`OPSET`, pinned): inputs ``image`` and ``precorrected`` float32
``(N, 3, H, W)`` (linear display RGB in [0, 1], rows top first; ``precorrected`` from
:func:`vrcorrect.learn.conditioning.precorrect`) and ``eye`` float32 ``(N, 4)``
(:func:`vrcorrect.learn.conditioning.eye_features`); output ``displayed`` float32
``(N, 3, H, W)`` in [0, 1].  ``N``, ``H`` and ``W`` are dynamic.  Metadata (``vrcorrect.*``
keys of the model's ``metadata_props``) carries what the runtime needs to use it safely:
the training ranges, the display, the pre-correction's regulariser, the reference, the
version and the training settings (:data:`METADATA_KEYS`).

Every export is checked: onnxruntime's output must equal torch's within
:data:`FP32_TOLERANCE` on a random input of odd size, or nothing is written.  ``fp16=True``
writes the weights in float16 (each followed by a Cast to float32; activations stay
float32, so it runs on every onnxruntime provider and halves the file) and reports its
measured largest error against the float32 torch model.
"""

from __future__ import annotations

import io
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import __version__
from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import check_writable, write_with
from .model import UNetConfig
from .train import load_checkpoint, model_from_checkpoint

OPSET = 17
FORMAT = "vrcorrect-learned-v1"
OUTPUT_NAME = "displayed"
FP32_TOLERANCE = 1e-4
METADATA_KEYS = ("vrcorrect.format", "vrcorrect.version", "vrcorrect.inputs", "vrcorrect.ranges",
                 "vrcorrect.display", "vrcorrect.reference", "vrcorrect.precorrection_mu_rel",
                 "vrcorrect.precorrection_steps",
                 "vrcorrect.train", "vrcorrect.precision", "vrcorrect.opset")


@dataclass(frozen=True)
class ExportReport:
    """What :func:`export_onnx` wrote and measured."""

    path: Path
    precision: str                 # "fp32" or "fp16-weights"
    max_abs_error_fp32: float      # onnxruntime (fp32 graph) vs torch
    max_abs_error_fp16: float | None
    metadata: dict[str, str]
    bytes: int


def metadata_for(ckpt: dict, precision: str) -> dict[str, str]:
    """The ``vrcorrect.*`` metadata of a checkpoint's export."""
    ds = ckpt["dataset"]
    return {
        "vrcorrect.format": FORMAT,
        "vrcorrect.version": __version__,
        "vrcorrect.inputs": ",".join(UNetConfig.from_dict(ckpt["train_config"]["model"]).input_names),
        "vrcorrect.ranges": json.dumps(ds["config"]["ranges"]),
        "vrcorrect.display": json.dumps(ds["display"]),
        "vrcorrect.reference": ds.get("reference", "glasses"),
        "vrcorrect.precorrection_mu_rel": repr(float(ds["config"]["precorrection_mu_rel"])),
        "vrcorrect.precorrection_steps": str(int(ds["config"].get("precorrection_steps", 0))),
        "vrcorrect.train": json.dumps({"step": ckpt["step"], "config": ckpt["train_config"],
                                       "dataset_samples": ds["samples"], "dataset_seed": ds["config"]["seed"],
                                       "crop_px": ds["config"]["crop_px"],
                                       "crops_per_eye": ds["config"].get("crops_per_eye", 1),
                                       "fast_tolerance": ds["config"].get("fast_tolerance"),
                                       "images": [i["name"] for i in ds.get("images", [])],
                                       "init": ckpt.get("init")}),
        "vrcorrect.precision": precision,
        "vrcorrect.opset": str(OPSET),
    }


def onnx_bytes(model: torch.nn.Module) -> bytes:
    """The model as an ONNX graph (pinned opset, dynamic batch, height and width; no metadata)."""
    H, W = 40, 48
    names = model.input_names
    args = tuple(torch.zeros(1, 4) if n == "eye" else torch.rand(1, 3, H, W) for n in names)
    buf = io.BytesIO()
    axes = {name: {0: "N", 2: "H", 3: "W"} for name in names if name != "eye"}
    axes[OUTPUT_NAME] = {0: "N", 2: "H", 3: "W"}
    axes["eye"] = {0: "N"}

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")            # the TorchScript exporter's deprecation notice
        torch.onnx.export(model, args, buf, dynamo=False, opset_version=OPSET, input_names=list(names),
                          output_names=[OUTPUT_NAME], dynamic_axes=axes, do_constant_folding=True)
    return buf.getvalue()


def fp16_weights(model_proto):
    """A copy with every float32 initializer of 16 or more values stored as float16 and cast back."""
    import onnx  # optional: onnx (the learn extra)
    from onnx import helper, numpy_helper  # optional: onnx (the learn extra)

    m = onnx.ModelProto()
    m.CopyFrom(model_proto)
    g = m.graph
    casts = []
    keep = []
    for init in g.initializer:
        if init.data_type == onnx.TensorProto.FLOAT and int(np.prod(init.dims)) >= 16:
            half = numpy_helper.from_array(numpy_helper.to_array(init).astype(np.float16), init.name + "_fp16")
            keep.append(half)
            casts.append(helper.make_node("Cast", [half.name], [init.name], to=onnx.TensorProto.FLOAT,
                                          name=init.name + "_cast"))
        else:
            keep.append(init)
    del g.initializer[:]
    g.initializer.extend(keep)
    nodes = list(g.node)
    del g.node[:]
    g.node.extend(casts + nodes)
    onnx.checker.check_model(m)
    return m


def _run_ort(data: bytes, inputs: dict[str, np.ndarray]) -> np.ndarray:
    import onnxruntime as ort  # optional: onnxruntime (the learn and realtime extras)

    session = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
    return session.run(None, inputs)[0]


def check_against_torch(model: torch.nn.Module, data: bytes, seed: int = 0, size: tuple[int, int] = (37, 45)
                        ) -> float:
    """Largest absolute difference between onnxruntime on ``data`` and torch, on a random
    image, pre-correction and eye of an odd ``size`` (not the size traced at export)."""
    rng = np.random.default_rng(seed)
    H, W = size
    inputs = {"image": rng.random((1, 3, H, W), dtype=np.float32),
              "precorrected": rng.random((1, 3, H, W), dtype=np.float32),
              "eye": rng.uniform(-1, 1, (1, 4)).astype(np.float32)}
    if "gradient" in model.input_names:
        inputs["gradient"] = rng.uniform(-0.2, 0.2, (1, 3, H, W)).astype(np.float32)
    with torch.no_grad():
        ref = model(*(torch.from_numpy(inputs[k]) for k in model.input_names)).numpy()
    return float(np.max(np.abs(_run_ort(data, inputs) - ref)))


def stamp_and_write(proto: Any, meta: dict[str, str], out: Path, force: bool, doc: str = "") -> bytes:
    """Add ``meta`` to the ONNX ``proto`` as metadata (and ``doc`` as its doc string), name vrcorrect
    its producer and write it to ``out`` atomically (:func:`~vrcorrect.plumbing.fileio.write_with`:
    an existing file only with ``force``); returns the bytes written."""
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.producer_name = "vrcorrect"
    if doc:
        proto.doc_string = doc
    blob = proto.SerializeToString()
    write_with(out, lambda tmp: tmp.write_bytes(blob), force=force)
    return blob


def export_onnx(checkpoint: str | Path, out: str | Path, fp16: bool = False, force: bool = False) -> ExportReport:
    """Export ``checkpoint`` to ``out`` (``.onnx``), checked against torch; see the module docstring.

    Raises
    ------
    InputError
        Unreadable checkpoint, existing ``out`` without ``force``, or onnxruntime differing
        from torch by more than :data:`FP32_TOLERANCE` (nothing is written then).
    """
    import onnx  # optional: onnx (the learn extra)

    out = Path(out)
    if out.suffix.lower() != ".onnx":
        raise ValidationError("--output", str(out), "a path ending in .onnx")
    check_writable(out, force=force)
    ckpt = load_checkpoint(checkpoint)
    model = model_from_checkpoint(ckpt)
    data = onnx_bytes(model)
    err32 = check_against_torch(model, data)
    if not err32 <= FP32_TOLERANCE:
        raise InputError(f"{checkpoint}: onnxruntime differs from torch by {err32:.3g} "
                         f"(> {FP32_TOLERANCE:g}); not written")
    proto = onnx.load_from_string(data)
    err16 = None
    precision = "fp32"
    if fp16:
        proto = fp16_weights(proto)
        precision = "fp16-weights"
        err16 = check_against_torch(model, proto.SerializeToString())
    meta = metadata_for(ckpt, precision)
    blob = stamp_and_write(proto, meta, out, force, "vrcorrect learned correction: inputs image, precorrected "
                           "(N,3,H,W) linear RGB, eye (N,4) features and, for models trained with it, gradient "
                           "(N,3,H,W); output displayed (N,3,H,W). See vrcorrect.runtime.learned.")
    return ExportReport(path=out, precision=precision, max_abs_error_fp32=err32, max_abs_error_fp16=err16,
                        metadata=meta, bytes=len(blob))
