"""Where the shipped learned model lives, and the ``--backend``/``--model`` rule of the commands.

Kept apart from :mod:`vrcorrect.runtime.learned` so that a command can resolve its options
without importing the optics (the CLI's start-up stays quick).
"""

from __future__ import annotations

from pathlib import Path

from ..plumbing.errors import ValidationError
from ..specs.vocabulary import Backend

#: The shipped default model (its card beside it: ``default.md``).
DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "default.onnx"


def model_for_backend(backend: str, model: str | Path | None) -> str | None:
    """The ``--model`` of a command with ``--backend``: the path for ``onnx`` (default: the shipped
    model, :data:`DEFAULT_MODEL`), ``None`` for ``glsl``; ``--model`` without ``onnx``, or naming no
    file, is refused before anything slow starts."""
    if backend != Backend.ONNX:
        if model:
            raise ValidationError("--model", str(model), "only with --backend onnx")
        return None
    if model:
        if not Path(model).is_file():
            raise ValidationError("--model", str(model), "an existing ONNX model file")
        return str(model)
    if DEFAULT_MODEL.is_file():
        return str(DEFAULT_MODEL)
    raise ValidationError("--model", None, f"an ONNX model file with --backend onnx (no default model is "
                          f"installed at {DEFAULT_MODEL})")
