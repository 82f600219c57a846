"""What a picture source is, before anything opens: ``--source`` parsed (:class:`SourceSpec`:
``demo``, an image, a folder, an animated image, a video or ``screen``), ``--size`` and
``--region`` parsed, and the pure helpers the sources use (:func:`fit_rect`: a picture fitted into
an eye, aspect kept; :func:`frame_index`, :func:`frame_at`: which picture belongs to a time;
:func:`folder_images`). No GL, no decoding: the commands check their options with these before
any window opens.

Layer 5: numpy; never torch.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ...plumbing.clips import ANIMATED_SUFFIXES, FFMPEG_HINT, VIDEO_SUFFIXES, clip_folder_files, frame_starts, index_at
from ...plumbing.errors import InputError, ValidationError
from ...plumbing.images import IMAGE_SUFFIXES
from ..gl import Rect

__all__ = ["IMAGE_SUFFIXES", "ANIMATED_SUFFIXES", "VIDEO_SUFFIXES", "MAX_EYE_SIZE", "SourceSpec", "parse_size",
           "parse_source", "parse_region", "fit_rect", "frame_index", "frame_at", "folder_images"]

MAX_EYE_SIZE = 8192
"""Largest eye width or height accepted by :func:`parse_size` (pixels)."""


# --------------------------------------------------------------------------
# Parsing and pure helpers
# --------------------------------------------------------------------------


def parse_size(text: str, field: str = "--size") -> tuple[int, int]:
    """``"WxH"`` (e.g. ``"640x480"``) as ``(width, height)`` in pixels, each 1 to :data:`MAX_EYE_SIZE`."""
    match = re.fullmatch(r"\s*(\d{1,5})\s*[xX]\s*(\d{1,5})\s*", text) if isinstance(text, str) else None
    allowed = f"WIDTHxHEIGHT in pixels, each from 1 to {MAX_EYE_SIZE} (e.g. 640x640)"
    if not match:
        raise ValidationError(field, text, allowed)
    width, height = int(match.group(1)), int(match.group(2))
    if not (1 <= width <= MAX_EYE_SIZE and 1 <= height <= MAX_EYE_SIZE):
        raise ValidationError(field, text, allowed)
    return width, height


def parse_region(text: str, field: str = "--region") -> Rect:
    """``"X,Y,W,H"`` (pixels; ``(X, Y)`` the top-left corner, from the screen's top-left) as a
    :class:`~vrcorrect.runtime.gl.Rect`; W and H from 1 to :data:`MAX_EYE_SIZE`."""
    allowed = f"X,Y,WIDTH,HEIGHT in pixels (X, Y >= 0; WIDTH, HEIGHT 1 to {MAX_EYE_SIZE}), e.g. 0,0,640,480"
    match = re.fullmatch(r"\s*(\d{1,5})\s*,\s*(\d{1,5})\s*,\s*(\d{1,5})\s*,\s*(\d{1,5})\s*", text) \
        if isinstance(text, str) else None
    if not match:
        raise ValidationError(field, text, allowed)
    x, y, w, h = (int(g) for g in match.groups())
    if not (1 <= w <= MAX_EYE_SIZE and 1 <= h <= MAX_EYE_SIZE):
        raise ValidationError(field, text, allowed)
    return Rect(x, y, w, h)


@dataclass(frozen=True)
class SourceSpec:
    """A checked ``--source``: ``kind`` is ``"demo"``, ``"image"`` (a still or animated image
    file), ``"folder"`` (images cycled) or ``"video"``; ``path`` is ``None`` for the demo."""

    kind: str
    path: Path | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("demo", "image", "folder", "video"):
            raise ValidationError("source.kind", self.kind, "demo, image, folder or video")
        if (self.kind == "demo") != (self.path is None):
            raise ValidationError("source.path", self.path, "None for the demo, a path otherwise")

    @property
    def label(self) -> str:
        return "demo scene" if self.path is None else f"{self.kind} {self.path.name}"


def _supported_text() -> str:
    return (f"'demo', an image ({' '.join(s.lstrip('.') for s in IMAGE_SUFFIXES)}; animated GIF/PNG/WebP "
            f"play), a video ({' '.join(s.lstrip('.') for s in VIDEO_SUFFIXES)}; needs imageio-ffmpeg) "
            "or a folder of images")


def _ffmpeg_available() -> bool:
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def parse_source(text: str, field: str = "--source") -> SourceSpec:
    """Check a ``--source`` value: ``demo``, an image or video file, or a folder of images.

    Raises
    ------
    InputError
        A path that does not exist, a folder without images, a file of an unsupported
        kind, or a video when ``imageio-ffmpeg`` is not installed (names what is supported).
    """
    if not isinstance(text, str) or not text.strip():
        raise ValidationError(field, text, _supported_text())
    if text == "demo":
        return SourceSpec("demo")
    path = Path(text)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder; {field} takes {_supported_text()}")
    if path.is_dir():
        folder_images(path)  # raises when empty
        return SourceSpec("folder", path)
    suffix = path.suffix.lower()
    if suffix in IMAGE_SUFFIXES:
        return SourceSpec("image", path)
    if suffix in VIDEO_SUFFIXES:
        if not _ffmpeg_available():
            raise InputError(f"{path}: video files need imageio-ffmpeg, which is not installed ({FFMPEG_HINT}); "
                             "without it, use an animated GIF/PNG/WebP, a folder of images or an image")
        return SourceSpec("video", path)
    raise InputError(f"{path}: unsupported file type {suffix or '(none)'!r}; {field} takes {_supported_text()}")


def folder_images(folder: str | Path) -> tuple[Path, ...]:
    """The image files (by suffix, see :data:`IMAGE_SUFFIXES`) directly in ``folder``, sorted
    naturally (``frame2`` before ``frame10``), as the command-line tools read a folder clip."""
    return clip_folder_files(folder)


def fit_rect(src_width: int, src_height: int, dst_width: int, dst_height: int) -> Rect:
    """The largest rectangle of the source's aspect ratio inside ``dst``, centred (image terms).

    A source of exactly the destination's size fills it; otherwise one side fills and the
    other is centred, rounded to whole pixels (at least 1).
    """
    for name, v in (("src_width", src_width), ("src_height", src_height),
                    ("dst_width", dst_width), ("dst_height", dst_height)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
            raise ValidationError(name, v, "an integer >= 1 (pixels)")
    if src_width * dst_height >= dst_width * src_height:  # source relatively wider: full width
        width, height = dst_width, max(1, min(dst_height, round(dst_width * src_height / src_width)))
    else:
        width, height = max(1, min(dst_width, round(dst_height * src_width / src_height))), dst_height
    return Rect((dst_width - width) // 2, (dst_height - height) // 2, int(width), int(height))


def frame_index(t_s: float, frames_per_s: float, count: int) -> int:
    """Index of the frame shown at time ``t_s`` of a looping sequence of ``count`` frames
    played at ``frames_per_s`` (frame i is shown from ``i / frames_per_s``)."""
    if not (isinstance(count, (int, np.integer)) and count >= 1):
        raise ValidationError("count", count, "an integer >= 1")
    if not (math.isfinite(frames_per_s) and frames_per_s > 0):
        raise ValidationError("frames_per_s", frames_per_s, "a finite number > 0")
    if not math.isfinite(t_s):
        raise ValidationError("t_s", t_s, "a finite time in seconds")
    return int(math.floor(max(t_s, 0.0) * frames_per_s + 1e-9)) % int(count)


def frame_at(t_s: float, durations_s: Sequence[float]) -> int:
    """Index of the frame shown at ``t_s`` in a looping sequence with these frame durations."""
    starts = frame_starts(durations_s)
    t = math.fmod(max(float(t_s), 0.0) + 1e-9, starts[-1]) if math.isfinite(t_s) else 0.0  # 1e-9: 0.1 + 0.2 is 0.3
    return index_at(starts, t)
