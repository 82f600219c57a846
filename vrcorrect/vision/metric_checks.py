"""The checks every metric makes of its inputs (:mod:`vrcorrect.vision.metrics`,
:mod:`vrcorrect.vision.vdp`): arrays of numbers, finite, of one shape, RGB where colour is scored,
within [0, 1] up to :data:`RANGE_TOLERANCE` (clipped: rounding), positive parameters. Each failure
is a :class:`~vrcorrect.plumbing.errors.ValidationError` naming the argument.

Layer 3: numpy only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..plumbing.errors import ValidationError

__all__ = ["RANGE_TOLERANCE", "as_float_array", "check_finite", "check_pair", "check_unit_range", "check_positive"]

#: Excursions outside [0, 1] up to this size are clipped (rounding); larger ones are rejected.
RANGE_TOLERANCE = 1e-6


def as_float_array(value: Any, name: str) -> np.ndarray:
    """``value`` as a float64 array, or a ValidationError naming ``name``."""
    try:
        arr = np.asarray(value)
    except Exception:  # pragma: no cover - exotic objects
        raise ValidationError(name, type(value).__name__, "a numeric array") from None
    if arr.dtype.kind not in "biuf":
        raise ValidationError(f"{name}.dtype", str(arr.dtype), "a real numeric array (float, int or bool)")
    return arr.astype(np.float64, copy=False)


def check_finite(arr: np.ndarray, name: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        raise ValidationError(name, f"{int(bad.sum())} NaN/inf values", "finite values")


def check_pair(reference: Any, test: Any, require_rgb: bool,
                names: tuple[str, str] = ("reference", "test")) -> tuple[np.ndarray, np.ndarray]:
    """Two finite float64 arrays of one shape; ``(H, W, 3)`` when ``require_rgb``."""
    a = as_float_array(reference, names[0])
    b = as_float_array(test, names[1])
    for arr, name in ((a, names[0]), (b, names[1])):
        if require_rgb:
            if arr.ndim != 3 or arr.shape[2] != 3:
                raise ValidationError(f"{name}.shape", arr.shape, "(height, width, 3)")
            if arr.shape[0] < 1 or arr.shape[1] < 1:
                raise ValidationError(f"{name}.shape", arr.shape, "at least 1x1 pixels")
        elif arr.size == 0:
            raise ValidationError(f"{name}.shape", arr.shape, "a non-empty array")
    if a.shape != b.shape:
        raise ValidationError(f"{names[1]}.shape", b.shape, f"the shape of {names[0]}, {a.shape}")
    check_finite(a, names[0])
    check_finite(b, names[1])
    return a, b


def check_unit_range(arr: np.ndarray, name: str) -> np.ndarray:
    """Clip excursions outside [0, 1] up to :data:`RANGE_TOLERANCE`; reject larger ones."""
    lo, hi = float(arr.min()), float(arr.max())
    if lo < -RANGE_TOLERANCE or hi > 1.0 + RANGE_TOLERANCE:
        worst = lo if -lo > hi - 1.0 else hi
        raise ValidationError(name, f"value {worst:.6g} (range {lo:.6g} to {hi:.6g})",
                              f"values in [0, 1] (excursions up to {RANGE_TOLERANCE:g} are clipped)")
    return np.clip(arr, 0.0, 1.0)


def check_positive(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValidationError(name, value, "a positive finite number")
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValidationError(name, value, "a positive finite number")
    return v
