"""What ``render``, ``correct`` and ``simulate`` share for clip inputs: the options (``--fps``,
``--clip-fps``), telling a clip from a still image before any heavy import, the plan of frames to
produce (the clip's source frames, or resampled in time to a stated rate), the output folder
(checked before the work), and the progress bar over frames.

The clip itself (folders, animations, videos; the all-or-nothing folder of frames) is
:mod:`vrcorrect.plumbing.clips`.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import numpy as np

from ..plumbing.clips import MAX_CLIP_FRAMES, Clip, FrameFolder, clip_kind, open_clip, resample_indices
from ..plumbing.errors import ValidationError
from .progress import Progress

if TYPE_CHECKING:  # pragma: no cover - typing only
    from .progress import Progress

__all__ = ["MAX_RATE", "CLIP_HELP", "add_input_output", "add_clip_options", "input_clip", "ClipPlan", "plan_frames",
           "output_folder", "frames_bar", "planned_frames"]

MAX_RATE = 1000.0
"""Highest ``--fps`` / ``--clip-fps`` accepted (frames per second)."""

CLIP_HELP = ("IN may also be a clip: a folder of frames (its images in natural order: frame2 before frame10), an "
             "animated GIF/PNG/WebP or a video file (mp4, mkv, webm, mov, avi, ...; decoded by imageio-ffmpeg's "
             "ffmpeg). A clip's frames are written to -o as a FOLDER of frame_00000.png, frame_00001.png, ... "
             f"(created; an existing non-empty folder needs --force), all or nothing. At most {MAX_CLIP_FRAMES} "
             "frames of at most 8192x8192 pixels, one size.")


def add_input_output(p: argparse.ArgumentParser, image_help: str) -> None:
    """``IN`` (an image, or a clip) and ``-o OUT`` (a PNG, or a clip's folder)."""
    p.add_argument("input", metavar="IN", help=f"{image_help}, or a clip: folder of frames, animated GIF/PNG/WebP, "
                                               "video file")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output PNG; for a clip, output folder")


def add_clip_options(p: argparse.ArgumentParser, *, fps_help: str) -> None:
    """``--fps`` and ``--clip-fps`` (with a clip input only)."""
    g = p.add_argument_group("clips")
    g.add_argument("--fps", metavar="F", help=fps_help)
    g.add_argument("--clip-fps", metavar="F",
                   help="the clip's own frame rate: a folder of frames has none (default: --fps, one source frame "
                        "per output frame); for a video or an animation it replaces the file's own timing")


def _rate(text: str | None, field: str) -> float | None:
    if text is None:
        return None
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = float("nan")
    if not (0.0 < value <= MAX_RATE):
        raise ValidationError(field, text, f"a frame rate in (0, {MAX_RATE:g}] frames per second")
    return value


def input_clip(args: argparse.Namespace, *, still_options: tuple[str, ...] = ()) -> Clip | None:
    """The clip of ``args.input`` (checked: :func:`~vrcorrect.plumbing.clips.open_clip`), or
    ``None`` for a still image (or a missing path: the still-image checks report it); refuses
    ``--fps``/``--clip-fps`` on a still image and ``still_options`` (``"frames"`` ...) on a clip.
    Cheap: numpy and Pillow, file headers; a video's frames are counted by ffmpeg."""
    kind = clip_kind(args.input)
    rates = [(name, getattr(args, name.replace("-", "_"))) for name in ("fps", "clip-fps")]
    if kind is None:
        for name, value in rates:
            if value is not None:
                raise ValidationError(f"--{name}", value, "only with a clip input (a folder of frames, an animated "
                                      "GIF/PNG/WebP or a video); a still image is one frame")
        return None
    for name in still_options:
        value = getattr(args, name.replace("-", "_"), None)
        if value is not None:
            raise ValidationError(f"--{name}", value, "only with a still image; a clip's frames come from the clip "
                                  "(and --fps)")
    for name, value in rates:
        _rate(value, f"--{name}")
    return open_clip(args.input)


@dataclass(frozen=True)
class ClipPlan:
    """Which source frame each output frame is (``sources``, non-decreasing), and in words."""

    clip: Clip
    sources: tuple[int, ...]
    frames_per_s: float | None
    text: str

    @property
    def count(self) -> int:
        return len(self.sources)


def plan_frames(clip: Clip, args: argparse.Namespace, default_fps: float | None) -> ClipPlan:
    """The frames to produce: resampled in time to ``--fps`` (or ``default_fps``) when there is a
    rate, each source frame once otherwise.  The source's timing: ``--clip-fps``, else the clip's
    own, else (a folder) the output rate.  More than :data:`MAX_CLIP_FRAMES` output frames is a
    one-line error naming ``--fps``."""
    fps = _rate(args.fps, "--fps")
    fps = default_fps if fps is None else fps
    clip_fps = _rate(args.clip_fps, "--clip-fps")
    head = f"{clip.kind} of {clip.count} frames"
    if fps is None:                                     # correct, simulate: each source frame once
        rate = f" at {clip_fps:g} fps (--clip-fps)" if clip_fps is not None else f" {clip.rate_text}"
        return ClipPlan(clip, tuple(range(clip.count)), clip_fps or clip.frames_per_s,
                        f"{head}{rate} -> {clip.count} frames, one per source frame")
    if clip_fps is not None:
        durations, source = (1.0 / clip_fps,) * clip.count, f"at {clip_fps:g} fps (--clip-fps)"
    elif clip.durations_s is not None:
        durations, source = clip.durations_s, clip.rate_text
    else:
        durations, source = (1.0 / fps,) * clip.count, f"with no frame rate, taken as {fps:g} fps"
    sources = resample_indices(durations, fps)
    if len(sources) > MAX_CLIP_FRAMES:
        raise ValidationError("--fps", args.fps if args.fps is not None else fps,
                              f"a rate that gives at most {MAX_CLIP_FRAMES} frames: {sum(durations):.4g} s of clip at "
                              f"{fps:g} fps are {len(sources)}")
    how = "one per source frame" if list(sources) == list(range(clip.count)) else \
        "source frames repeated or dropped by presentation time"
    return ClipPlan(clip, tuple(sources), fps, f"{head} {source} -> {len(sources)} frames at {fps:g} fps ({how})")


def output_folder(args: argparse.Namespace, plan: ClipPlan) -> FrameFolder:
    """The checked output folder of ``-o`` for ``plan`` (before any work): not a ``.png`` path."""
    out = Path(args.output)
    if out.exists() and out.resolve() == Path(args.input).resolve():
        raise ValidationError("--output", str(out), "a folder other than the input clip's (its frames are read "
                              "while the output is written)")
    if out.suffix.lower() == ".png":
        raise ValidationError("--output", str(out), f"a folder for the clip's {plan.count} frames (the input is a "
                              f"{plan.clip.kind}), e.g. {out.with_suffix('')}/")
    return FrameFolder(out, plan.count, force=args.force)


def frames_bar(desc: str, total: int) -> "Progress":
    """Progress over frames (:class:`~vrcorrect.apps.progress.Progress`: a line redrawn on a terminal,
    a line every few seconds otherwise)."""

    return Progress(desc, "frame", total)


def planned_frames(plan: ClipPlan) -> Iterator[tuple[int, np.ndarray]]:
    """``(source index, frame)`` for each output frame of ``plan``: each source frame decoded once,
    yielded as many times as the plan shows it (the same array object when repeated; dropped ones
    are decoded and skipped)."""
    counts = np.bincount(np.asarray(plan.sources, dtype=np.int64), minlength=plan.clip.count)
    for index, frame in enumerate(plan.clip.frames()):
        for _ in range(int(counts[index])):
            yield index, frame
