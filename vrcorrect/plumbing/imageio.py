"""Reading and writing images (code values in [0, 1]; no colour transform here).

8-bit images of any Pillow mode and 16-bit PNGs are read as float32 RGB;
alpha is dropped, grey is replicated.  PNGs are written 8- or 16-bit, atomically.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Callable

import numpy as np
from PIL import Image, UnidentifiedImageError

from .errors import InputError, ValidationError
from .fileio import write_with

#: Largest image accepted (pixels), to refuse decompression bombs with a clear message.
MAX_PIXELS = 8192 * 8192


def read_image(path: str | Path, notes: list[str] | None = None) -> np.ndarray:
    """Read an image file as float32 ``(H, W, 3)`` code values in [0, 1].

    ``notes``: when given, what was done silently before is said there: an animated image's first
    frame is used, an alpha channel is dropped (the colour values are used as stored, not
    composited over anything)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected an image file")
    Image.MAX_IMAGE_PIXELS = MAX_PIXELS
    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            frames = int(getattr(im, "n_frames", 1) or 1)
            if notes is not None and frames > 1:
                notes.append(f"{path.name} is animated ({frames} frames): its first frame is used (for moving "
                             "pictures use vrcorrect mirror, overlay or xr --source)")
            if notes is not None and (mode in ("RGBA", "LA", "PA") or "transparency" in im.info):
                notes.append(f"{path.name} has transparency: it is dropped, the colours are used as stored "
                             "(not composited over a background)")
            if mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float64)
                scale = 65535.0 if mode.startswith("I;16") or a.max() > 255 else 255.0
                grey = (a / scale).astype(np.float32)
                return np.repeat(grey[..., None], 3, axis=2)
            if mode == "F":
                raise InputError(f"{path}: floating-point images are not supported; use 8- or 16-bit PNG")
            rgb = im.convert("RGB")
            bits16 = _png_rgb16(path) if path.suffix.lower() == ".png" and mode in ("RGB", "RGBA") else None
            if bits16 is not None:
                return bits16
            return np.asarray(rgb, dtype=np.float32) / 255.0
    except InputError:
        raise
    except UnidentifiedImageError:
        raise InputError(f"{path}: not an image file Pillow can read") from None
    except Image.DecompressionBombError:
        raise InputError(f"{path}: image larger than {MAX_PIXELS} pixels") from None
    except (OSError, ValueError, SyntaxError, zlib.error) as exc:
        raise InputError(f"{path}: cannot read image ({exc})") from None


def _png_rgb16(path: Path) -> np.ndarray | None:
    """Decode a 16-bit RGB(A) PNG (Pillow reduces those to 8 bits); None otherwise."""
    data = path.read_bytes()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    pos = 8
    width = height = depth = ctype = None
    idat = []
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if depth != 16 or ctype not in (2, 6) or interlace:
                return None
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    channels = 3 if ctype == 2 else 4
    # Tolerate a stream without its final checksum, as Pillow does.
    raw = zlib.decompressobj().decompress(b"".join(idat))
    stride = width * channels * 2
    bpp = channels * 2
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(height, stride + 1)
    out = np.zeros((height, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(height):
        ftype = rows[y, 0]
        line = rows[y, 1:].astype(np.int32)
        if ftype == 0:
            cur = line
        elif ftype == 2:
            cur = (line + prev) & 0xFF
        elif ftype == 1:  # Sub: running sum along each byte lane
            lanes = line.reshape(-1, bpp)
            cur = (np.cumsum(lanes, axis=0) & 0xFF).reshape(-1)
        else:  # Average and Paeth depend on the previous output byte: sequential
            cur = np.zeros(stride, dtype=np.int32)
            for x in range(stride):
                a = cur[x - bpp] if x >= bpp else 0
                b = prev[x]
                c = prev[x - bpp] if x >= bpp else 0
                if ftype == 3:
                    pred = (a + b) // 2
                else:  # Paeth
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    pred = a if (pa <= pb and pa <= pc) else (b if pb <= pc else c)
                cur[x] = (line[x] + pred) & 0xFF
        out[y] = cur
        prev = cur
    values = out.view(">u2").reshape(height, width, channels)[..., :3]
    return (values.astype(np.float32) / 65535.0)


def _png16_bytes(rgb: np.ndarray) -> bytes:
    h, w, _ = rgb.shape
    values = np.round(np.clip(rgb, 0.0, 1.0) * 65535.0).astype(">u2")
    raw = np.zeros((h, 1 + w * 6), dtype=np.uint8)
    raw[:, 1:] = values.reshape(h, w * 3).view(np.uint8)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6)) + chunk(b"IEND", b""))


def png_writer(path: str | Path, rgb: np.ndarray, bits: int = 8) -> Callable[[Path], None]:
    """Check ``(H, W, 3)`` code values in [0, 1] for an 8- or 16-bit PNG at ``path`` and return the
    function that writes them to a given (temporary) path: for outputs written together
    (:func:`vrcorrect.plumbing.fileio.atomic_paths`)."""
    if bits not in (8, 16):
        raise ValidationError("bits", bits, "8 or 16")
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValidationError("image.shape", a.shape, "(height, width, 3)")
    if not np.all(np.isfinite(a)):
        raise ValidationError("image", "NaN/inf values", "finite values in [0, 1]")
    if Path(path).suffix.lower() != ".png":
        raise ValidationError("output", str(path), "a path ending in .png")

    def writer(tmp: Path) -> None:
        if bits == 16:
            tmp.write_bytes(_png16_bytes(a))
        else:
            img8 = np.round(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)
            Image.fromarray(img8, mode="RGB").save(tmp, format="PNG")

    return writer


def write_png(path: str | Path, rgb: np.ndarray, bits: int = 8, force: bool = False) -> None:
    """Write ``(H, W, 3)`` code values in [0, 1] as an 8- or 16-bit PNG, atomically.

    Never overwrites an existing file unless ``force``.
    """
    write_with(Path(path), png_writer(path, rgb, bits), force=force)
