"""Transfer functions: display code values in [0, 1] to linear light in [0, 1] and back, by name
(``"srgb"``, ``"gamma2.2"``, ``"linear"``) or by a profile's :attr:`DisplayProfile.transfer`.

Clip to [0, 1]; NaN stays NaN; the result has the input's floating dtype.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ...plumbing.errors import ValidationError
from .profile import TRANSFERS, DisplayProfile

__all__ = ["srgb_to_linear", "linear_to_srgb", "decode", "encode"]


def _as_float_array(v: Any) -> tuple[np.ndarray, np.dtype | None]:
    """Input as a float array; returns (work array, dtype to cast back to or None)."""
    arr = np.asarray(v)
    if arr.dtype.kind in "iub":
        if arr.dtype.kind == "b" or isinstance(v, (np.ndarray, np.generic)):
            raise ValidationError(
                "v", f"array of dtype {arr.dtype}", "floating-point code values in [0, 1] (divide 8-bit codes by 255)"
            )
        arr = arr.astype(np.float64)  # Python ints / lists of ints: 0 and 1 are valid code values
    elif arr.dtype.kind != "f":
        try:
            arr = arr.astype(np.float64)
        except (TypeError, ValueError):
            raise ValidationError("v", f"array of dtype {arr.dtype}", "floating-point values in [0, 1]") from None
    if arr.dtype == np.float16:
        return arr.astype(np.float32), np.dtype(np.float16)
    return arr, None


def _finish(out: np.ndarray, cast: np.dtype | None) -> np.ndarray:
    return out.astype(cast) if cast is not None else out


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """sRGB code values -> linear light (IEC 61966-2-1 piecewise curve).

    ``v / 12.92`` for ``v <= 0.04045``, else ``((v + 0.055) / 1.055) ** 2.4``.
    Input is clipped to [0, 1] first; NaN stays NaN. The result has the
    input's floating dtype (float32 in, float32 out).
    """
    arr, cast = _as_float_array(v)
    x = np.clip(arr, 0.0, 1.0)
    with np.errstate(invalid="ignore"):
        out = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return _finish(out.astype(x.dtype, copy=False), cast)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """Linear light -> sRGB code values (inverse of :func:`srgb_to_linear`).

    ``12.92·v`` for ``v <= 0.0031308``, else ``1.055·v**(1/2.4) - 0.055``.
    Input clipped to [0, 1] first; NaN stays NaN; dtype follows the input.
    """
    arr, cast = _as_float_array(v)
    x = np.clip(arr, 0.0, 1.0)
    with np.errstate(invalid="ignore"):
        out = np.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1.0 / 2.4) - 0.055)
    return _finish(out.astype(x.dtype, copy=False), cast)


def _transfer_name(profile_or_transfer: DisplayProfile | str) -> str:
    if isinstance(profile_or_transfer, DisplayProfile):
        return profile_or_transfer.transfer
    if isinstance(profile_or_transfer, str) and profile_or_transfer.strip().lower() in TRANSFERS:
        return profile_or_transfer.strip().lower()
    raise ValidationError("transfer", profile_or_transfer, "a DisplayProfile or one of: " + ", ".join(TRANSFERS))


def decode(profile_or_transfer: DisplayProfile | str, v: np.ndarray) -> np.ndarray:
    """Display code values in [0, 1] -> linear light, by the transfer function.

    ``"srgb"``: :func:`srgb_to_linear`; ``"gamma2.2"``: ``v ** 2.2``;
    ``"linear"``: identity. Clips to [0, 1]; NaN stays NaN; dtype follows
    the input.
    """
    return _apply_transfer(profile_or_transfer, v, srgb_to_linear, 2.2)


def encode(profile_or_transfer: DisplayProfile | str, v: np.ndarray) -> np.ndarray:
    """Linear light in [0, 1] -> display code values (inverse of :func:`decode`)."""
    return _apply_transfer(profile_or_transfer, v, linear_to_srgb, 1.0 / 2.2)


def _apply_transfer(profile_or_transfer: DisplayProfile | str, v: np.ndarray,
                    srgb: Callable[[np.ndarray], np.ndarray], gamma_exponent: float) -> np.ndarray:
    """:func:`decode` and :func:`encode`: ``srgb`` for an sRGB display, ``v ** gamma_exponent``
    for gamma 2.2, identity for linear; clipped to [0, 1], dtype following the input."""
    name = _transfer_name(profile_or_transfer)
    if name == "srgb":
        return srgb(v)
    arr, cast = _as_float_array(v)
    x = np.clip(arr, 0.0, 1.0)
    if name == "gamma2.2":
        x = x**gamma_exponent
    return _finish(x.astype(arr.dtype, copy=False), cast)
