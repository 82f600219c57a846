"""Image quality metrics: ColorVideoVDP (JOD), FLIP, SSIM, PSNR and the LMS objective.

ColorVideoVDP and FovVideoVDP themselves (:func:`jod`, :func:`foveated_jod`, :func:`video_jod`)
are in :mod:`vrcorrect.vision.vdp`, the checks of the metrics' inputs in
:mod:`vrcorrect.vision.metric_checks`; this module lists them beside its own.

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

import math
from dataclasses import dataclass

import numpy as np

from ..physics.kernel import EyeKernel
from ..physics.perception import apply_matrix
from ..plumbing.errors import ValidationError
from ..specs.display import DisplayProfile, encode
from .forward import check_image, lms_to_display, simulate_lms
from .metric_checks import RANGE_TOLERANCE, as_float_array, check_finite, check_pair, check_positive, check_unit_range
from .vdp import foveated_jod, jod, video_jod

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

#: skimage's default SSIM window (7x7, uniform).
SSIM_WIN_SIZE = 7
#: SSIM stabilising constants as fractions of the data range (Wang et al. 2004).
SSIM_K1, SSIM_K2 = 0.01, 0.03


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
    dr = check_positive(data_range, "data_range")
    a, b = check_pair(reference, test, require_rgb=False)
    mse = float(np.mean((a - b) ** 2))
    if mse == 0.0:
        return math.inf
    # optional: scikit-image (the metrics extra)
    from skimage.metrics import peak_signal_noise_ratio  # on use: scikit-image (heavy)

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
    dr = check_positive(data_range, "data_range")
    a, b = check_pair(reference, test, require_rgb=True)
    if np.array_equal(a, b):
        return 1.0
    side = min(a.shape[0], a.shape[1])
    if side < 3:
        return _global_ssim(a, b, dr)
    win = min(SSIM_WIN_SIZE, side if side % 2 == 1 else side - 1)
    # optional: scikit-image (the metrics extra)
    from skimage.metrics import structural_similarity  # on use: scikit-image (heavy)

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
    ppd = check_positive(pixels_per_degree, "pixels_per_degree")
    names = ("reference_srgb", "test_srgb")
    a, b = check_pair(reference_srgb, test_srgb, require_rgb=True, names=names)
    a = np.ascontiguousarray(check_unit_range(a, names[0]), dtype=np.float32)
    b = np.ascontiguousarray(check_unit_range(b, names[1]), dtype=np.float32)
    import flip_evaluator  # optional: flip-evaluator (the metrics extra)

    try:
        error_map, mean_error, _params = flip_evaluator.evaluate(
            a, b, "LDR", applyMagma=False, parameters={"ppd": ppd})
    except SystemExit:  # pragma: no cover - validation above should make this unreachable
        raise ValidationError("flip arguments", f"ppd={ppd}, shape={a.shape}",
                              "arguments flip_evaluator accepts") from None
    error_map = np.asarray(error_map, dtype=np.float32).reshape(a.shape[:2])
    return float(mean_error), error_map


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
    a, b = check_pair(lms, target_lms, require_rgb=True, names=("lms", "target_lms"))
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
        t_lms = as_float_array(target_lms, "target_lms")
        if t_lms.shape != seen_lms.shape:
            raise ValidationError("target_lms.shape", t_lms.shape, f"the image's shape, {seen_lms.shape}")
        check_finite(t_lms, "target_lms")
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
