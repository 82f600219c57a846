"""Clips: moving pictures read frame by frame, and folders of numbered frames written all or nothing.

A clip is a folder of image files (sorted naturally: ``frame2`` before ``frame10``), an animated
GIF, PNG (APNG) or WebP (more than one frame), or a video file decoded by the ffmpeg that
``imageio-ffmpeg`` ships.  :func:`clip_kind` tells a clip from a still image, :func:`open_clip`
checks one (it exists, it decodes, every frame has one size, it is within :data:`MAX_CLIP_FRAMES`
frames and :data:`~vrcorrect.plumbing.imageio.MAX_PIXELS` pixels a frame) without decoding its
frames, and :meth:`Clip.frames` decodes them one at a time, so a long clip never sits in memory.

Timing: a video has its container's frame rate, an animation its frames' durations, a folder
none (the caller states a rate).  :func:`resample_indices` plays a clip at another rate: the
source frame shown at each displayed frame's time (frames repeated or dropped).

:class:`AnimatedImage` and :class:`VideoReader` are the decoders; the real-time picture sources
(:mod:`vrcorrect.runtime.shell.sources`) play the same files through them.  :class:`FrameFolder`
writes ``frame_00000.png``, ... into a temporary sibling folder and renames it into place at the
end, so an error or a signal leaves no partial output.

Layer 0: numpy and Pillow; ``imageio_ffmpeg`` (the ``realtime`` extra) imported when a video is
opened.
"""

from __future__ import annotations

import bisect
import math
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Iterator, Sequence

import numpy as np
from PIL import Image, UnidentifiedImageError

from .errors import InputError, ValidationError
from .fileio import Writer, atomic_paths
from .imageio import MAX_PIXELS, png_writer, read_image
from .images import IMAGE_SUFFIXES, image_files
from .signals import signals_deferred

__all__ = [
    "ANIMATED_SUFFIXES", "VIDEO_SUFFIXES", "FFMPEG_HINT", "MAX_CLIP_FRAMES", "CLIP_KINDS",
    "natural_key", "clip_folder_files", "is_animated", "AnimatedImage", "VideoReader", "clip_kind", "Clip",
    "open_clip", "read_clip", "frame_starts", "index_at", "resample_indices", "frame_name", "FrameFolder",
]

ANIMATED_SUFFIXES = (".gif", ".png", ".webp")
"""Image files that are a clip when they hold more than one frame."""

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".mkv", ".webm", ".avi", ".mpg", ".mpeg", ".ogv", ".wmv", ".flv")
"""Video files, decoded by the ffmpeg that ``imageio-ffmpeg`` ships (the ``realtime`` extra)."""

FFMPEG_HINT = "pip install imageio-ffmpeg (part of the realtime extra: pip install -e '.[realtime]')"

MAX_CLIP_FRAMES = 10_000
"""Most frames a clip may have (a little under two minutes at 90 Hz)."""

CLIP_KINDS = ("folder", "animation", "video")

#: An animation frame's duration when the file gives none (browsers' convention), and the shortest
#: one taken as given (shorter ones, 0 included, are taken as this).
DEFAULT_FRAME_DURATION_S = 0.1
MIN_FRAME_DURATION_S = 0.01


# --------------------------------------------------------------------------
# Finding the frames
# --------------------------------------------------------------------------


def natural_key(name: str) -> tuple:
    """Sort key that orders the digit runs of ``name`` by value: ``frame2`` before ``frame10``
    (ties, such as ``f01`` and ``f1``, by the plain name)."""
    parts = re.split(r"(\d+)", name)
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p.casefold()) for p in parts if p) + (name,)


def clip_folder_files(folder: str | os.PathLike[str]) -> tuple[Path, ...]:
    """The image files (by suffix, :data:`~vrcorrect.plumbing.images.IMAGE_SUFFIXES`; not hidden ones,
    such as macOS's ``._name.png``) directly in ``folder``, sorted naturally (:func:`natural_key`); an
    :class:`InputError` when there are none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    files = tuple(p for p in image_files(folder) if not p.name.startswith("."))   # hidden files are not frames
    if not files:
        raise InputError(f"{folder}: no images in the folder (a directory of frames holds image files: "
                         f"{' '.join(IMAGE_SUFFIXES)})")
    return tuple(sorted(files, key=lambda p: natural_key(p.name)))


def _image_error(path: Path, exc: BaseException) -> InputError:
    if isinstance(exc, UnidentifiedImageError):
        return InputError(f"{path}: not an image file Pillow can read")
    if isinstance(exc, Image.DecompressionBombError):
        return InputError(f"{path}: image larger than {MAX_PIXELS} pixels")
    return InputError(f"{path}: cannot read image ({exc})")


def is_animated(path: str | os.PathLike[str]) -> bool:
    """True if the image file holds more than one frame (False when Pillow cannot open it)."""
    try:
        with Image.open(path) as im:
            return int(getattr(im, "n_frames", 1) or 1) > 1
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError):
        return False


def _check_pixels(path: Path, width: int, height: int) -> None:
    if width * height > MAX_PIXELS:
        raise InputError(f"{path}: frames of {width}x{height} pixels; at most {MAX_PIXELS} pixels a frame "
                         "(8192x8192) are accepted")


# --------------------------------------------------------------------------
# Decoders (shared with the real-time picture sources)
# --------------------------------------------------------------------------


class _Closing:
    """``with``: :meth:`close` at the end of the block."""

    def close(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class AnimatedImage(_Closing):
    """An animated GIF, PNG (APNG) or WebP opened with Pillow: :attr:`count` frames (the first
    ``max_frames`` of :attr:`total_frames`), their durations in seconds (:attr:`durations_s`; none
    given: 0.1 s, shorter than 0.01 s: 0.01 s), :attr:`size` ``(W, H)``; :meth:`frame` decodes one as
    uint8 ``(H, W, 3)`` sRGB codes (Pillow composes each frame over the ones before it)."""

    def __init__(self, path: str | os.PathLike[str], max_frames: int = MAX_CLIP_FRAMES):
        self.path = Path(path)
        self._image: Image.Image | None = None
        Image.MAX_IMAGE_PIXELS = MAX_PIXELS
        try:
            self._image = Image.open(self.path)
            self.size = (int(self._image.size[0]), int(self._image.size[1]))
            _check_pixels(self.path, *self.size)
            self.total_frames = int(getattr(self._image, "n_frames", 1) or 1)
            self.count = min(self.total_frames, int(max_frames))
            durations = []
            for i in range(self.count):
                self._image.seek(i)
                ms = float(self._image.info.get("duration") or 1e3 * DEFAULT_FRAME_DURATION_S)
                durations.append(max(ms / 1e3, MIN_FRAME_DURATION_S))
        except InputError:
            self.close()
            raise
        except (OSError, ValueError, EOFError, SyntaxError, Image.DecompressionBombError) as exc:
            self.close()
            raise InputError(f"{self.path}: cannot read the animation ({exc})") from None
        self.durations_s = tuple(durations)

    def frame(self, i: int) -> np.ndarray:
        """Frame ``i`` (0 to :attr:`count` - 1) as uint8 ``(H, W, 3)``."""
        if self._image is None:
            raise InputError(f"{self.path}: the animation is closed")
        try:
            self._image.seek(int(i))
            return np.asarray(self._image.convert("RGB"), dtype=np.uint8)
        except (OSError, ValueError, EOFError, SyntaxError) as exc:
            raise InputError(f"{self.path}: cannot read frame {i} ({exc})") from None

    def close(self) -> None:
        if self._image is not None:
            self._image.close()
            self._image = None


def _imageio_ffmpeg(path: Path) -> ModuleType:
    try:
        import imageio_ffmpeg  # on use: the realtime extra (ffmpeg for video files)
    except ImportError as exc:
        raise InputError(f"{path}: video files need imageio-ffmpeg, which is not installed ({exc}); {FFMPEG_HINT}; "
                         "without it, use an animated GIF/PNG/WebP, a folder of images or an image") from None
    return imageio_ffmpeg


def _ffmpeg_message(exc: BaseException) -> str:
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    return (lines[-1] if lines else type(exc).__name__)[:200]


class VideoReader(_Closing):
    """A video file decoded in order by ffmpeg (``imageio_ffmpeg.read_frames``): :attr:`size`
    ``(W, H)``, :attr:`frames_per_s` (the container's rate, ``None`` when it gives none),
    :meth:`read` the next frame as uint8 ``(H, W, 3)`` or ``None`` at the end, :meth:`close` stops
    ffmpeg."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        module = _imageio_ffmpeg(self.path)
        self._frames: Iterator[bytes] | None = None
        try:
            frames = module.read_frames(str(self.path))
            meta = next(frames)
        except (OSError, RuntimeError, StopIteration, ValueError) as exc:
            raise InputError(f"{self.path}: ffmpeg cannot read the video ({_ffmpeg_message(exc)})") from None
        self._frames = frames
        try:
            self.size = (int(meta["size"][0]), int(meta["size"][1]))
        except (KeyError, TypeError, ValueError, IndexError):
            self.close()
            raise InputError(f"{self.path}: ffmpeg found no picture size in the video") from None
        try:
            _check_pixels(self.path, *self.size)
        except InputError:
            self.close()
            raise
        fps = float(meta.get("fps") or 0.0)
        self.frames_per_s: float | None = fps if math.isfinite(fps) and fps > 0 else None
        self.read_count = 0

    def read(self) -> np.ndarray | None:
        if self._frames is None:
            return None
        try:
            data = next(self._frames)
        except StopIteration:
            return None
        except (OSError, RuntimeError) as exc:
            raise InputError(f"{self.path}: ffmpeg failed while decoding frame {self.read_count} "
                             f"({_ffmpeg_message(exc)})") from None
        w, h = self.size
        self.read_count += 1
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)

    def close(self) -> None:
        if self._frames is not None:
            self._frames.close()             # imageio-ffmpeg stops its ffmpeg process
            self._frames = None


def count_video_frames(path: Path) -> int:
    """The number of frames in a video (ffmpeg copies the stream to nowhere and counts)."""
    module = _imageio_ffmpeg(path)
    try:
        count, _seconds = module.count_frames_and_secs(str(path))
    except (OSError, RuntimeError, ValueError) as exc:
        raise InputError(f"{path}: ffmpeg cannot count the video's frames ({_ffmpeg_message(exc)})") from None
    return int(count)


# --------------------------------------------------------------------------
# A clip
# --------------------------------------------------------------------------


def clip_kind(path: str | os.PathLike[str]) -> str | None:
    """``"folder"``, ``"animation"`` (an animated GIF/PNG/WebP of more than one frame) or
    ``"video"`` (by suffix, :data:`VIDEO_SUFFIXES`) when ``path`` is a clip; ``None`` for anything
    else (a still image, or a path that does not exist: the still-image checks report those)."""
    p = Path(path)
    if p.is_dir():
        return "folder"
    if not p.is_file():
        return None
    suffix = p.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        return "video"
    if suffix in ANIMATED_SUFFIXES and is_animated(p):
        return "animation"
    return None


@dataclass(frozen=True)
class Clip:
    """A checked clip (:func:`open_clip`): ``count`` frames of ``size`` ``(W, H)``.

    ``durations_s``: each frame's display duration (a video: one over its rate; an animation: its
    own), ``None`` for a folder (no timing of its own) and a video without a rate.  ``files``: a
    folder's frames in order.  ``notes``: what was noticed and will be done (transparency dropped,
    an animated file in a folder taken by its first frame)."""

    path: Path
    kind: str
    count: int
    size: tuple[int, int]
    durations_s: tuple[float, ...] | None = None
    frames_per_s: float | None = None
    files: tuple[Path, ...] = ()
    notes: tuple[str, ...] = field(default=())

    @property
    def rate_text(self) -> str:
        """The clip's own timing in words: ``"at 24 fps"``, ``"of 100 ms frames (10 fps)"``,
        ``"of varying frame durations (0.83 s)"`` or ``"with no frame rate"``."""
        if self.frames_per_s is not None:
            return f"at {self.frames_per_s:g} fps"
        if self.durations_s:
            d = self.durations_s
            if max(d) - min(d) < 1e-9:
                return f"of {1e3 * d[0]:g} ms frames ({1.0 / d[0]:.3g} fps)"
            return f"of varying frame durations ({sum(d):.3g} s)"
        return "with no frame rate"

    def describe(self) -> str:
        """``"video clip.mp4: 30 frames of 48x40 at 24 fps"``."""
        return f"{self.kind} {self.path.name}: {self.count} frames of {self.size[0]}x{self.size[1]} {self.rate_text}"

    def durations_at(self, frames_per_s: float | None) -> tuple[float, ...]:
        """The frames' durations, with ``frames_per_s`` as the rate of a clip that has none (a
        folder; ValidationError naming ``frames_per_s`` when it is needed and missing)."""
        if self.durations_s is not None:
            return self.durations_s
        if frames_per_s is None or not (math.isfinite(frames_per_s) and frames_per_s > 0):
            raise ValidationError("frames_per_s", frames_per_s, f"a rate in frames per second for a {self.kind} "
                                  "with no timing of its own")
        return (1.0 / float(frames_per_s),) * self.count

    def frames(self) -> Iterator[np.ndarray]:
        """The frames in order, each float32 ``(H, W, 3)`` sRGB code values in [0, 1] (a 16-bit
        PNG in a folder keeps its precision), decoded one at a time."""
        for frame in self._decoded():
            yield frame.astype(np.float32) / 255.0 if frame.dtype == np.uint8 else frame

    def frames_u8(self) -> list[np.ndarray]:
        """All frames as uint8 ``(H, W, 3)`` sRGB codes (16-bit frames rounded), in memory: for short
        clips (``count * W * H * 3`` bytes)."""
        return [frame if frame.dtype == np.uint8 else np.round(frame * 255.0).astype(np.uint8)
                for frame in self._decoded()]

    def _decoded(self) -> Iterator[np.ndarray]:
        """Each frame as decoded: uint8 from an animation or a video, float32 codes from a folder's files."""
        if self.kind == "folder":
            for path in self.files:
                image = read_image(path)
                if (image.shape[1], image.shape[0]) != self.size:      # changed since it was opened
                    raise InputError(f"{path}: {image.shape[1]}x{image.shape[0]} pixels, the clip's frames are "
                                     f"{self.size[0]}x{self.size[1]}")
                yield image
        elif self.kind == "animation":
            with AnimatedImage(self.path, self.count) as animation:
                for i in range(self.count):
                    yield animation.frame(i)
        else:
            with VideoReader(self.path) as video:
                for i in range(self.count):
                    frame = video.read()
                    if frame is None:
                        raise InputError(f"{self.path}: the video ended after {i} of its {self.count} frames")
                    yield frame


def _limit_error(path: Path, count: int, max_frames: int) -> InputError:
    return InputError(f"{path}: {count} frames; a clip may have at most {max_frames} (cut it shorter, e.g. "
                      "ffmpeg -i IN -frames:v N OUT)")


def _open_folder(path: Path, max_frames: int) -> Clip:
    files = clip_folder_files(path)
    if len(files) > max_frames:
        raise _limit_error(path, len(files), max_frames)
    Image.MAX_IMAGE_PIXELS = MAX_PIXELS
    size: tuple[int, int] | None = None
    transparent: list[Path] = []
    animated: list[Path] = []
    for file in files:                                  # headers only: sizes, modes, frame counts
        try:
            with Image.open(file) as im:
                this = (int(im.size[0]), int(im.size[1]))
                if im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info:
                    transparent.append(file)
                if int(getattr(im, "n_frames", 1) or 1) > 1:
                    animated.append(file)
                if im.mode == "F":
                    raise InputError(f"{file}: floating-point images are not supported; use 8- or 16-bit PNG")
        except InputError:
            raise
        except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
            raise _image_error(file, exc) from None
        if size is None:
            size = this
            _check_pixels(file, *size)
        elif this != size:
            raise InputError(f"{file}: {this[0]}x{this[1]} pixels, but the clip's first frame {files[0].name} is "
                             f"{size[0]}x{size[1]}; every frame of a folder must have one size")
    notes = []
    if transparent:
        notes.append(f"{len(transparent)} of the {len(files)} frames have transparency ({transparent[0].name} first): "
                     "it is dropped, the colours are used as stored")
    if animated:
        notes.append(f"{len(animated)} of the frames are animated files ({animated[0].name} first): the first frame "
                     "of each is used")
    return Clip(path, "folder", len(files), size, files=files, notes=tuple(notes))


def _open_animation(path: Path, max_frames: int) -> Clip:
    with AnimatedImage(path, max_frames) as animation:
        if animation.total_frames > max_frames:
            raise _limit_error(path, animation.total_frames, max_frames)
        d = animation.durations_s
        fps = 1.0 / d[0] if max(d) - min(d) < 1e-9 else None
        return Clip(path, "animation", animation.count, animation.size, durations_s=d, frames_per_s=fps)


def _open_video(path: Path, max_frames: int) -> Clip:
    with VideoReader(path) as video:
        size, fps = video.size, video.frames_per_s
        if video.read() is None:
            raise InputError(f"{path}: the video has no frames")
    count = count_video_frames(path)
    if count < 1:
        raise InputError(f"{path}: the video has no frames")
    if count > max_frames:
        raise _limit_error(path, count, max_frames)
    durations = (1.0 / fps,) * count if fps is not None else None
    notes = () if fps is not None else (f"{path.name} states no frame rate: it is timed like a folder of frames",)
    return Clip(path, "video", count, size, durations_s=durations, frames_per_s=fps, notes=notes)


def open_clip(path: str | os.PathLike[str], max_frames: int = MAX_CLIP_FRAMES) -> Clip:
    """Check the clip at ``path`` (see :func:`clip_kind`) without decoding its frames: it exists,
    it decodes, every frame has one size (a folder: the first file that differs is named), at most
    ``max_frames`` frames and :data:`~vrcorrect.plumbing.imageio.MAX_PIXELS` pixels a frame.

    Raises
    ------
    InputError
        One line naming the file: missing, empty folder, no images, unreadable, a video ffmpeg
        cannot read or without frames, mixed sizes, too long, frames too large.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if not os.access(p, os.R_OK):
        raise InputError(f"{p}: not readable (permissions)")
    kind = clip_kind(p)
    if kind == "folder":
        return _open_folder(p, max_frames)
    if kind == "animation":
        return _open_animation(p, max_frames)
    if kind == "video":
        return _open_video(p, max_frames)
    raise InputError(f"{p}: not a clip (a folder of frames, an animated GIF/PNG/WebP or a video: "
                     f"{' '.join(s.lstrip('.') for s in VIDEO_SUFFIXES)})")


read_clip = open_clip
"""The name code that reads a whole short clip uses (``read_clip(path).frames_u8()``)."""


# --------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------


def frame_starts(durations_s: Sequence[float]) -> list[float]:
    """Start times of frames with these durations, and the end of the last: ``[0, d0, d0 + d1, ...]``
    (ValidationError naming ``durations_s`` unless all are finite and > 0)."""
    if len(durations_s) == 0 or any(not (math.isfinite(d) and d > 0) for d in durations_s):
        raise ValidationError("durations_s", durations_s, "one or more finite durations > 0 (seconds)")
    return [0.0, *np.cumsum(np.asarray(durations_s, dtype=np.float64)).tolist()]


def index_at(starts: Sequence[float], t_s: float) -> int:
    """The frame shown at ``t_s`` (clamped to the clip) given :func:`frame_starts`; a time within
    1e-9 s before a frame's start counts as that frame (0.1 + 0.2 is 0.3)."""
    return min(max(bisect.bisect_right(starts, t_s + 1e-9) - 1, 0), len(starts) - 2)


def resample_indices(durations_s: Sequence[float], frames_per_s: float) -> list[int]:
    """Play frames of these durations at ``frames_per_s``: for each displayed frame ``j`` (shown from
    ``j / frames_per_s``), the source frame whose time holds it; source frames are repeated or
    dropped.  The clip lasts ``sum(durations_s)``, so it gives ``ceil(sum * frames_per_s)`` frames
    (at least 1): 30 frames at 24 fps (1.25 s) played at 90 fps are 113."""
    if isinstance(frames_per_s, bool) or not (math.isfinite(frames_per_s) and frames_per_s > 0):
        raise ValidationError("frames_per_s", frames_per_s, "a finite rate > 0 (frames per second)")
    starts = frame_starts(durations_s)
    count = max(1, math.ceil(starts[-1] * frames_per_s - 1e-9))
    return [index_at(starts, j / frames_per_s) for j in range(count)]


# --------------------------------------------------------------------------
# Writing a folder of frames
# --------------------------------------------------------------------------

FRAME_PATTERN = re.compile(r"frame_\d{5,}\.png")


def frame_name(index: int, count: int) -> str:
    """``frame_00000.png``: the index zero-padded to the clip's length, at least 5 digits."""
    return f"frame_{index:0{max(5, len(str(max(count - 1, 0))))}d}.png"


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


class FrameFolder:
    """A folder of numbered PNG frames (:func:`frame_name`), written all or nothing.

    Checked when made, before any work: ``path`` is not a file; an existing folder must be empty,
    or with ``force`` hold only frames (``frame_NNNNN.png``: what this class writes; anything else
    there is the user's and is never deleted); its parent exists and a folder can be made there.
    Used as a context manager: frames go into a temporary sibling folder (``.NAME.*.partial``);
    :meth:`commit` renames it into place (replacing the old folder) together with any other
    outputs; leaving the block without :meth:`commit` (an error, Ctrl-C, SIGTERM) removes it.
    """

    def __init__(self, path: str | os.PathLike[str], count: int, *, force: bool = False):
        self.path, self.count, self.force = Path(path), int(count), bool(force)
        self.tmp: Path | None = None
        self.written = 0
        self._check(final=False)
        parent = self._parent()
        try:
            probe = tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".probe", dir=parent)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot create a folder in {parent} ({exc.strerror or exc})") from None
        os.rmdir(probe)

    def _parent(self) -> Path:
        parent = self.path.parent if str(self.path.parent) else Path(".")
        if not parent.is_dir():
            raise InputError(f"{self.path}: folder {parent} does not exist")
        return parent

    def _check(self, final: bool) -> None:
        p = self.path
        if p.exists() and not p.is_dir():
            raise InputError(f"{p}: is a file; a clip's output is a folder of frames (give a folder path)")
        if not p.is_dir():
            return
        entries = sorted(e.name for e in p.iterdir())
        if entries and not self.force:
            raise InputError(f"{p}: folder exists and is not empty" + (" (it appeared while working)" if final else "")
                             + "; pass --force to replace it")
        foreign = [e for e in entries if not FRAME_PATTERN.fullmatch(e)]
        if foreign:
            raise InputError(f"{p}: holds {foreign[0]!r}, which is not a frame; --force replaces only a folder of "
                             "frame_NNNNN.png files (choose another output folder)")

    def __enter__(self) -> "FrameFolder":
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".partial", dir=self._parent()))
        try:
            os.chmod(self.tmp, 0o777 & ~_umask())
        except OSError:
            pass
        return self

    def name(self, index: int) -> str:
        return frame_name(index, self.count)

    def write(self, index: int, rgb: np.ndarray, bits: int = 8) -> Path:
        """Write frame ``index`` (``(H, W, 3)`` code values in [0, 1]) as an 8- or 16-bit PNG."""
        if self.tmp is None:
            raise InputError(f"{self.path}: write frames inside 'with FrameFolder(...)'")
        if not 0 <= index < self.count:
            raise ValidationError("index", index, f"a frame number from 0 to {self.count - 1}")
        target = self.tmp / self.name(index)
        png_writer(target, rgb, bits)(target)
        self.written += 1
        return self.path / target.name

    def commit(self, others: Sequence[tuple[Path, Writer]] = ()) -> None:
        """Put the folder in place, and ``others`` (``(path, writer)`` pairs, e.g. a report, checked
        like single outputs), with Ctrl-C, SIGTERM and SIGHUP held back: all appear or none."""
        if self.tmp is None:
            raise InputError(f"{self.path}: nothing to commit")
        with signals_deferred():
            self._check(final=True)
            if others:
                with atomic_paths([Path(p) for p, _ in others], force=self.force) as tmps:
                    for (_, writer), tmp in zip(others, tmps):
                        writer(tmp)
            old = None
            if self.path.is_dir():
                old = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".replaced", dir=self._parent()))
                os.rmdir(old)
                os.rename(self.path, old)
            os.rename(self.tmp, self.path)
            self.tmp = None
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)

    def __exit__(self, *exc: Any) -> None:
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            self.tmp = None

