"""Frames through the whole GL pipeline on a headless EGL context (``vrcorrect render``).

:func:`render_frame`: upload the image (sRGB code values), run
:class:`~vrcorrect.runtime.corrector.Corrector` (``apply``, or ``simulate`` for what the eye sees)
on ``frames`` frames of it (the iterative filters warm-start each from the last: N frames of k
iterations are N k iterations), read the last frame's framebuffer back.

:func:`render_clip`: a clip's frames through one Corrector as a headset shows them: the warm start
carried from frame to frame, moved by the content's estimated motion
(:class:`~vrcorrect.runtime.motion.MotionTracker`) and restarted cold on a scene cut; every frame
read back.

The same code path as the mirror and the headset, minus the window: for servers, tests and
benchmarks.  Layer 5 (numpy, moderngl; onnxruntime for the ONNX backend).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import time
from typing import TYPE_CHECKING, Any, Callable, Hashable, Iterable, Iterator

import numpy as np

from ...plumbing.errors import ValidationError
from ...specs.display import DisplayProfile, get_display
from ...specs.vocabulary import Backend, Eye
from ...vision.forward import check_image
from ..corrector import Corrector, runs_iterations
from ..gl import (
    check_gl_errors,
    headless_context,
    read_framebuffer,
    release,
    render_target,
    upload_texture,
    write_texture,
)
from ..motion import MotionTracker
from ..pupil_bank import codes_light_and_band
from ..rx_snapshot import RxSource

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["VIEWS", "MAX_FRAMES", "SETTLED_FRAMES", "check_frames", "render_frame", "render_clip"]

VIEWS = ("corrected", "seen-corrected", "seen-uncorrected")
MAX_FRAMES = 10_000
# ``vrcorrect render``'s default number of frames with ``filter="fista"``: a still view a tenth of a
# second after it appeared at 90 Hz, when k = 4 is within 5 % of ``fast`` (docs/benchmarks.md)
SETTLED_FRAMES = 10


def check_frames(frames: object, field: str = "frames") -> int:
    """``frames``: a whole number from 1 to :data:`MAX_FRAMES`."""
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or not 1 <= frames <= MAX_FRAMES:
        raise ValidationError(field, frames, f"a whole number of frames from 1 to {MAX_FRAMES}")
    return int(frames)


def render_frame(image: np.ndarray, rx: RxSource, display: str | os.PathLike[str] | DisplayProfile,
                 eye: str = Eye.RIGHT, backend: str = Backend.GLSL, view: str = "corrected",
                 ctx: "moderngl.Context | None" = None, frames: int = 1,
                 progress: Callable[[int, int], None] | None = None, frame_time_s: float = 1.0 / 90.0,
                 **options: Any) -> tuple[np.ndarray, dict[str, Any]]:
    """Correct (or simulate) one ``(H, W, 3)`` image of sRGB code values in [0, 1] (float) or
    uint8, ``frames`` times as a still video (the last frame is returned); returns the 8-bit result
    ``(H, W, 3)`` and what was built (``Corrector.describe()`` plus ``build_s``, ``frame_s`` (all
    frames, with the upload and the read-back), ``first_frame_s`` (the first of them, with the upload and
    the cold start and its programs' first run), ``frames`` and ``objective_fraction``: the last
    frame's objective over uncorrected where the GPU computes it (``filter="fista"`` and the
    per-frame blend), else None).  ``ctx``: an existing context (default: a new headless one);
    ``progress(done, total)`` is called after each frame.  With ``pupil="auto"`` the first design is
    for the image's own light and the pupil's dynamics run at ``frame_time_s`` a frame."""
    _check_view(view)
    frames = check_frames(frames)
    img = _codes(image, "image")
    options = _with_first_light(options, img, display)
    with _corrector_session(ctx, rx, display, eye, backend, options, frame_time_s) as (ctx, corrector, held, build_s):
        t1 = time.perf_counter()
        src = upload_texture(ctx, img)
        held.append(src)
        tex, fbo = render_target(ctx, width=img.shape[1], height=img.shape[0])
        held += [tex, fbo]
        total = frames if view != "seen-uncorrected" else 1
        first_s = None
        for done in range(1, total + 1):
            if view == "corrected":
                corrector.apply(src, fbo)
            else:
                corrector.simulate(src, fbo, corrected=view == "seen-corrected")
            if progress is not None or done == 1:
                ctx.finish()
            if done == 1:
                first_s = time.perf_counter() - t1
            if progress is not None:
                progress(done, total)
        out = read_framebuffer(fbo)
        t2 = time.perf_counter()
        check_gl_errors(ctx, "render")
        info = corrector.describe()
        fraction = corrector.last_objective_fraction((img.shape[1], img.shape[0])) \
            if view != "seen-uncorrected" and corrector.enabled else None
        info.update(build_s=build_s, frame_s=t2 - t1, first_frame_s=first_s, renderer=ctx.info.get("GL_RENDERER", "?"),
                    view=view, frames=frames, objective_fraction=fraction)
        return out, info


def _check_view(view: str) -> None:
    if view not in VIEWS:
        raise ValidationError("view", view, "one of " + ", ".join(VIEWS))


def _with_first_light(options: dict[str, Any], first_codes: np.ndarray, display: Any) -> dict[str, Any]:
    """``options`` with the first frame's mean relative luminance (``first_luminance``) where the pupil
    follows the light, and its band (``first_band``) where the band is chosen by the picture, so that
    the first design is for them."""
    if options.get("pupil") != "auto":
        return options

    profile = display if isinstance(display, DisplayProfile) else get_display(display)
    light, band = codes_light_and_band(first_codes, profile, options.get("band") == "auto")
    return {**options, "first_luminance": light, **({"first_band": band} if band is not None else {})}


@contextlib.contextmanager
def _corrector_session(ctx: "moderngl.Context | None", rx: RxSource, display: Any, eye: str, backend: str,
                       options: dict[str, Any], frame_time_s: float | None = None
                       ) -> Iterator[tuple["moderngl.Context", Corrector, list[Any], float]]:
    """``(ctx, corrector, held, build_s)``: a Corrector on ``ctx`` (default: a new headless context,
    released at the end), a list the caller adds its GL objects to (all released when the block
    ends, however it ends) and the seconds the Corrector took to build."""
    own = ctx is None
    if ctx is None:
        ctx = headless_context(require=430)
    corrector = None
    held: list[Any] = []
    try:
        t0 = time.perf_counter()
        corrector = Corrector(ctx, rx, display, eye, backend, **options)
        corrector.frame_time_s = frame_time_s
        yield ctx, corrector, held, time.perf_counter() - t0
    finally:
        if corrector is not None:
            corrector.release()
        release(*reversed(held))
        if own:
            ctx.release()


def _codes(image: np.ndarray, field: str) -> np.ndarray:
    """sRGB code values in [0, 1] (float) or uint8, checked, as uint8."""
    img = check_image(image, field, codes=True)
    if img.dtype != np.uint8:
        img = np.round(img.astype(np.float64) * 255).astype(np.uint8)
    return img


def render_clip(frames: Iterable[tuple[Hashable, np.ndarray]], rx: RxSource,
                display: str | os.PathLike[str] | DisplayProfile, eye: str = Eye.RIGHT, backend: str = Backend.GLSL,
                view: str = "corrected", ctx: "moderngl.Context | None" = None, *, reprojection: bool = True,
                emit: Callable[[int, np.ndarray], None] | None = None,
                progress: Callable[[int], None] | None = None, frame_time_s: float = 1.0 / 90.0,
                **options: Any) -> dict[str, Any]:
    """Play a clip through one :class:`~vrcorrect.runtime.corrector.Corrector` as a headset does.

    ``frames``: ``(key, image)`` per displayed frame, in order; ``image`` ``(H, W, 3)`` sRGB code
    values in [0, 1] (float) or uint8, one size for the whole clip; ``key`` names the source
    picture (a source frame shown twice in a row, as a clip played at a higher rate repeats it,
    has the same key and is not new content).  Each frame is uploaded (into one texture) and
    corrected (``view="corrected"``: ``apply``) or seen (``"seen-corrected"``,
    ``"seen-uncorrected"``: ``simulate``), then read back and handed to ``emit(index, out)``
    (uint8 ``(H, W, 3)``); ``progress(done)`` after each.

    The iterative filters carry their solution from frame to frame.  With ``reprojection`` (and a
    filter that iterates) each new picture's motion is estimated on the CPU
    (:class:`~vrcorrect.runtime.motion.MotionTracker`, as the mirror's sources do): the warm start
    is moved by it (``motion_px``), and on a scene cut the corrector is reset (a cold start).
    Without ``reprojection`` the warm start is the previous solution as it was and no cut is
    detected.

    With ``pupil="auto"`` the first design is for the first frame's light and the pupil's dynamics run
    at ``frame_time_s`` a frame (the clip's rate: ``vrcorrect render`` plays it at ``--fps``).

    Returns ``Corrector.describe()`` plus ``renderer``, ``view``, ``build_s``, ``frames``,
    ``size``, ``cuts`` (indices of the displayed frames that started cold after a detected cut),
    ``motion_tracked``, ``frame_ms`` (each frame's upload, GPU work and read-back, in ms) and
    ``objective_fractions`` (each frame's objective over uncorrected as the GPU computed it,
    read one frame late without a stall, the last one at the end; ``None`` where there is none:
    ``seen-uncorrected``, methods without a per-frame guard)."""
    _check_view(view)
    frames = iter(frames)
    first = next(frames, None)
    if first is None:
        raise ValidationError("frames", "no frames", "one or more frames")
    options = _with_first_light(options, _codes(first[1], "frames[0]"), display)
    frames = itertools.chain([first], frames)
    with _corrector_session(ctx, rx, display, eye, backend, options, frame_time_s) as (ctx, corrector, held, build_s):
        iterates = runs_iterations(corrector) and view != "seen-uncorrected"
        tracker = MotionTracker() if reprojection and iterates else None
        guarded = view != "seen-uncorrected" and corrector.enabled
        cuts: list[int] = []
        frame_ms: list[float] = []
        fractions: list[float | None] = []
        size: tuple[int, int] | None = None
        previous_key: Any = object()
        index = -1
        for index, (key, image) in enumerate(frames):
            img = _codes(image, f"frames[{index}]")
            t1 = time.perf_counter()
            if size is None:
                size = (img.shape[1], img.shape[0])
                src = upload_texture(ctx, img)
                held.append(src)
                tex, fbo = render_target(ctx, width=size[0], height=size[1])
                held += [tex, fbo]
            elif (img.shape[1], img.shape[0]) != size:
                raise ValidationError(f"frames[{index}].shape", img.shape,
                                      f"the clip's frame size, {size[1]}x{size[0]}")
            else:
                write_texture(src, img)
            motion: tuple[int, int] | None = None
            if tracker is not None and key != previous_key:
                tracker.new_frame(img)
                taken = tracker.take()
                if taken == "cut":
                    corrector.reset()
                    cuts.append(index)
                else:
                    motion = taken
            previous_key = key
            if view == "corrected":
                corrector.apply(src, fbo, motion_px=motion)
            else:
                corrector.simulate(src, fbo, corrected=view == "seen-corrected", motion_px=motion)
            out = read_framebuffer(fbo)
            frame_ms.append(1e3 * (time.perf_counter() - t1))
            if guarded and index >= 1:
                fractions[index - 1] = corrector.previous_objective_fraction(size)
            fractions.append(None)
            if emit is not None:
                emit(index, out)
            if progress is not None:
                progress(index + 1)
        if index < 0:
            raise ValidationError("frames", "no frames", "one or more frames")
        if guarded:
            fractions[-1] = corrector.last_objective_fraction(size)
        check_gl_errors(ctx, "render_clip")
        info = corrector.describe()
        info.update(renderer=ctx.info.get("GL_RENDERER", "?"), view=view, build_s=build_s,
                    frames=index + 1, size=size, cuts=cuts, motion_tracked=tracker is not None, frame_ms=frame_ms,
                    objective_fractions=fractions)
        return info
