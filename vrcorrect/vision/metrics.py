"""Image quality metrics: ColorVideoVDP (JOD), FLIP, SSIM, PSNR and the LMS objective.

Layer 3. Imports numpy and the layers below at module level; scikit-image,
flip_evaluator and ColorVideoVDP (``cvvdp``, which needs torch and
torchvision) only inside the functions that use them, so the real-time path,
which never scores, never imports torch.

Which score to believe
----------------------
**JOD** (:func:`jod`, ColorVideoVDP, Mantiuk et al. 2024) is the primary
score: it was built and calibrated on human judgements of exactly this kind
of difference (blur, ringing, contrast and colour changes), and it is told
the display's pixels per degree, peak luminance, contrast and ambient light.
10 means identical; one JOD less means about 75 % of observers would pick
the other image.  **FLIP** is a second opinion only: on this problem it
ranks a ringing-free blur above a sharper image with a little ringing, which
neither ColorVideoVDP nor a look at a text chart does.

Two ways of scoring what an eye sees (:func:`evaluate_seen`):

* **On what the eye sees** (``flip``, ``ssim``, ``psnr``): the retinal cone
  images are mapped back to the display's linear RGB
  (:func:`vrcorrect.vision.forward.lms_to_display`, which clips to the gamut) and
  encoded with the sRGB transfer function, then compared as ordinary sRGB
  images.  This is the meaningful score.
* **In LMS space as the paper did** (``flip_lms``, ``ssim_lms``,
  ``psnr_lms``): ChromaCorrect (Güzel et al. 2023, Fig. 6 and supplementary)
  reports FLIP/SSIM/PSNR of the simulated LMS images themselves.  Here both
  LMS images are divided by the largest cone response of the display's white
  (``max_k sum_c A[k, c]``, which is 1 because the cone responses are
  normalised so that white gives L = M = S = 1), clipped to [0, 1], and the
  (L, M, S) triplets are handed to the metrics as if they were (R, G, B)
  code values.  FLIP's colour model does not apply to such input; the numbers
  are only for comparison with the paper's.

flip_evaluator (NVIDIA FLIP, ``flip-evaluator`` 1.7) facts found by
experiment: ``evaluate(reference, test, "LDR", applyMagma=False,
parameters={"ppd": ppd})`` returns ``(error_map, mean_error, parameters)``,
``error_map`` of shape ``(H, W, 1)`` float32 with ``mean_error`` equal to its
mean.  It accepts any size down to 1x1 (its filters clamp at the image edge:
a constant 1x1 pair scores the same as a constant 32x32 pair), converts
float64 and non-contiguous arrays itself, but silently accepts NaN and values
outside [0, 1], raises ``RuntimeError`` on a size mismatch, ``TypeError`` on a
2-D array, and calls ``sys.exit`` on a non-positive ppd.  :func:`flip`
therefore validates everything first and passes float32 C-contiguous arrays.
"""

from __future__ import annotations

import importlib.util
import math
import os
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..physics.kernel import EyeKernel
from ..physics.perception import apply_matrix
from ..plumbing.errors import InputError, ValidationError
from ..specs.display import DisplayProfile, encode
from .forward import check_image, lms_to_display, simulate_lms

__all__ = [
    "RANGE_TOLERANCE",
    "ImageMetrics",
    "psnr",
    "ssim",
    "flip",
    "jod",
    "foveated_jod",
    "video_jod",
    "lms_objective",
    "evaluate_seen",
]

#: Excursions outside [0, 1] up to this size are clipped (rounding); larger ones are rejected.
RANGE_TOLERANCE = 1e-6

#: skimage's default SSIM window (7x7, uniform).
SSIM_WIN_SIZE = 7
#: SSIM stabilising constants as fractions of the data range (Wang et al. 2004).
SSIM_K1, SSIM_K2 = 0.01, 0.03


# --------------------------------------------------------------------------
# Validation helpers
# --------------------------------------------------------------------------


def _as_float_array(value: Any, name: str) -> np.ndarray:
    """``value`` as a float64 array, or a ValidationError naming ``name``."""
    try:
        arr = np.asarray(value)
    except Exception:  # pragma: no cover - exotic objects
        raise ValidationError(name, type(value).__name__, "a numeric array") from None
    if arr.dtype.kind not in "biuf":
        raise ValidationError(f"{name}.dtype", str(arr.dtype), "a real numeric array (float, int or bool)")
    return arr.astype(np.float64, copy=False)


def _check_finite(arr: np.ndarray, name: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        raise ValidationError(name, f"{int(bad.sum())} NaN/inf values", "finite values")


def _check_pair(reference: Any, test: Any, require_rgb: bool,
                names: tuple[str, str] = ("reference", "test")) -> tuple[np.ndarray, np.ndarray]:
    """Two finite float64 arrays of one shape; ``(H, W, 3)`` when ``require_rgb``."""
    a = _as_float_array(reference, names[0])
    b = _as_float_array(test, names[1])
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
    _check_finite(a, names[0])
    _check_finite(b, names[1])
    return a, b


def _check_unit_range(arr: np.ndarray, name: str) -> np.ndarray:
    """Clip excursions outside [0, 1] up to :data:`RANGE_TOLERANCE`; reject larger ones."""
    lo, hi = float(arr.min()), float(arr.max())
    if lo < -RANGE_TOLERANCE or hi > 1.0 + RANGE_TOLERANCE:
        worst = lo if -lo > hi - 1.0 else hi
        raise ValidationError(name, f"value {worst:.6g} (range {lo:.6g} to {hi:.6g})",
                              f"values in [0, 1] (excursions up to {RANGE_TOLERANCE:g} are clipped)")
    return np.clip(arr, 0.0, 1.0)


def _check_positive(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValidationError(name, value, "a positive finite number")
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValidationError(name, value, "a positive finite number")
    return v


# --------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------


def psnr(reference: np.ndarray, test: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB.

    ``10 log10(data_range² / MSE)`` via
    :func:`skimage.metrics.peak_signal_noise_ratio`, accumulated in float64.

    Parameters
    ----------
    reference, test
        Arrays of one shape (any number of dimensions, non-empty), finite.
        Values outside ``[0, data_range]`` are used as given.
    data_range
        Peak-to-peak range of the signal (> 0, finite); 1 for images in [0, 1].

    Returns
    -------
    float
        PSNR in dB; ``math.inf`` when the images are identical.

    Raises
    ------
    ValidationError
        Naming ``reference``/``test`` (shape mismatch, NaN/inf, non-numeric)
        or ``data_range``.
    """
    dr = _check_positive(data_range, "data_range")
    a, b = _check_pair(reference, test, require_rgb=False)
    mse = float(np.mean((a - b) ** 2))
    if mse == 0.0:
        return math.inf
    # optional: scikit-image (the metrics extra)
    from skimage.metrics import peak_signal_noise_ratio

    return float(peak_signal_noise_ratio(a, b, data_range=dr))


def _global_ssim(a: np.ndarray, b: np.ndarray, data_range: float) -> float:
    """SSIM over the whole image as one window, per channel, averaged over channels.

    ``((2 µa µb + C1)(2 σab + C2)) / ((µa² + µb² + C1)(σa² + σb² + C2))`` with
    ``C1 = (K1 L)²``, ``C2 = (K2 L)²`` and population (ddof 0) moments, so it
    is defined for a single pixel.
    """
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    axes = (0, 1)
    mu_a, mu_b = a.mean(axis=axes), b.mean(axis=axes)
    var_a = ((a - mu_a) ** 2).mean(axis=axes)
    var_b = ((b - mu_b) ** 2).mean(axis=axes)
    cov = ((a - mu_a) * (b - mu_b)).mean(axis=axes)
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return float(np.mean(s))


def ssim(reference: np.ndarray, test: np.ndarray, data_range: float = 1.0) -> float:
    """Mean structural similarity of two ``(H, W, 3)`` images.

    :func:`skimage.metrics.structural_similarity` with ``channel_axis=-1``
    and its defaults (7x7 uniform window, K1 = 0.01, K2 = 0.03, sample
    covariance), computed in float64.  Images smaller than 7 pixels on a
    side use the largest odd window that fits (3 or 5).  Below 3 pixels on
    a side no window fits: identical images give 1.0, others the SSIM formula
    evaluated once over the whole image per channel (population moments) and
    averaged over the channels.

    Parameters
    ----------
    reference, test
        ``(H, W, 3)`` arrays of one shape, finite.
    data_range
        Peak-to-peak range (> 0, finite); 1 for images in [0, 1].

    Returns
    -------
    float
        SSIM in [-1, 1]; 1 for identical images.

    Raises
    ------
    ValidationError
        Naming ``reference``/``test`` (not ``(H, W, 3)``, shape mismatch,
        NaN/inf) or ``data_range``.
    """
    dr = _check_positive(data_range, "data_range")
    a, b = _check_pair(reference, test, require_rgb=True)
    if np.array_equal(a, b):
        return 1.0
    side = min(a.shape[0], a.shape[1])
    if side < 3:
        return _global_ssim(a, b, dr)
    win = min(SSIM_WIN_SIZE, side if side % 2 == 1 else side - 1)
    # optional: scikit-image (the metrics extra)
    from skimage.metrics import structural_similarity

    return float(structural_similarity(a, b, data_range=dr, channel_axis=-1, win_size=win))


def flip(reference_srgb: np.ndarray, test_srgb: np.ndarray,
         pixels_per_degree: float) -> tuple[float, np.ndarray]:
    """NVIDIA FLIP (LDR) between two sRGB-encoded images.

    Calls ``flip_evaluator.evaluate(reference, test, "LDR", applyMagma=False,
    parameters={"ppd": pixels_per_degree})`` after validating everything it
    would otherwise mishandle (it calls ``sys.exit`` on some bad arguments and
    silently accepts NaN and out-of-range values).

    Parameters
    ----------
    reference_srgb, test_srgb
        ``(H, W, 3)`` sRGB-encoded code values in [0, 1], one shape, any size
        from 1x1 (FLIP's filters clamp at the edges).  Excursions outside
        [0, 1] up to :data:`RANGE_TOLERANCE` are clipped; larger ones raise.
    pixels_per_degree
        Angular resolution at which the images are seen (> 0, finite).  FLIP's
        own default (67) is a desktop monitor; a headset has about 20-25.

    Returns
    -------
    (mean_error, error_map)
        Mean FLIP error (0 identical, up to 1) and the ``(H, W)`` float32
        per-pixel error map (without colour map).

    Raises
    ------
    ValidationError
        Naming ``reference_srgb``/``test_srgb`` (not ``(H, W, 3)``, shape
        mismatch, NaN/inf, out of range) or ``pixels_per_degree``.
    """
    ppd = _check_positive(pixels_per_degree, "pixels_per_degree")
    names = ("reference_srgb", "test_srgb")
    a, b = _check_pair(reference_srgb, test_srgb, require_rgb=True, names=names)
    a = np.ascontiguousarray(_check_unit_range(a, names[0]), dtype=np.float32)
    b = np.ascontiguousarray(_check_unit_range(b, names[1]), dtype=np.float32)
    import flip_evaluator  # optional: flip-evaluator (the metrics extra)

    try:
        error_map, mean_error, _params = flip_evaluator.evaluate(
            a, b, "LDR", applyMagma=False, parameters={"ppd": ppd})
    except SystemExit:  # pragma: no cover - validation above should make this unreachable
        raise ValidationError("flip arguments", f"ppd={ppd}, shape={a.shape}",
                              "arguments flip_evaluator accepts") from None
    error_map = np.asarray(error_map, dtype=np.float32).reshape(a.shape[:2])
    return float(mean_error), error_map


#: Smallest image side ColorVideoVDP can score (its pyramid fails on a 1-pixel side).
JOD_MIN_SIDE = 2
#: Keeps the schema declarations of torchvision's missing compiled operators alive (see _import_cvvdp).
_TORCHVISION_SCHEMAS: list = []


def _import_cvvdp():
    """Import ``pycvvdp``, making torchvision importable beside the CPU build of torch.

    ColorVideoVDP imports torchvision for two pure-Python pieces
    (``transforms.GaussianBlur`` and ``ops.MLP``).  The torchvision wheel that
    matches this project's torch (0.28.0 for torch 2.13.0) is built against
    CUDA torch: its compiled operators (``torchvision/_C.so``) link CUDA
    libraries the CPU build lacks, so they fail to load, which torchvision
    tolerates, except that its ``_meta_registrations`` registers fake kernels
    for ``torchvision::nms`` and ``torchvision::qnms`` without checking, and
    the import fails with "operator torchvision::nms does not exist".  When
    the compiled operators cannot load, this declares those two operators'
    schemas (no kernel: calling them still fails loudly) so the import
    succeeds.  Nothing ColorVideoVDP calls uses them.
    """
    try:
        import torch  # optional: torch (the solve and learn extras)
    except ImportError as exc:
        raise InputError(f"ColorVideoVDP needs torch, which is not installed ({exc}); install the 'metrics' "
                         "and 'solve' extras (bash tools/setup.sh)") from None
    if "torchvision" not in sys.modules and not _TORCHVISION_SCHEMAS:
        spec = importlib.util.find_spec("torchvision")
        compiled = os.path.join(os.path.dirname(spec.origin), "_C.so") if spec and spec.origin else None
        try:
            if compiled is None or not os.path.exists(compiled):
                raise OSError("no compiled operators")
            torch.ops.load_library(compiled)
        except (OSError, RuntimeError):
            lib = torch.library.Library("torchvision", "DEF")
            for op in ("nms", "qnms"):
                lib.define(f"{op}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
            _TORCHVISION_SCHEMAS.append(lib)
    try:
        import pycvvdp  # optional: cvvdp (the metrics extra)
    except ImportError as exc:
        raise InputError(f"ColorVideoVDP (PyPI 'cvvdp') cannot be imported ({exc}); install the 'metrics' extra "
                         "(bash tools/setup.sh)") from None
    return torch, pycvvdp


def _jod_pair(reference_srgb: Any, test_srgb: Any, display: Any) -> tuple[np.ndarray, np.ndarray]:
    """:func:`jod`'s and :func:`foveated_jod`'s inputs checked (each error naming its field) and as
    the metrics take them: float32 ``(H, W, 3)`` in [0, 1]."""
    if not isinstance(display, DisplayProfile):
        raise ValidationError("display", type(display).__name__, "a DisplayProfile (vrcorrect.specs.display.get_display)")
    names = ("reference_srgb", "test_srgb")
    a, b = _check_pair(reference_srgb, test_srgb, require_rgb=True, names=names)
    if min(a.shape[:2]) < JOD_MIN_SIDE:
        raise ValidationError(f"{names[0]}.shape", a.shape, f"at least {JOD_MIN_SIDE}x{JOD_MIN_SIDE} pixels "
                              "(the metrics' pyramids need two)")
    return (np.ascontiguousarray(_check_unit_range(a, names[0]), dtype=np.float32),
            np.ascontiguousarray(_check_unit_range(b, names[1]), dtype=np.float32))


def jod(reference_srgb: np.ndarray, test_srgb: np.ndarray, display: DisplayProfile) -> float:
    """ColorVideoVDP quality of ``test_srgb`` against ``reference_srgb`` on ``display``, in JOD.

    ColorVideoVDP (PyPI ``cvvdp``; Mantiuk, Hammou, Hanji, "ColorVideoVDP: A
    visual difference predictor for image, video and display distortions",
    ACM Transactions on Graphics 43(4), 2024) predicts how different two
    images look to a human observer, in just-objectionable differences: 10
    means no visible difference; each JOD less means about 75 % of observers
    would choose the better one.  It runs on the CPU, offline (no download).

    The viewing conditions are the display's: geometry from
    ``display.pixels_per_degree`` and the image size; photometry from
    ``display.photometry`` (peak luminance, contrast, ambient light and
    reflectivity, with the sRGB transfer function, which is how the images
    are encoded here whatever the panel's own).

    Parameters
    ----------
    reference_srgb, test_srgb
        ``(H, W, 3)`` sRGB-encoded code values in [0, 1], one shape, each side
        at least :data:`JOD_MIN_SIDE` pixels.  Excursions outside [0, 1] up to
        :data:`RANGE_TOLERANCE` are clipped; larger ones raise.
    display
        A :class:`vrcorrect.specs.display.DisplayProfile`.

    Returns
    -------
    float
        JOD, at most 10 (identical images score 10 to float precision).

    Raises
    ------
    ValidationError
        Naming ``reference_srgb``/``test_srgb`` (not ``(H, W, 3)``, too small,
        shape mismatch, NaN/inf, out of range) or ``display``.
    InputError
        When ColorVideoVDP or torch is not installed.
    """
    a, b = _jod_pair(reference_srgb, test_srgb, display)
    torch, metric = _cvvdp_for(display, a.shape[1], a.shape[0])
    with torch.no_grad():
        q, _stats = metric.predict(torch.from_numpy(b), torch.from_numpy(a), dim_order="HWC")
    return float(q)


def foveated_jod(reference_srgb: np.ndarray, test_srgb: np.ndarray, display: DisplayProfile,
                 fixation_px: tuple[float, float]) -> float:
    """FovVideoVDP's quality of ``test_srgb`` against ``reference_srgb`` on ``display`` for an eye
    fixating ``fixation_px`` (``(x, y)`` pixels, rows top first), in JOD.

    FovVideoVDP (PyPI ``pyfvvdp``; Mantiuk, Ashraf, Chapiro, "FovVideoVDP: A visible difference
    predictor for wide field-of-view video", ACM Transactions on Graphics 40(4), 2021), in its
    foveated mode: the eye's sensitivity falls with the eccentricity from the fixation point, so a
    difference far from it counts less than one at it.  It compares luminance (no colour).  The
    viewing conditions are :func:`jod`'s: the display's pixels per degree (as a horizontal field of
    view of the image's width) and photometry (peak luminance, contrast, ambient light and
    reflectivity, the sRGB transfer function).  It runs on the CPU, offline.

    Raises
    ------
    ValidationError
        As :func:`jod`, and ``fixation_px`` outside the image.
    InputError
        When FovVideoVDP or torch is not installed.
    """
    a, b = _jod_pair(reference_srgb, test_srgb, display)
    H, W = a.shape[:2]
    fx, fy = (float(v) for v in fixation_px)
    if not (math.isfinite(fx) and math.isfinite(fy) and 0 <= fx < W and 0 <= fy < H):
        raise ValidationError("fixation_px", fixation_px, f"a point inside the {W}x{H} image")
    torch, _ = _import_cvvdp()             # torch and torchvision set up as ColorVideoVDP needs them
    try:
        import pyfvvdp  # optional: pyfvvdp (the metrics extra)
    except ImportError as exc:
        raise InputError(f"FovVideoVDP (PyPI 'pyfvvdp') cannot be imported ({exc}); install the 'metrics' extra "
                         "(bash tools/setup.sh)") from None
    ph = display.photometry
    ppd = float(display.pixels_per_degree)
    fov = 2.0 * math.degrees(math.atan(W * math.tan(math.radians(0.5 / ppd))))
    metric = pyfvvdp.fvvdp(
        display_name=display.name, foveated=True, quiet=True, device=torch.device("cpu"),
        display_geometry=pyfvvdp.fvvdp_display_geometry((W, H), fov_horizontal=fov),
        display_photometry=pyfvvdp.fvvdp_display_photo_eotf(ph.peak_luminance_cd_m2, contrast=ph.contrast, EOTF="sRGB",
                                                            E_ambient=ph.ambient_lux, k_refl=ph.reflectivity,
                                                            name=display.name))
    with torch.no_grad():
        q, _stats = metric.predict(torch.from_numpy(b), torch.from_numpy(a), dim_order="HWC",
                                   fixation_point=torch.tensor([int(fx), int(fy)]))
    return float(q)


#: Highest frame rate :func:`video_jod` accepts (Hz): ColorVideoVDP's temporal filters span a quarter
#: of a second, so their frame buffers grow with the rate (about 250 frames at 1000 Hz).
VIDEO_JOD_MAX_FPS = 1000.0


def _frames_array(frames: Any, name: str) -> np.ndarray:
    """``frames`` (an ``(F, H, W, 3)`` array or a sequence of ``(H, W, 3)`` frames) as one float32
    C-contiguous ``(F, H, W, 3)`` array in [0, 1], checked frame by frame (no float64 copy of the
    whole clip)."""
    if isinstance(frames, np.ndarray) or hasattr(frames, "__array_interface__"):
        arr = np.asarray(frames)
        if arr.dtype.kind not in "biuf":
            raise ValidationError(f"{name}.dtype", str(arr.dtype), "a real numeric array (float, int or bool)")
        if arr.ndim != 4 or arr.shape[3] != 3:
            raise ValidationError(f"{name}.shape", arr.shape, "(frames, height, width, 3)")
        seq: Any = arr
    elif isinstance(frames, (list, tuple)):
        seq = frames
    else:
        raise ValidationError(name, type(frames).__name__,
                              "an (F, H, W, 3) array or a list of (H, W, 3) frames of sRGB code values")
    if len(seq) < 1:
        raise ValidationError(f"{name}.shape", getattr(seq, "shape", (0,)), "at least 1 frame")
    first = np.shape(seq[0])
    if len(first) != 3 or first[2] != 3:
        raise ValidationError(f"{name}[0].shape", first, "(height, width, 3)")
    if min(first[:2]) < JOD_MIN_SIDE:
        raise ValidationError(f"{name}.shape", (len(seq), *first), f"frames of at least {JOD_MIN_SIDE}x{JOD_MIN_SIDE} "
                              "pixels (ColorVideoVDP's pyramid needs two)")
    out = np.empty((len(seq), *first), dtype=np.float32)
    for i in range(len(seq)):
        frame = _as_float_array(seq[i], f"{name}[{i}]") if not isinstance(seq, np.ndarray) else seq[i]
        if frame.shape != first:
            raise ValidationError(f"{name}[{i}].shape", frame.shape, f"the shape of {name}[0], {first}")
        frame = frame.astype(np.float64, copy=False)
        _check_finite(frame, f"{name}[{i}]")
        out[i] = _check_unit_range(frame, f"{name}[{i}]")
    return out


def video_jod(reference_frames: Any, test_frames: Any, display: DisplayProfile, fps: float) -> float:
    """ColorVideoVDP quality of the clip ``test_frames`` against ``reference_frames`` on
    ``display``, in JOD, in video mode: the metric's temporal channels (sustained and transient)
    see flicker and changes from frame to frame that per-frame scores miss.

    Viewing conditions exactly as :func:`jod` (geometry from ``display.pixels_per_degree`` and the
    frame size; photometry from ``display.photometry``, sRGB encoding); the clip is scored with
    ``predict(test, reference, dim_order="FHWC", frames_per_second=fps)``.

    Parameters
    ----------
    reference_frames, test_frames
        ``(F, H, W, 3)`` arrays, or sequences of ``F`` arrays ``(H, W, 3)``, of sRGB-encoded code
        values in [0, 1] (float, int or bool arrays as for :func:`jod`: values, not 8-bit codes),
        one shape, ``F >= 1``, each side at least :data:`JOD_MIN_SIDE` pixels.  Excursions outside
        [0, 1] up to :data:`RANGE_TOLERANCE` are clipped; larger ones raise.  ``F == 1`` is a
        still image: ColorVideoVDP then runs in image mode and the result equals
        :func:`jod` of the two frames (``fps`` is checked but has no effect).
    display
        A :class:`vrcorrect.specs.display.DisplayProfile`.
    fps
        The rate the clips are shown at, frames per second: a finite number in
        (0, :data:`VIDEO_JOD_MAX_FPS`] (90 for a headset).

    Returns
    -------
    float
        JOD, at most 10 (identical clips score 10 to float precision).

    Notes
    -----
    Meant for short clips as a headset shows them: seconds, up to a few hundred frames of up to
    about 512x512 pixels.  Memory: both clips are held as float32 (``12 F H W`` bytes each: 71 MB
    for a 1-second 90-frame clip at 256x256) plus ColorVideoVDP's buffers for a quarter of a second
    of frames; the frames are processed one at a time on the CPU.  Time grows with ``F H W``:
    measured on 2 busy CPU cores, that 90-frame 256x256 clip took 38 s and 380 MB above the
    process's baseline, 90 frames at 64x64 about 1 s.

    A still clip is not a still image to ColorVideoVDP: an image is scored as if seen briefly (its
    quality is scaled by the calibrated ``image_int`` = 0.578 before the JOD mapping), a clip for
    its whole duration.  So ``F >= 2`` copies of one image pair lose more:
    ``10 - video_jod = (10 - jod) * image_int ** -jod_exp`` = 1.67 times the image's loss (with the
    metric's ``jod_exp`` = 0.930, where the loss exceeds about 0.004 JOD), the same for any ``F``
    and any rate; measured agreement within 0.001 JOD (tests/test_video_jod.py).

    Raises
    ------
    ValidationError
        Naming ``reference_frames``/``test_frames`` (not ``(F, H, W, 3)``, no frame, frames too
        small, a frame of another shape, NaN/inf, out of range), ``fps`` or ``display``.
    InputError
        When ColorVideoVDP or torch is not installed.
    """
    if not isinstance(display, DisplayProfile):
        raise ValidationError("display", type(display).__name__,
                              "a DisplayProfile (vrcorrect.specs.display.get_display)")
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(float(fps)) and 0.0 < float(fps) <= VIDEO_JOD_MAX_FPS):
        raise ValidationError("fps", fps, f"a frame rate in (0, {VIDEO_JOD_MAX_FPS:g}] frames per second")
    a = _frames_array(reference_frames, "reference_frames")
    b = _frames_array(test_frames, "test_frames")
    if a.shape != b.shape:
        raise ValidationError("test_frames.shape", b.shape, f"the shape of reference_frames, {a.shape}")
    torch, metric = _cvvdp_for(display, a.shape[2], a.shape[1])
    with torch.no_grad():
        q, _stats = metric.predict(torch.from_numpy(b), torch.from_numpy(a), dim_order="FHWC",
                                   frames_per_second=float(fps))
    return float(q)


def _cvvdp_for(display: DisplayProfile, width: int, height: int):
    """ColorVideoVDP under ``display``'s viewing conditions for ``width`` x ``height`` images (what
    :func:`jod` and :func:`video_jod` share); returns ``(torch, metric)``."""
    torch, pycvvdp = _import_cvvdp()
    ph = display.photometry
    metric = pycvvdp.cvvdp(
        display_name=display.name,
        display_geometry=pycvvdp.vvdp_display_geometry((width, height), ppd=float(display.pixels_per_degree)),
        display_photometry=pycvvdp.vvdp_display_photo_eotf(
            ph.peak_luminance_cd_m2, contrast=ph.contrast, source_colorspace="sRGB", EOTF="sRGB",
            E_ambient=ph.ambient_lux, k_refl=ph.reflectivity, name=display.name),
        device=torch.device("cpu"), quiet=True)
    return torch, metric


def lms_objective(lms: np.ndarray, target_lms: np.ndarray) -> float:
    """Mean squared error between two cone images (the optimisation's objective).

    ``mean over pixels and the 3 cones of (lms - target_lms)²``, accumulated
    in float64.

    Parameters
    ----------
    lms, target_lms
        ``(H, W, 3)`` cone responses (L, M, S; display white = 1), one shape,
        finite.

    Raises
    ------
    ValidationError
        Naming ``lms``/``target_lms`` (not ``(H, W, 3)``, shape mismatch,
        NaN/inf).
    """
    a, b = _check_pair(lms, target_lms, require_rgb=True, names=("lms", "target_lms"))
    return float(np.mean((a - b) ** 2))


# --------------------------------------------------------------------------
# What the eye sees
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageMetrics:
    """Scores of what an eye sees against what it should see.

    Attributes
    ----------
    jod
        ColorVideoVDP (:func:`jod`) of the seen image against the target,
        both rendered back to display sRGB, on the display's viewing
        conditions: the primary, perceptual score (10 = identical, higher is
        better).  ``None`` when not computed (``evaluate_seen(..., jod=False)``).
    flip, ssim, psnr
        On the seen and target images rendered back to display sRGB
        (FLIP at the display's pixels per degree; PSNR in dB).
    objective
        :func:`lms_objective` of the seen and target cone images (unscaled).
    flip_lms, ssim_lms, psnr_lms
        On the cone images themselves, scaled by the white's largest cone
        response and clipped to [0, 1], (L, M, S) read as (R, G, B): the
        paper's way of reporting.
    """

    flip: float
    ssim: float
    psnr: float
    objective: float
    flip_lms: float
    ssim_lms: float
    psnr_lms: float
    jod: float | None = None


def _check_linear(image: np.ndarray, name: str) -> np.ndarray:
    return check_image(image, name)  # rejects values a display cannot show


def evaluate_seen(displayed_linear: np.ndarray, target_linear: np.ndarray, eye_kernel: EyeKernel,
                  display: DisplayProfile, target_lms: np.ndarray | None = None,
                  reference_kernel: EyeKernel | None = None, *,
                  with_jod: bool = True) -> tuple[ImageMetrics, dict]:
    """Score what ``eye_kernel``'s eye sees of a displayed image against the target.

    Seen: ``simulate_lms(displayed_linear, eye_kernel)``.  Target, the first
    that applies: ``target_lms`` as given; ``simulate_lms(target_linear,
    reference_kernel)`` (e.g. a sharp eye at the same display); else the
    paper's ideal ``A @ target`` per pixel with ``A = eye_kernel.matrix`` (the
    target as a perfectly focused eye would see it).

    Both cone images are rendered back to the display's linear RGB with
    :func:`vrcorrect.vision.forward.lms_to_display` (``eye_kernel``'s matrix,
    clipped to the gamut) and sRGB-encoded (``encode("srgb", ...)``: FLIP
    expects sRGB code values whatever the panel's own transfer function), and
    FLIP (at ``display.pixels_per_degree``), SSIM and PSNR compare seen
    against target.  ``objective`` is :func:`lms_objective` of the unscaled
    cone images.  The ``*_lms`` scores compare the cone images divided by
    ``max_k sum_c A[k, c]`` (the white's largest cone response, 1 by the
    white normalisation) and clipped to [0, 1], as the paper reported.

    Parameters
    ----------
    displayed_linear
        ``(H, W, 3)`` linear RGB sent to the display, in [0, 1].
    target_linear
        ``(H, W, 3)`` linear RGB of the intended image, in [0, 1].
    eye_kernel
        The viewer's kernel (:func:`vrcorrect.physics.kernel.build_kernel`), built for
        ``display`` (same pixels per degree).
    display
        The display profile; its ``pixels_per_degree`` is FLIP's.
    target_lms
        Optional ``(H, W, 3)`` target cone image; overrides the rest.
    reference_kernel
        Optional kernel of the eye whose view is the target (same display).
    with_jod
        Also score ColorVideoVDP (:func:`jod`, imports torch; about 0.1 s at
        256², 0.7 s at 512² on 2 CPU cores); ``False`` leaves ``jod`` None.

    Returns
    -------
    (metrics, images)
        :class:`ImageMetrics` and a dict of ``(H, W, 3)`` float arrays
        ``"seen_srgb"``, ``"target_srgb"``, ``"seen_lms"``, ``"target_lms"``
        (unscaled cone images) and the ``(H, W)`` FLIP maps ``"flip_map"``
        (sRGB) and ``"flip_map_lms"`` (LMS).

    Raises
    ------
    ValidationError
        Naming the field: ``displayed_linear``/``target_linear`` (shape,
        NaN/inf, outside [0, 1]), ``target_lms``, or
        ``display.pixels_per_degree`` when it differs from the kernel's.
    """
    displayed = _check_linear(displayed_linear, "displayed_linear")
    target = _check_linear(target_linear, "target_linear")
    if displayed.shape != target.shape:
        raise ValidationError("target_linear.shape", target.shape,
                              f"the shape of displayed_linear, {displayed.shape}")
    ppd = float(display.pixels_per_degree)
    for kern, name in ((eye_kernel, "eye_kernel"), (reference_kernel, "reference_kernel")):
        if kern is not None and not math.isclose(kern.pixels_per_degree, ppd, rel_tol=1e-9):
            raise ValidationError("display.pixels_per_degree", ppd,
                                  f"the {name}'s pixels per degree, {kern.pixels_per_degree:g}")

    seen_lms = np.asarray(simulate_lms(displayed, eye_kernel)[0], dtype=np.float64)
    if target_lms is not None:
        t_lms = _as_float_array(target_lms, "target_lms")
        if t_lms.shape != seen_lms.shape:
            raise ValidationError("target_lms.shape", t_lms.shape, f"the image's shape, {seen_lms.shape}")
        _check_finite(t_lms, "target_lms")
    elif reference_kernel is not None:
        t_lms = np.asarray(simulate_lms(target, reference_kernel)[0], dtype=np.float64)
    else:
        t_lms = apply_matrix(np.asarray(eye_kernel.matrix, dtype=np.float64), target.astype(np.float64))

    # On what the eye sees: back to display RGB, sRGB-encoded.
    seen_srgb = encode("srgb", lms_to_display(seen_lms, eye_kernel))
    target_srgb = encode("srgb", lms_to_display(t_lms, eye_kernel))
    flip_mean, flip_map = flip(target_srgb, seen_srgb, ppd)

    # In LMS space as the paper did.
    white_max = float(np.max(np.asarray(eye_kernel.matrix, dtype=np.float64).sum(axis=1)))
    seen_u = np.clip(seen_lms / white_max, 0.0, 1.0)
    target_u = np.clip(t_lms / white_max, 0.0, 1.0)
    flip_lms_mean, flip_map_lms = flip(target_u, seen_u, ppd)

    metrics = ImageMetrics(
        flip=flip_mean,
        ssim=ssim(target_srgb, seen_srgb),
        psnr=psnr(target_srgb, seen_srgb),
        objective=lms_objective(seen_lms, t_lms),
        flip_lms=flip_lms_mean,
        ssim_lms=ssim(target_u, seen_u),
        psnr_lms=psnr(target_u, seen_u),
        jod=jod(target_srgb, seen_srgb, display) if with_jod else None,
    )
    images = {
        "seen_srgb": seen_srgb,
        "target_srgb": target_srgb,
        "flip_map": flip_map,
        "flip_map_lms": flip_map_lms,
        "seen_lms": seen_lms,
        "target_lms": t_lms,
    }
    return metrics, images
