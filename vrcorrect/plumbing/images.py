"""Image sets: the bundled evaluation images (scikit-image's photographs and the project's
charts), a folder of the user's images, and the one way every set is cropped and sized.

Used by ``vrcorrect evaluate`` and ``acuity``, the learned model's data set, and the real-time
picture sources (which list folders with :func:`image_files`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .charts import colour_bars, siemens_star, text_chart
from .errors import InputError, ValidationError
from .imageio import read_image

#: Image side lengths accepted (pixels).
SIZE_RANGE = (16, 4096)
#: File suffixes a folder of images is read for (what :func:`vrcorrect.plumbing.imageio.read_image` decodes).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".gif", ".ppm", ".pgm", ".tga")
#: The suffixes of an evaluation or training folder (``--images``): photographs, PNG or JPEG.
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg")
#: scikit-image's colour photographs used by default (those present are used).
SKIMAGE_PHOTOS = ("astronaut", "coffee", "chelsea", "rocket")


def image_files(folder: Path, suffixes: Sequence[str] = IMAGE_SUFFIXES) -> tuple[Path, ...]:
    """The files directly in ``folder`` whose suffix (any case) is one of ``suffixes``, sorted by
    name; empty when there are none (each caller says what it looked for)."""
    try:
        return tuple(sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in suffixes))
    except OSError as exc:
        raise InputError(f"{folder}: cannot list the folder ({exc.strerror or exc})") from None


def check_size(size: Any) -> int:
    lo, hi = SIZE_RANGE
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not (lo <= int(size) <= hi):
        raise ValidationError("size", size, f"an integer from {lo} to {hi} pixels")
    return int(size)


def prepare_image(image: np.ndarray, size: int, name: str = "image") -> np.ndarray:
    """Centre-crop ``image`` to a square and resize it to ``size x size`` (anti-aliased).

    Parameters
    ----------
    image
        ``(H, W, 3)`` (or ``(H, W)``, replicated) sRGB code values in [0, 1], or uint8.
    size
        Side of the result in pixels.

    Returns
    -------
    numpy.ndarray
        float32 ``(size, size, 3)`` in [0, 1].
    """
    # optional: scikit-image (the metrics and test extras)
    from skimage.transform import resize  # on use: scikit-image (heavy)
    from skimage.util import img_as_float32  # on use: scikit-image (heavy)

    size = check_size(size)
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValidationError(f"{name}.shape", a.shape, "(height, width, 3)")
    a = img_as_float32(a[..., :3]) if a.dtype.kind in "ui" else a[..., :3].astype(np.float32)
    if not np.all(np.isfinite(a)):
        raise ValidationError(name, "NaN/inf values", "finite sRGB code values in [0, 1]")
    h, w = a.shape[:2]
    side = min(h, w)
    y0, x0 = (h - side) // 2, (w - side) // 2
    a = a[y0:y0 + side, x0:x0 + side]
    if side != size:
        a = resize(a, (size, size), order=1, mode="reflect", anti_aliasing=side > size,
                   preserve_range=True)
    return np.ascontiguousarray(np.clip(a, 0.0, 1.0), dtype=np.float32)


def bundled_images(size: int = 256) -> list[tuple[str, np.ndarray]]:
    """The default evaluation images at ``size x size``: sRGB float32 ``(size, size, 3)``.

    scikit-image's colour photographs (:data:`SKIMAGE_PHOTOS`, those this
    scikit-image ships), centre-cropped and resized, then the procedural
    charts: ``text`` (:func:`vrcorrect.plumbing.charts.text_chart`), ``siemens_star``
    and ``colour_bars``.
    """
    size = check_size(size)
    images: list[tuple[str, np.ndarray]] = []
    try:
        import skimage.data as skdata  # optional: scikit-image (the metrics and test extras)
    except ImportError:  # pragma: no cover - scikit-image is a dependency
        skdata = None
    for name in SKIMAGE_PHOTOS:
        loader = getattr(skdata, name, None) if skdata is not None else None
        if loader is None:
            continue
        try:
            photo = loader()
        except Exception:  # pragma: no cover - a data file missing from this install
            continue
        images.append((name, prepare_image(photo, size, name)))
    images.append(("text", text_chart(size, size)))
    images.append(("siemens_star", siemens_star(size)))
    images.append(("colour_bars", colour_bars(size, size)))
    return images


def folder_images(folder: str | Path, size: int = 256) -> list[tuple[str, np.ndarray]]:
    """Every PNG/JPEG in ``folder`` (sorted by name), centre-cropped and resized to ``size``.

    Raises
    ------
    InputError
        The folder is missing, not a folder, or holds no PNG/JPEG image; or an
        image cannot be read.
    """
    size = check_size(size)
    folder = Path(folder)
    if not folder.exists():
        raise InputError(f"{folder}: no such folder (--images expects a folder of PNG or JPEG images)")
    if not folder.is_dir():
        raise InputError(f"{folder}: is not a folder (--images expects a folder of PNG or JPEG images)")
    files = image_files(folder, PHOTO_SUFFIXES)
    if not files:
        raise InputError(f"{folder}: no PNG or JPEG images in this folder")
    images = []
    used: set[str] = set()
    for path in files:
        name = safe_name(path.stem)
        if name in used:
            name = safe_name(f"{path.stem}_{path.suffix.lstrip('.')}")
        n = 2
        base = name
        while name in used:
            name, n = f"{base}_{n}", n + 1
        used.add(name)
        images.append((name, prepare_image(read_image(path), size, str(path))))
    return images


def safe_name(text: str) -> str:
    """A file-name-safe version of an image name (letters, digits, ``-``, ``_``, ``.``)."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._")
    return name or "image"
