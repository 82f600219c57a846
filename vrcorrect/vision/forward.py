"""Forward model: what an eye sees of a displayed image.

``retina_k = sum_c K[k, c] * image_c`` (true convolution; outside the image the
panel is black), in linear light, as cone responses (L, M, S) with the
display's white at 1.  :func:`lms_to_display` maps cone responses back to the
display's linear RGB for viewing ("what this eye sees").

Two convolution paths that agree: ``"fft"`` (zero-padded real FFTs, one
forward transform per primary and one inverse per cone) and ``"direct"``
(spatial sums).  The dtype follows the image: float32 images are computed in
float32/complex64, float64 in float64.

Exact shortcuts, taken only where they are exact:

* identity kernel (1x1): a per-pixel 3x3 matrix, no convolution;
* a grey image (R == G == B everywhere): ``r_k = (sum_c K[k, c]) * g``,
  three convolutions instead of nine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.ndimage

from ..physics.kernel import EyeKernel
from ..physics.perception import apply_matrix
from ..plumbing.errors import ValidationError

METHODS = ("auto", "fft", "direct")


@dataclass(frozen=True)
class SimulationInfo:
    """What the forward model did (for --explain)."""

    path: str          # "identity", "fft", "direct"
    achromatic: bool   # grey-image shortcut taken
    convolutions: int


UNIT_TOLERANCE = 1e-6
"""Excursions outside [0, 1] up to this are float rounding, clipped; larger ones are refused."""


def check_image(image: np.ndarray, name: str = "image", *, unit_range: bool = True,
                codes: bool = False) -> np.ndarray:
    """The one checker of image arguments of the library's public entry points.

    ``image`` must be ``(H, W, 3)`` with at least one pixel, of a float dtype (float16 is
    converted to float32; float32 and float64 are kept) and finite.  Integer and boolean arrays are
    refused, naming the likely mistake (8-bit code values where linear light is expected), except
    that ``codes=True`` (display code values, e.g. ``runtime.shell.render.render_frame``) also accepts
    uint8 as 0-255 and returns it unchanged.  With ``unit_range`` the values must lie in [0, 1];
    excursions up to :data:`UNIT_TOLERANCE` are clipped.  Every refusal is a
    :class:`~vrcorrect.plumbing.errors.ValidationError` naming ``name``, the value and what is allowed.
    """
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValidationError(f"{name}.shape", a.shape, "(height, width, 3)")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise ValidationError(f"{name}.shape", a.shape, "at least 1x1 pixels")
    if codes and a.dtype == np.uint8:
        return a
    if a.dtype.kind in "uib":
        what = ("float code values in [0, 1] or uint8 0-255" if codes else
                "float linear light in [0, 1] (8-bit code values: decode them first, "
                "vrcorrect.specs.display.decode(display, codes / 255))")
        raise ValidationError(f"{name}.dtype", str(a.dtype), what)
    if a.dtype.kind != "f":
        raise ValidationError(f"{name}.dtype", str(a.dtype), "a float array")
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float32)
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValidationError(f"{name}", f"{int(bad.sum())} NaN/inf values",
                              "finite values in [0, 1]" if unit_range else "finite values")
    if unit_range:
        lo, hi = float(a.min()), float(a.max())
        if lo < -UNIT_TOLERANCE or hi > 1.0 + UNIT_TOLERANCE:
            raise ValidationError(f"{name}", f"values from {lo:.6g} to {hi:.6g}",
                                  "values in [0, 1] (" + ("code values" if codes else "linear light") +
                                  "; a display cannot show others)")
        if lo < 0.0 or hi > 1.0:
            a = np.clip(a, 0.0, 1.0)
    return a


def is_grey(image: np.ndarray) -> bool:
    """True when every pixel has R == G == B exactly."""
    return bool(np.array_equal(image[..., 0], image[..., 1]) and np.array_equal(image[..., 1], image[..., 2]))


def _convolve_direct(channels: np.ndarray, kernels: np.ndarray) -> np.ndarray:
    """out[k] = sum_c kernels[k, c] * channels[c] (true convolution, zero outside)."""
    n_out = kernels.shape[0]
    out = np.zeros((n_out,) + channels.shape[1:], dtype=channels.dtype)
    for k in range(n_out):
        for c in range(channels.shape[0]):
            kern = kernels[k, c].astype(channels.dtype)
            if not kern.any():
                continue
            out[k] += scipy.ndimage.convolve(channels[c], kern, mode="constant", cval=0.0)
    return out


def _convolve_fft(channels: np.ndarray, kernels: np.ndarray) -> np.ndarray:
    """Same as :func:`_convolve_direct` by zero-padded real FFTs."""
    H, W = channels.shape[1:]
    s = kernels.shape[-1]
    r = s // 2
    shape = (scipy.fft.next_fast_len(H + s - 1, real=True), scipy.fft.next_fast_len(W + s - 1, real=True))
    dtype = channels.dtype
    X = scipy.fft.rfft2(channels, s=shape, axes=(1, 2), workers=-1)
    Kf = scipy.fft.rfft2(kernels.astype(dtype), s=shape, axes=(2, 3), workers=-1)
    out = np.empty((kernels.shape[0], H, W), dtype=dtype)
    for k in range(kernels.shape[0]):
        acc = np.einsum("cyx,cyx->yx", Kf[k], X)
        full = scipy.fft.irfft2(acc, s=shape, workers=-1)
        out[k] = full[r:r + H, r:r + W]
    return out


def simulate_lms(image: np.ndarray, eye_kernel: EyeKernel, method: str = "auto",
                 ) -> tuple[np.ndarray, SimulationInfo]:
    """Retinal cone image (L, M, S) of a linear RGB image.

    Parameters
    ----------
    image
        ``(H, W, 3)`` linear display RGB, float32 or float64 (other dtypes are
        converted to float32), finite.
    eye_kernel
        The eye's kernel from :func:`vrcorrect.physics.kernel.build_kernel`.
    method
        ``"auto"`` (FFT for kernels wider than 9 px, else direct), ``"fft"``
        or ``"direct"``.

    Returns
    -------
    (lms, info)
        ``(H, W, 3)`` cone responses in the image's dtype, and what was done.
    """
    if method not in METHODS:
        raise ValidationError("method", method, "one of " + ", ".join(METHODS))
    img = check_image(image)
    if eye_kernel.size == 1:
        return apply_matrix(eye_kernel.kernel[:, :, 0, 0], img), SimulationInfo("identity", False, 0)
    grey = is_grey(img)
    if grey:
        channels = img[None, :, :, 0]
        kernels = eye_kernel.cone_kernels[:, None]
    else:
        channels = np.moveaxis(img, 2, 0)
        kernels = eye_kernel.kernel
    if method == "auto":
        method = "fft" if eye_kernel.size > 9 else "direct"
    fn = _convolve_fft if method == "fft" else _convolve_direct
    out = fn(np.ascontiguousarray(channels), kernels)
    return np.moveaxis(out, 0, 2), SimulationInfo(method, grey, int(kernels.shape[0] * kernels.shape[1]))


def lms_to_display(lms: np.ndarray, eye_kernel: EyeKernel, clip: bool = True) -> np.ndarray:
    """Cone responses -> the display's linear RGB that would produce them.

    Out-of-gamut values are clipped to [0, 1] when ``clip``.
    """
    rgb = apply_matrix(np.linalg.inv(eye_kernel.matrix), lms)
    return np.clip(rgb, 0.0, 1.0) if clip else rgb


def what_the_eye_sees(image: np.ndarray, eye_kernel: EyeKernel, method: str = "auto",
                      ) -> tuple[np.ndarray, SimulationInfo]:
    """Linear display RGB showing, on an ideal display, what the eye sees of ``image``."""
    lms, info = simulate_lms(image, eye_kernel, method)
    return lms_to_display(lms, eye_kernel), info
