"""Picture sources: what an eye is shown when it is not the 3D demo scene.

A still image, a folder of images (each shown in turn), an animated image (GIF, APNG, WebP), a
video file, or a region of the X11 screen. Every source renders, per frame, one RGBA8 texture
per eye at the eye size, holding sRGB code values in OpenGL's orientation (what
:class:`~vrcorrect.runtime.corrector.Corrector` takes); both eyes see the same picture, fitted
into the eye size, aspect kept, centred on black (docs/architecture.md, 'Physics conventions':
outside the image the panel is black), resampled on the GPU in linear light; a picture of exactly
the eye size is shown texel for texel.

What the sources share is in :class:`PictureSource`: opening (the subclass's :meth:`_open`) and
showing the first picture, or releasing everything when either fails; decoding each new picture
to uint8 codes, fitting it to the eye (:class:`FittedImage`), and the pictures' motion for the
reprojected warm start (:meth:`~PictureSource.track_motion`). A subclass says only how to open
itself and which picture belongs to a time (:meth:`~PictureSource._update`). GPU objects are
made when a source opens (and when a picture of another size comes); rendering allocates nothing.

What a source is (:class:`~vrcorrect.runtime.shell.source_spec.SourceSpec`, parsed from
``--source``), and the pure helpers the sources use, are in
:mod:`~vrcorrect.runtime.shell.source_spec`.

Layer 5: numpy, Pillow, moderngl; video files through ``imageio-ffmpeg`` and the screen
through ``mss`` when installed (both in the ``realtime`` extra).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Callable, Hashable, Iterable, Protocol

import numpy as np

from ...plumbing.clips import ANIMATED_SUFFIXES, AnimatedImage, VideoReader, is_animated
from ...plumbing.errors import InputError, ValidationError
from ...plumbing.imageio import read_image
from ..corrector import runs_iterations
from ..gl import Rect, draw_fullscreen, fullscreen_triangle, release, render_target, upload_texture, write_texture
from ..motion import MotionTracker
from ..optional import import_optional
from ..shaders import compile_program
from .source_spec import SourceSpec, fit_rect, folder_images, frame_at, frame_index

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ..corrector import Corrector

__all__ = [
    "PictureFeed", "EyeTarget", "FittedImage", "PictureSource", "StillSource", "FolderSource",
    "AnimatedImageSource", "VideoSource", "ScreenGrabber", "screen_bounds", "ScreenSource", "open_picture_source",
    "start_motion", "take_motion",
]

# --------------------------------------------------------------------------
# GPU side: an eye's output texture, a picture fitted into it
# --------------------------------------------------------------------------


class PictureFeed(Protocol):
    """What the applications take as a view's pictures: :class:`PictureSource` or the demo scene."""

    label: str
    size: tuple[int, int]

    def render(self, t_s: float) -> tuple["moderngl.Texture", "moderngl.Texture"]: ...

    def release(self) -> None: ...


class EyeTarget:
    """An eye's RGBA8 output texture (+ framebuffer), with a depth buffer and multisampled
    colour for drawing when ``samples`` > 1 (resolved into the texture)."""

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, samples: int, depth: bool):
        self.ctx = ctx
        self.texture, self.framebuffer = render_target(ctx, width=width, height=height)
        self._objects: list[Any] = []
        self.draw_framebuffer: moderngl.Framebuffer = self.framebuffer
        self.multisampled = bool(depth and samples > 1)
        if self.multisampled:
            colour = ctx.renderbuffer((width, height), 4, samples=samples)
            depth_rb = ctx.depth_renderbuffer((width, height), samples=samples)
            self.draw_framebuffer = ctx.framebuffer(color_attachments=[colour], depth_attachment=depth_rb)
            self._objects = [self.draw_framebuffer, colour, depth_rb]
        elif depth:
            depth_rb = ctx.depth_renderbuffer((width, height))
            self.draw_framebuffer = ctx.framebuffer(color_attachments=[self.texture], depth_attachment=depth_rb)
            self._objects = [self.draw_framebuffer, depth_rb]

    def resolve(self) -> None:
        if self.multisampled:
            self.ctx.copy_framebuffer(self.framebuffer, self.draw_framebuffer)

    def release(self) -> None:
        release(*self._objects, self.framebuffer, self.texture)
        self._objects = []


class FittedImage:
    """One picture fitted into an eye-sized RGBA8 texture of sRGB codes (black around it).

    The picture is uploaded as an sRGB texture with mipmaps (decoded, filtered and reduced in
    linear light) and drawn with ``composite.glsl`` (ENCODE_SRGB) into its :func:`fit_rect`.
    The picture's texture is reused while the picture size stays the same.
    """

    def __init__(self, ctx: "moderngl.Context", width: int, height: int):
        self.ctx, self.size = ctx, (int(width), int(height))
        self.target = EyeTarget(ctx, width, height, 0, depth=False)
        self.program: moderngl.Program | None = None
        self.vao: moderngl.VertexArray | None = None
        self.picture: moderngl.Texture | None = None
        try:
            self.program = compile_program(ctx, "composite.glsl", defines={"ENCODE_SRGB": None})
            self.vao = fullscreen_triangle(ctx, self.program)
            self.program["u_source"].value = 0
        except BaseException:
            self.release()
            raise

    def show(self, image: np.ndarray) -> None:
        """Fit ``image`` (uint8 ``(H, W, 3|4)`` sRGB codes, top row first) into the texture."""
        img = np.asarray(image)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
            raise ValidationError("image", f"{img.dtype} array of shape {img.shape}", "uint8 (H, W, 3 or 4)")
        if self.picture is not None and self.picture.size == (img.shape[1], img.shape[0]) \
                and self.picture.components == img.shape[2]:
            write_texture(self.picture, img)
        else:
            release(self.picture)
            self.picture = None
            self.picture = upload_texture(self.ctx, img, filter="mipmap", srgb=True)
        fb = self.target.framebuffer
        fb.use()
        self.ctx.viewport = (0, 0, *self.size)
        fb.clear(0.0, 0.0, 0.0, 1.0)
        self.picture.use(0)
        draw_fullscreen(self.vao, fb, rect=fit_rect(img.shape[1], img.shape[0], *self.size))

    def release(self) -> None:
        release(self.picture, self.vao, self.program)
        self.picture = self.vao = self.program = None
        self.target.release()


def _as_codes(image: np.ndarray) -> np.ndarray:
    """Code values in [0, 1] (float) or uint8 -> uint8."""
    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a
    return np.round(np.clip(a.astype(np.float32), 0.0, 1.0) * 255.0).astype(np.uint8)


def _read_codes(path: Path) -> np.ndarray:
    """An image file's sRGB codes, uint8 ``(H, W, 3)``."""
    return _as_codes(read_image(path))


# --------------------------------------------------------------------------
# The picture sources
# --------------------------------------------------------------------------


class PictureSource:
    """Base of the picture sources: both eyes see the same picture, fitted into the eye size.

    ``__init__`` opens the source (:meth:`_open`, the subclass's: read the file, start the
    decoder or the grabber, set :attr:`label`), makes the eye texture and shows the picture of
    time 0; when any of it fails, whatever was made is released (:meth:`release`, which must
    cope with a source half made) and the error raised.
    """

    label = "image"

    def __init__(self, ctx: "moderngl.Context", width: int, height: int):
        self.ctx, self.size = ctx, (int(width), int(height))
        self._fitted: FittedImage | None = None
        self._shown: Hashable = None
        self.motion: MotionTracker | None = None   # when the caller wants the frames' motion (track_motion)
        self._codes: np.ndarray | None = None      # the picture shown (for track_motion)
        try:
            self._open()
            self._fitted = FittedImage(ctx, width, height)
            self._update(0.0)
        except BaseException:
            self.release()
            raise

    def _open(self) -> None:
        """Open the picture's file, decoder or grabber (nothing by default)."""

    def _update(self, t_s: float) -> None:  # pragma: no cover - overridden
        """Show the picture of time ``t_s`` (through :meth:`_show`)."""
        raise NotImplementedError

    def _show(self, key: Hashable, image_fn: Callable[[], np.ndarray]) -> None:
        """Show ``image_fn()`` (sRGB codes, uint8 or float in [0, 1]) unless the picture ``key`` is
        shown already (then ``image_fn`` is not called)."""
        if key != self._shown:
            codes = _as_codes(image_fn())
            if self.motion is not None:
                r = fit_rect(codes.shape[1], codes.shape[0], *self.size)
                self.motion.new_frame(codes, (r.width / codes.shape[1], r.height / codes.shape[0]))
            self._fitted.show(codes)
            self._shown, self._codes = key, codes

    def track_motion(self) -> None:
        """Estimate the content's motion between consecutive pictures on the CPU, before upload
        (:mod:`vrcorrect.runtime.motion`), for :meth:`take_motion`."""
        if self.motion is None:
            self.motion = MotionTracker()
            if self._codes is not None:                      # the picture shown already: the first
                self.motion.new_frame(self._codes)

    def take_motion(self) -> tuple[int, int] | str:
        """The content's motion in eye-texture pixels since the last call: ``(dx, dy)`` (x right,
        y down; ``(0, 0)`` when the picture has not changed or motion is not tracked) or ``"cut"``
        (unrelated pictures: the corrector should start cold)."""
        return (0, 0) if self.motion is None else self.motion.take()

    def render(self, t_s: float) -> tuple["moderngl.Texture", "moderngl.Texture"]:
        """The picture of time ``t_s`` for ``(left, right)``: one texture, both eyes."""
        self._update(t_s)
        texture = self._fitted.target.texture
        return texture, texture

    def release(self) -> None:
        if self._fitted is not None:
            self._fitted.release()
            self._fitted = None


class StillSource(PictureSource):
    """One image (array of sRGB code values, uint8 or float in [0, 1], or a file) for both eyes."""

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, image: np.ndarray | str | Path,
                 label: str = "image"):
        self._picture = _read_codes(Path(image)) if isinstance(image, (str, Path)) else _as_codes(image)
        self.label = label
        super().__init__(ctx, width, height)

    def _update(self, t_s: float) -> None:
        self._show(0, lambda: self._picture)


class FolderSource(PictureSource):
    """The images of a folder, in name order, each shown for ``interval_s`` seconds, looping."""

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, folder: str | Path,
                 interval_s: float = 3.0):
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise ValidationError("interval_s", interval_s, "a number of seconds > 0")
        self.files = folder_images(folder)
        self.interval_s = float(interval_s)
        self.label = f"folder {Path(folder).name} ({len(self.files)} images)"
        super().__init__(ctx, width, height)

    def _update(self, t_s: float) -> None:
        i = frame_index(t_s, 1.0 / self.interval_s, len(self.files))
        self._show(i, lambda: _read_codes(self.files[i]))
        self.index = i


class AnimatedImageSource(PictureSource):
    """An animated GIF, PNG (APNG) or WebP, played at its own frame durations, looping (decoded by
    :class:`~vrcorrect.plumbing.clips.AnimatedImage`)."""

    MAX_FRAMES = 10000

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, path: str | Path):
        self.path = Path(path)
        self._image: AnimatedImage | None = None
        super().__init__(ctx, width, height)

    def _open(self) -> None:
        self._image = AnimatedImage(self.path, self.MAX_FRAMES)
        self.durations_s = self._image.durations_s
        self.label = f"animation {self.path.name} ({self._image.count} frames)"

    @staticmethod
    def is_animated(path: str | Path) -> bool:
        """True if the image file holds more than one frame."""
        return is_animated(path)

    def _update(self, t_s: float) -> None:
        i = frame_at(t_s, self.durations_s)
        self._show(i, lambda: self._image.frame(i))
        self.index = i

    def release(self) -> None:
        super().release()
        if self._image is not None:
            self._image.close()
            self._image = None


class VideoSource(PictureSource):
    """A video file decoded by ffmpeg (:class:`~vrcorrect.plumbing.clips.VideoReader`), played in
    real time, looping.

    Frames are read in order from ffmpeg's pipe; when rendering falls behind, frames in
    between are read and skipped, so the video keeps to the clock.
    """

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, path: str | Path):
        self.path = Path(path)
        self.label = f"video {self.path.name}"
        self._reader: VideoReader | None = None
        self._passes = -1
        super().__init__(ctx, width, height)

    def _open(self) -> None:
        """Start (again) reading the video from its first frame."""
        self._close()
        self._reader = VideoReader(self.path)
        self._passes += 1
        self.frame_size = self._reader.size
        self.frames_per_s = self._reader.frames_per_s or 25.0
        self._pass_start_s: float | None = None
        self._read = -1          # index (in this pass) of the last frame read
        self._last: np.ndarray | None = None

    def _close(self) -> None:
        if self._reader is not None:
            self._reader.close()
        self._reader = None

    def _update(self, t_s: float) -> None:
        if self._pass_start_s is None:
            self._pass_start_s = t_s
        target = int(math.floor((t_s - self._pass_start_s) * self.frames_per_s + 1e-9))
        while self._read < target:
            frame = self._reader.read()
            if frame is None:  # end of the video: start again from its first frame
                if self._read < 0:
                    raise InputError(f"{self.path}: the video has no frames")
                self._open()
                self._pass_start_s = t_s
                target = 0
                continue
            self._read += 1
            self._last = frame
        key = (self._passes, self._read)
        self._show(key, lambda: self._last)

    def release(self) -> None:
        self._close()
        super().release()


# --------------------------------------------------------------------------
# The X11 screen
# --------------------------------------------------------------------------


def _mss() -> ModuleType:
    if not os.environ.get("DISPLAY"):
        raise InputError("the screen source needs an X11 display, and DISPLAY is not set "
                         "(under Wayland, only XWayland windows can be grabbed)")
    # lazy: mss opens the X display, needed only by the screen source
    return import_optional("mss", error=InputError, needed_by="the screen source")


class ScreenGrabber:
    """Grabs rectangles of the X11 screen (the root window, all monitors) with ``mss``
    (XCB ``ShmGetImage``, or ``GetImage`` where shared memory is not available).

    Raises :class:`~vrcorrect.plumbing.errors.InputError` when there is no X display (or no ``mss``).
    What is grabbed is what the X server holds: windows above the region are in it, so a
    window showing the grab must lie outside the region.
    """

    #: Seconds to wait before each further attempt to open the display. A connection refused once
    #: by a busy X server (seen under a loaded test machine) is tried again; a display that
    #: stays unreachable is reported after the last one.
    RETRY_DELAYS_S: tuple[float, ...] = (0.2, 0.5, 1.0)

    def __init__(self) -> None:
        mss = _mss()
        self._mss: Any = None                           # an mss.MSS
        errors = []
        for delay in (0.0, *self.RETRY_DELAYS_S):
            time.sleep(delay)
            try:
                self._mss = mss.MSS()
                whole = self._mss.monitors[0]
                break
            except Exception as exc:  # mss raises ScreenShotError and ctypes/XCB errors
                self.close()
                errors.append(" ".join(str(exc).split())[:200])
        else:
            tries = len(errors)
            raise InputError(f"cannot grab the X11 screen {os.environ.get('DISPLAY')!r} "
                             f"({errors[-1]}; {tries} attempts over {sum(self.RETRY_DELAYS_S):.1f} s)")
        self.bounds = Rect(0, 0, int(whole["width"]), int(whole["height"]))
        self._origin = (int(whole["left"]), int(whole["top"]))

    def grab(self, region: Rect) -> np.ndarray:
        """The pixels of ``region`` (screen pixels from the top-left of the whole screen) as
        ``(H, W, 3)`` uint8 sRGB codes, top row first."""
        region.check_inside(self.bounds.width, self.bounds.height)
        box = {"left": self._origin[0] + int(region.x), "top": self._origin[1] + int(region.y),
               "width": int(region.width), "height": int(region.height)}
        try:
            shot = self._mss.grab(box)
        except Exception as exc:
            raise InputError(f"grabbing the screen region {box} failed ({' '.join(str(exc).split())[:200]})") from None
        return np.asarray(shot)[..., 2::-1]  # BGRA -> RGB (a view; FittedImage copies it once)

    def close(self) -> None:
        if self._mss is not None:
            self._mss.close()
            self._mss = None


def screen_bounds() -> Rect:
    """The whole X11 screen (all monitors) as a rectangle at (0, 0)."""
    grabber = ScreenGrabber()
    try:
        return grabber.bounds
    finally:
        grabber.close()


class ScreenSource(PictureSource):
    """A region of the X11 screen, grabbed every frame and fitted like an image (an output of
    the region's size shows it pixel for pixel). The picture texture is made on the first
    frame and rewritten in place after that.

    Raises :class:`~vrcorrect.plumbing.errors.ValidationError` when ``region`` is not inside the screen.
    """

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, region: Rect):
        self.region = region
        self.label = f"screen {region.width}x{region.height}+{region.x}+{region.y}"
        self.grabber: ScreenGrabber | None = None
        self._frames = 0
        super().__init__(ctx, width, height)

    def _open(self) -> None:
        self.grabber = ScreenGrabber()
        b, region = self.grabber.bounds, self.region
        if region.x + region.width > b.width or region.y + region.height > b.height:
            raise ValidationError("--region", f"{region.x},{region.y},{region.width},{region.height}",
                                  f"a rectangle inside the {b.width}x{b.height} screen")

    def _update(self, t_s: float) -> None:
        self._frames += 1
        self._show(self._frames, lambda: self.grabber.grab(self.region))

    def release(self) -> None:
        if self.grabber is not None:
            self.grabber.close()
        super().release()


# --------------------------------------------------------------------------
# Opening a source; its motion for the correctors
# --------------------------------------------------------------------------


def open_picture_source(ctx: "moderngl.Context", spec: SourceSpec, width: int, height: int, *,
                        folder_interval_s: float = 3.0) -> PictureSource:
    """The picture source ``spec`` (an image, folder or video; see :func:`parse_source`) rendering
    ``width`` x ``height`` eye textures: :class:`StillSource`, :class:`AnimatedImageSource`,
    :class:`FolderSource` or :class:`VideoSource`."""
    if spec.kind == "demo":
        raise ValidationError("source", "demo", "an image, a folder of images or a video (the demo scene is "
                              "opened by vrcorrect.runtime.shell.scene.open_source)")
    if spec.kind == "folder":
        return FolderSource(ctx, width, height, spec.path, folder_interval_s)
    if spec.kind == "video":
        return VideoSource(ctx, width, height, spec.path)
    if spec.path.suffix.lower() in ANIMATED_SUFFIXES and AnimatedImageSource.is_animated(spec.path):
        return AnimatedImageSource(ctx, width, height, spec.path)
    return StillSource(ctx, width, height, spec.path, label=f"image {spec.path.name}")


def start_motion(source: PictureFeed, correctors: Iterable["Corrector"], reprojection: bool = True) -> bool:
    """Have a CPU source (one with ``track_motion``: image, folder, video, screen) estimate its
    pictures' motion when ``reprojection`` is on and a corrector runs projected gradient; returns
    whether it does.  The demo scene is rendered on the GPU and its motion (a 3D camera and objects)
    is not a global shift: it keeps the plain warm start."""
    if reprojection and any(runs_iterations(c) for c in correctors) and hasattr(source, "track_motion"):
        source.track_motion()
        return True
    return False


def take_motion(source: PictureFeed, correctors: Iterable["Corrector"]) -> tuple[int, int] | None:
    """The ``motion_px`` for this frame's ``Corrector.apply`` from ``source`` (:func:`start_motion`),
    after its ``render``; on a scene cut the projected-gradient correctors are reset (cold start)
    and ``None`` is returned."""
    take = getattr(source, "take_motion", None)
    motion = take() if take is not None else (0, 0)
    if motion == "cut":
        for c in correctors:
            if runs_iterations(c):
                c.reset()
        return None
    return motion
