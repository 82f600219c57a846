"""The motion suite's clips: about a second at 90 Hz of what a headset shows, made from the bundled
photographs, Pillow's default font and the mirror's 3D demo scene.

* ``still`` - a photograph held still;
* ``sprite`` - a small picture sliding 2 px a frame over it;
* ``text`` - a page of text scrolling up 2 px a frame;
* ``cut`` - a pan of 2 px a frame across one photograph, cut half-way to a pan across another;
* ``zoom`` - the photograph's centre zooming in (not a shift);
* ``head turn`` - the demo scene seen by the right eye while the head turns 0.5 degrees a frame
  (45 degrees a second; the cube spins and the banner scrolls as well).

:func:`suite` makes the tuning set; :func:`held_out` makes other clips of the first three kinds
from pictures and text the project never tuned on (scikit-image's rocket, colour wheel and
immunohistochemistry; other words at another size), for the issue's done-when check through
``vrcorrect render``.  Frames are 8-bit sRGB ``(H, W, 3)``.  Layer 6.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...plumbing.images import prepare_image
from ...specs.vocabulary import VIEW_ORDER, Eye

__all__ = ["SEQUENCES", "HELD_OUT", "BenchClip", "photo", "suite", "held_out", "text_page", "dark_text_page", "save_clip"]

SEQUENCES = ("still", "sprite", "text", "cut", "zoom", "head turn")
HELD_OUT = ("sprite", "text", "cut")
STEP_PX = 2                                  # sprite, text and pan speed, px a frame
TURN_DEG = 0.5                               # head turn a frame (45 deg/s at 90 Hz)
WORDS = ("the quick brown fox jumps over the lazy dog while vision blurs and the display corrects "
         "sharp letters for every eye").split()
HELD_OUT_WORDS = ("pack my box with five dozen liquor jugs then sphinx of black quartz judge my vow as "
                  "waves of light reach the retina").split()


@dataclass
class BenchClip:
    """One sequence: its frames and where it cuts (the first frame of the new shot, or ``None``)."""

    name: str
    frames: list[np.ndarray]
    cut_at: int | None = None
    what: str = ""
    notes: dict[str, Any] = field(default_factory=dict)


def photo(name: str, side: int) -> np.ndarray:
    """scikit-image's photograph ``name``, centre-cropped square and resized to ``side``, 8-bit."""
    from skimage import data  # optional: scikit-image (bundled photographs)

    image = prepare_image(getattr(data, name)()[..., :3], side, name)
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


def text_page(width: int, height: int, words: tuple[str, ...] | list[str] = WORDS, font_px: int = 14,
              ink: tuple[int, int, int] = (20, 20, 30), paper: tuple[int, int, int] = (245, 245, 240)) -> np.ndarray:
    """A page of dark text on light paper, ``height`` x ``width`` 8-bit RGB (Pillow's default font)."""
    from PIL import Image, ImageDraw  # on use: Pillow (start-up time)

    from ...runtime.shell.text import (
        default_font,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    img = Image.new("RGB", (width, height), paper)
    draw, font = ImageDraw.Draw(img), default_font(font_px)
    y, i, line_px = 4, 0, int(round(1.3 * font_px))
    while y < height - font_px:
        draw.text((6, y), " ".join(words[(i + j) % len(words)] for j in range(8)), fill=ink, font=font)
        y += line_px
        i += 5
    return np.asarray(img)


def _pan(image: np.ndarray, size: int, frames: int, top: int) -> list[np.ndarray]:
    return [image[top:top + size, STEP_PX * f:STEP_PX * f + size] for f in range(frames)]


def _sprite(background: np.ndarray, sprite: np.ndarray, size: int, frames: int) -> list[np.ndarray]:
    s = sprite.shape[0]
    out = []
    for f in range(frames):
        im = background.copy()
        x = min(8 + STEP_PX * f, size - s)
        y = (size - s) // 2
        im[y:y + s, x:x + s] = sprite
        out.append(im)
    return out


def _zoom(image: np.ndarray, size: int, frames: int) -> list[np.ndarray]:
    from skimage.transform import resize  # optional: scikit-image

    n = image.shape[0]
    out = []
    for f in range(frames):
        side = int(round(n - (n - size) * f / max(frames - 1, 1)))
        o = (n - side) // 2
        crop = image[o:o + side, o:o + side].astype(np.float32) / 255
        if side != size:
            crop = resize(crop, (size, size, 3), order=1, anti_aliasing=True)
        out.append(np.round(np.clip(crop, 0, 1) * 255).astype(np.uint8))
    return out


def head_turn(ctx: Any, size: int, frames: int, deg_per_frame: float = TURN_DEG,
              frame_s: float = 1 / 90) -> list[np.ndarray]:
    """The mirror's demo scene seen by the right eye while the head turns left ``deg_per_frame``
    degrees a frame (rendered on ``ctx``)."""
    from ...runtime.gl import (
        download_texture,  # on use: start-up time (the CLI imports the studies to build its parser)
    )
    from ...runtime.shell.scene import (  # on use: start-up time (the CLI imports the studies to build its parser)
        DemoScene,
        SceneConfig,
        eye_position,
        perspective,
        rotation_y,
        translation,
    )

    config = SceneConfig()
    projection = perspective(config.fov_y_deg, 1.0, 0.05, 60.0)
    camera = eye_position(Eye.RIGHT, config)
    scene = DemoScene(ctx, size, size, config)
    images = []
    try:
        for f in range(frames):
            view = np.linalg.inv(translation(*camera) @ rotation_y(math.radians(deg_per_frame * f)))
            texture = scene.render(f * frame_s, views={eye: (projection @ view, camera) for eye in VIEW_ORDER})[1]
            images.append(np.ascontiguousarray(download_texture(texture)[..., :3]))
    finally:
        scene.release()
    return images


def suite(size: int = 256, frames: int = 90, ctx: Any = None, names: tuple[str, ...] = SEQUENCES) -> list[BenchClip]:
    """The motion suite (module docstring); ``ctx``: a GL context for the head turn (without one it
    is left out)."""
    pad = STEP_PX * frames
    base = photo("astronaut", size + pad)
    top = pad // 2
    clips = []
    for name in names:
        if name == "still":
            still = base[top:top + size, top:top + size]
            clips.append(BenchClip(name, [still] * frames, what="a photograph held still"))
        elif name == "sprite":
            clips.append(BenchClip(name, _sprite(base[top:top + size, top:top + size], photo("chelsea", max(16, size // 4)), size,
                                            frames), what=f"a picture sliding {STEP_PX} px a frame over a photograph"))
        elif name == "text":
            page = text_page(size, size + pad)
            clips.append(BenchClip(name, [page[STEP_PX * f:STEP_PX * f + size] for f in range(frames)],
                              what=f"text scrolling {STEP_PX} px a frame"))
        elif name == "cut":
            half = frames // 2
            other = photo("coffee", size + pad)
            clips.append(BenchClip(name, _pan(base, size, half, top) + _pan(other, size, frames - half, top), cut_at=half,
                              what=f"a pan of {STEP_PX} px a frame, cut half-way to another"))
        elif name == "zoom":
            clips.append(BenchClip(name, _zoom(base, size, frames), what="zooming into the photograph's centre"))
        elif name == "head turn" and ctx is not None:
            clips.append(BenchClip(name, head_turn(ctx, size, frames),
                              what=f"the demo scene, the head turning {TURN_DEG:g} deg a frame"))
    return clips


def dark_text_page(width: int, height: int) -> np.ndarray:
    """The held-out words as light text on dark blue, 18 px (the held-out text clip's page; ``bench
    robust``'s dark-mode still is its top)."""
    return text_page(width, height, HELD_OUT_WORDS, font_px=18, ink=(240, 240, 235), paper=(30, 40, 70))


def held_out(size: int = 256, frames: int = 90) -> list[BenchClip]:
    """Clips of the sprite, text and cut kinds from pictures and words the project never tuned on."""
    pad = STEP_PX * frames
    rocket = photo("rocket", size + pad)
    top = pad // 2
    half = frames // 2
    page = dark_text_page(size, size + pad)
    return [
        BenchClip("sprite", _sprite(rocket[top:top + size, top:top + size], photo("colorwheel", max(16, size // 4)), size, frames),
             what="a colour wheel sliding over the rocket"),
        BenchClip("text", [page[STEP_PX * f:STEP_PX * f + size] for f in range(frames)],
             what="light text on dark blue, 18 px, scrolling"),
        BenchClip("cut", _pan(rocket, size, half, top) + _pan(photo("immunohistochemistry", size + pad), size, frames - half,
                                                          top), cut_at=half, what="a pan across the rocket, cut to a slide"),
    ]


def save_clip(clip: BenchClip, folder: Any) -> None:
    """Write ``clip``'s frames as ``frame_00000.png``... into ``folder`` (made)."""

    from PIL import Image  # on use: Pillow (start-up time)

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(clip.frames):
        Image.fromarray(frame).save(folder / f"frame_{i:05d}.png")
