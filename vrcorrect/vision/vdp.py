"""ColorVideoVDP (Mantiuk et al. 2024) as this project's judge: :func:`jod` for images,
:func:`video_jod` for clips (video mode), :func:`foveated_jod` and :func:`foveated_video_jod`
(FovVideoVDP's foveated mode, a gaze point and the eye's falloff) for foveated corrections. Each is told the display's pixels per
degree, peak luminance, contrast and ambient light (:class:`~vrcorrect.specs.display.DisplayProfile`).
10 JOD means identical; one JOD less means about 75 % of observers would pick the other image.

Layer 3. ``cvvdp`` (torch, torchvision) is imported inside the functions only: the real-time path,
which never scores, never imports torch.
"""

from __future__ import annotations

import importlib.util
import math
import os
import sys
from typing import Any

import numpy as np

from ..plumbing.errors import InputError, ValidationError
from ..specs.display import DisplayProfile
from .metric_checks import as_float_array, check_finite, check_pair, check_unit_range

__all__ = ["JOD_MIN_SIDE", "VIDEO_JOD_MAX_FPS", "jod", "foveated_jod", "foveated_video_jod", "video_jod"]

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
    a, b = check_pair(reference_srgb, test_srgb, require_rgb=True, names=names)
    if min(a.shape[:2]) < JOD_MIN_SIDE:
        raise ValidationError(f"{names[0]}.shape", a.shape, f"at least {JOD_MIN_SIDE}x{JOD_MIN_SIDE} pixels "
                              "(the metrics' pyramids need two)")
    return (np.ascontiguousarray(check_unit_range(a, names[0]), dtype=np.float32),
            np.ascontiguousarray(check_unit_range(b, names[1]), dtype=np.float32))


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
    fixation = _fixation(fixation_px, W, H)
    torch, metric = _fvvdp_for(display, W, H)
    with torch.no_grad():
        q, _stats = metric.predict(torch.from_numpy(b), torch.from_numpy(a), dim_order="HWC", fixation_point=fixation)
    return float(q)


def foveated_video_jod(reference_frames: Any, test_frames: Any, display: DisplayProfile,
                       fixation_px: tuple[float, float], fps: float) -> float:
    """FovVideoVDP's quality of the clip ``test_frames`` against ``reference_frames`` for an eye
    fixating ``fixation_px`` throughout, in JOD: :func:`foveated_jod` in video mode (its temporal
    channels see flicker and frame-to-frame changes), with the frames and ``fps`` checked as for
    :func:`video_jod`.  Luminance only, on the CPU; time grows with ``F H W``.

    Raises ``ValidationError`` as :func:`video_jod` and :func:`foveated_jod` (naming the field), and
    ``InputError`` when FovVideoVDP or torch is not installed."""
    a, b = _clip_pair(reference_frames, test_frames, display, fps)
    H, W = a.shape[1:3]
    fixation = _fixation(fixation_px, W, H)
    torch, metric = _fvvdp_for(display, W, H)
    with torch.no_grad():
        q, _stats = metric.predict(torch.from_numpy(b), torch.from_numpy(a), dim_order="FHWC",
                                   frames_per_second=float(fps), fixation_point=fixation)
    return float(q)


def _fixation(fixation_px: Any, width: int, height: int) -> Any:
    """``fixation_px`` checked to lie inside the image, as FovVideoVDP takes it (a torch tensor)."""
    try:
        fx, fy = (float(v) for v in fixation_px)
    except (TypeError, ValueError):
        raise ValidationError("fixation_px", fixation_px, "(x, y) in pixels") from None
    if not (math.isfinite(fx) and math.isfinite(fy) and 0 <= fx < width and 0 <= fy < height):
        raise ValidationError("fixation_px", fixation_px, f"a point inside the {width}x{height} image")
    torch, _ = _import_cvvdp()
    return torch.tensor([int(fx), int(fy)])


def _fvvdp_for(display: DisplayProfile, W: int, H: int):
    """FovVideoVDP, foveated, under ``display``'s viewing conditions for ``W`` x ``H`` images;
    returns ``(torch, metric)``."""
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
    return torch, metric


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
        frame = as_float_array(seq[i], f"{name}[{i}]") if not isinstance(seq, np.ndarray) else seq[i]
        if frame.shape != first:
            raise ValidationError(f"{name}[{i}].shape", frame.shape, f"the shape of {name}[0], {first}")
        frame = frame.astype(np.float64, copy=False)
        check_finite(frame, f"{name}[{i}]")
        out[i] = check_unit_range(frame, f"{name}[{i}]")
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
    a, b = _clip_pair(reference_frames, test_frames, display, fps)
    torch, metric = _cvvdp_for(display, a.shape[2], a.shape[1])
    with torch.no_grad():
        q, _stats = metric.predict(torch.from_numpy(b), torch.from_numpy(a), dim_order="FHWC",
                                   frames_per_second=float(fps))
    return float(q)


def _clip_pair(reference_frames: Any, test_frames: Any, display: Any, fps: Any) -> tuple[np.ndarray, np.ndarray]:
    """The checks :func:`video_jod` and :func:`foveated_video_jod` share: the display, the rate and
    both clips (one shape), as float32 ``(F, H, W, 3)`` arrays."""
    if not isinstance(display, DisplayProfile):
        raise ValidationError("display", type(display).__name__,
                              "a DisplayProfile (vrcorrect.specs.display.get_display)")
    _check_fps(fps)
    a = _frames_array(reference_frames, "reference_frames")
    b = _frames_array(test_frames, "test_frames")
    if a.shape != b.shape:
        raise ValidationError("test_frames.shape", b.shape, f"the shape of reference_frames, {a.shape}")
    return a, b


def _check_fps(fps: Any) -> None:
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(float(fps)) and 0.0 < float(fps) <= VIDEO_JOD_MAX_FPS):
        raise ValidationError("fps", fps, f"a frame rate in (0, {VIDEO_JOD_MAX_FPS:g}] frames per second")


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
