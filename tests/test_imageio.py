"""Reading and writing images: exact round trips, every Pillow mode we accept,
16-bit PNGs (including filtered ones from other encoders), and safe writes."""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vrcorrect.plumbing.errors import InputError, ValidationError
from vrcorrect.plumbing.imageio import read_image, write_png

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------- helpers

def _listing(folder: Path) -> set[str]:
    return set(os.listdir(folder))


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    if pb <= pc:
        return b
    return c


def _filter_row(ftype: int, cur: bytes, prev: bytes, bpp: int) -> bytes:
    """Apply PNG filter ``ftype`` (PNG spec, section 9) to one scanline of bytes."""
    out = bytearray(len(cur))
    for x in range(len(cur)):
        a = cur[x - bpp] if x >= bpp else 0
        b = prev[x]
        c = prev[x - bpp] if x >= bpp else 0
        pred = {0: 0, 1: a, 2: b, 3: (a + b) // 2, 4: _paeth(a, b, c)}[ftype]
        out[x] = (cur[x] - pred) & 0xFF
    return bytes([ftype]) + bytes(out)


def _png16(values: np.ndarray, filters: list[int], *, idat_parts: int = 1, drop_adler: bool = False) -> bytes:
    """An independent 16-bit RGB (3 channels) or RGBA (4 channels) PNG encoder with per-row filters."""
    h, w, ch = values.shape
    ctype = {3: 2, 4: 6}[ch]
    bpp = 2 * ch
    rows = values.astype(">u2").reshape(h, w * ch).view(np.uint8)
    prev = bytes(w * bpp)
    raw = b""
    for y in range(h):
        cur = rows[y].tobytes()
        raw += _filter_row(filters[y % len(filters)], cur, prev, bpp)
        prev = cur
    data = zlib.compress(raw, 9)
    if drop_adler:
        data = data[:-4]
    step = -(-len(data) // idat_parts)
    idats = b"".join(_chunk(b"IDAT", data[i:i + step]) for i in range(0, len(data), step))
    return (PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, ctype, 0, 0, 0)) + idats
            + _chunk(b"IEND", b""))


def _known_u16(h: int, w: int, ch: int, seed: int = 7) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = rng.integers(0, 65536, size=(h, w, ch), dtype=np.uint16)
    v[0, 0] = 0           # extremes, so byte wrap-around in every predictor is exercised
    v[-1, -1] = 65535
    v[1, :] = 65535
    v[2, :] = 0
    return v


# ---------------------------------------------------------------- round trips

def test_8bit_rgb_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    codes = rng.integers(0, 256, size=(17, 23, 3), dtype=np.uint8)
    codes[0, 0] = (0, 0, 0)
    codes[0, 1] = (255, 255, 255)
    path = tmp_path / "rt8.png"
    write_png(path, codes / 255.0)
    with Image.open(path) as im:
        assert im.mode == "RGB" and im.size == (23, 17)
        np.testing.assert_array_equal(np.asarray(im), codes)
    back = read_image(path)
    assert back.dtype == np.float32 and back.shape == (17, 23, 3)
    np.testing.assert_array_equal(np.round(back * 255.0).astype(np.uint8), codes)


def test_1x1_image_round_trip(tmp_path):
    path = tmp_path / "one.png"
    write_png(path, np.array([[[1.0, 0.0, 0.5]]]))
    np.testing.assert_allclose(read_image(path), [[[1.0, 0.0, 128 / 255]]], atol=1e-6)


def test_16bit_png_round_trip_within_one_code(tmp_path):
    rng = np.random.default_rng(1)
    rgb = rng.random((19, 13, 3))
    rgb[0, 0] = (0.0, 1.0, 0.5)
    path = tmp_path / "rt16.png"
    write_png(path, rgb, bits=16)
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    width, height, depth, ctype = struct.unpack(">IIBB", data[16:26])
    assert (width, height, depth, ctype) == (13, 19, 16, 2)
    back = read_image(path)
    assert back.shape == (19, 13, 3) and back.dtype == np.float32
    # 16-bit quantisation is half a code; float32 adds a little.
    assert np.max(np.abs(back - rgb)) <= 1 / 65535
    # Finer than 8 bits could hold: the 16-bit data really is used.
    assert np.max(np.abs(back - np.round(rgb * 255) / 255)) > 1 / 1024


def test_write_clips_out_of_range_values(tmp_path):
    path = tmp_path / "clip.png"
    write_png(path, np.array([[[1.5, -0.25, 0.0]]]))
    np.testing.assert_array_equal(np.asarray(Image.open(path)), [[[255, 0, 0]]])


# ---------------------------------------------------------------- reading modes

def test_read_grey_L(tmp_path):
    codes = np.arange(0, 256, 4, dtype=np.uint8).reshape(8, 8)
    path = tmp_path / "grey.png"
    Image.fromarray(codes, mode="L").save(path)
    img = read_image(path)
    assert img.shape == (8, 8, 3) and img.dtype == np.float32
    for c in range(3):
        np.testing.assert_allclose(img[..., c], codes / 255.0, atol=1e-7)


def test_read_rgba_drops_alpha_without_premultiplying(tmp_path):
    rng = np.random.default_rng(2)
    rgba = rng.integers(0, 256, size=(6, 9, 4), dtype=np.uint8)
    rgba[..., 3] = np.linspace(0, 255, 9).astype(np.uint8)[None, :]  # includes fully transparent pixels
    path = tmp_path / "rgba.png"
    Image.fromarray(rgba, mode="RGBA").save(path)
    img = read_image(path)
    assert img.shape == (6, 9, 3)
    np.testing.assert_allclose(img, rgba[..., :3] / 255.0, atol=1e-7)


def test_read_palette_image(tmp_path):
    palette = [255, 0, 0, 0, 128, 0, 10, 20, 250, 255, 255, 255]
    index = np.array([[0, 1, 2, 3], [3, 2, 1, 0], [1, 1, 2, 2]], dtype=np.uint8)
    im = Image.fromarray(index, mode="P")
    im.putpalette(palette + [0] * (768 - len(palette)))
    path = tmp_path / "pal.png"
    im.save(path)
    with Image.open(path) as check:
        assert check.mode == "P"
    expected = np.array(palette, dtype=np.float64).reshape(-1, 3)[index] / 255.0
    img = read_image(path)
    assert img.shape == (3, 4, 3)
    np.testing.assert_allclose(img, expected, atol=1e-7)


def test_read_16bit_grey(tmp_path):
    codes = np.array([[0, 1, 255, 256], [1000, 32768, 65534, 65535]], dtype=np.uint16)
    path = tmp_path / "grey16.png"
    Image.fromarray(codes).save(path)
    with Image.open(path) as check:
        assert check.mode.startswith("I")
    img = read_image(path)
    assert img.shape == (2, 4, 3)
    assert img.min() >= 0.0 and img.max() <= 1.0
    for c in range(3):
        np.testing.assert_allclose(img[..., c], codes / 65535.0, rtol=0, atol=1e-7)


def test_read_dark_16bit_grey_is_not_mistaken_for_8bit(tmp_path):
    """A 16-bit grey image whose codes all happen to be <= 255 is still 16-bit."""
    codes = np.array([[0, 10], [100, 255]], dtype=np.uint16)
    path = tmp_path / "dark16.png"
    Image.fromarray(codes).save(path)
    img = read_image(path)
    np.testing.assert_allclose(img[..., 0], codes / 65535.0, atol=1e-7)


def test_read_jpeg(tmp_path):
    colour = np.array([200, 60, 30], dtype=np.uint8)
    path = tmp_path / "photo.jpg"
    Image.fromarray(np.broadcast_to(colour, (16, 24, 3)).copy(), mode="RGB").save(path, quality=95)
    img = read_image(path)
    assert img.shape == (16, 24, 3) and img.dtype == np.float32
    assert img.min() >= 0.0 and img.max() <= 1.0
    np.testing.assert_allclose(img.reshape(-1, 3).mean(axis=0), colour / 255.0, atol=4 / 255)


# ---------------------------------------------------------------- 16-bit PNGs from other encoders

@pytest.mark.parametrize("ftype", [0, 1, 2, 3, 4])
def test_16bit_rgb_png_with_one_filter_type(tmp_path, ftype):
    values = _known_u16(5, 6, 3, seed=ftype)
    path = tmp_path / f"f{ftype}.png"
    path.write_bytes(_png16(values, [ftype]))
    img = read_image(path)
    np.testing.assert_array_equal(np.round(img.astype(np.float64) * 65535).astype(np.uint16), values)


def test_16bit_rgb_png_with_mixed_filters_and_split_idat(tmp_path):
    """Filters 1, 2, 3, 4 (and 0) on different rows, first row Paeth, data over 3 IDAT chunks."""
    values = _known_u16(10, 7, 3)
    path = tmp_path / "mixed.png"
    path.write_bytes(_png16(values, [4, 1, 2, 3, 4, 0, 3, 2, 1, 4], idat_parts=3))
    with Image.open(path) as check:  # another decoder agrees on the high bytes
        np.testing.assert_array_equal(np.asarray(check.convert("RGB")), (values >> 8).astype(np.uint8))
    img = read_image(path)
    assert img.shape == (10, 7, 3)
    np.testing.assert_allclose(img, values / 65535.0, rtol=0, atol=1e-7)


def test_16bit_rgba_png_with_filters_drops_alpha(tmp_path):
    values = _known_u16(6, 5, 4, seed=3)
    path = tmp_path / "rgba16.png"
    path.write_bytes(_png16(values, [1, 2, 3, 4, 3, 1]))
    img = read_image(path)
    assert img.shape == (6, 5, 3)
    np.testing.assert_allclose(img, values[..., :3] / 65535.0, rtol=0, atol=1e-7)


def test_16bit_png_without_zlib_checksum_reads_like_pillow(tmp_path):
    """Pillow accepts a zlib stream missing its Adler-32 trailer; so must the 16-bit decoder."""
    values = _known_u16(4, 4, 3, seed=9)
    path = tmp_path / "noadler.png"
    path.write_bytes(_png16(values, [1, 4, 2, 3], drop_adler=True))
    img = read_image(path)
    np.testing.assert_allclose(img, values / 65535.0, rtol=0, atol=1e-7)


# ---------------------------------------------------------------- bad input files

def test_read_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_image(tmp_path / "nope.png")


def test_read_directory(tmp_path):
    with pytest.raises(InputError, match="directory"):
        read_image(tmp_path)


def test_read_text_file_named_png(tmp_path):
    path = tmp_path / "text.png"
    path.write_text("this is not an image\n")
    with pytest.raises(InputError, match="text.png"):
        read_image(path)


@pytest.mark.parametrize("keep", [0.3, 0.6, 0.9])
def test_read_truncated_png(tmp_path, keep):
    good = tmp_path / "good.png"
    rng = np.random.default_rng(4)
    write_png(good, rng.random((32, 32, 3)))
    data = good.read_bytes()
    bad = tmp_path / "cut.png"
    bad.write_bytes(data[:int(len(data) * keep)])
    with pytest.raises(InputError, match="cut.png"):
        read_image(bad)


def test_read_truncated_16bit_png(tmp_path):
    good = tmp_path / "good16.png"
    write_png(good, np.random.default_rng(5).random((32, 32, 3)), bits=16)
    data = good.read_bytes()
    bad = tmp_path / "cut16.png"
    bad.write_bytes(data[:len(data) // 2])
    with pytest.raises(InputError, match="cut16.png"):
        read_image(bad)


# ---------------------------------------------------------------- refusing bad writes

@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_write_refuses_non_finite(tmp_path, bad):
    rgb = np.full((4, 4, 3), 0.5)
    rgb[2, 1, 0] = bad
    with pytest.raises(ValidationError, match="NaN"):
        write_png(tmp_path / "nan.png", rgb)
    assert _listing(tmp_path) == set()


@pytest.mark.parametrize("name", ["out.jpg", "out", "out.png.tmp"])
def test_write_refuses_non_png_path(tmp_path, name):
    with pytest.raises(ValidationError, match=r"\.png"):
        write_png(tmp_path / name, np.zeros((2, 2, 3)))
    assert _listing(tmp_path) == set()


@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (4, 4, 1)])
def test_write_refuses_wrong_shape(tmp_path, shape):
    with pytest.raises(ValidationError, match="shape"):
        write_png(tmp_path / "s.png", np.zeros(shape))
    assert _listing(tmp_path) == set()


def test_write_refuses_bad_bit_depth(tmp_path):
    with pytest.raises(ValidationError, match="bits"):
        write_png(tmp_path / "b.png", np.zeros((2, 2, 3)), bits=12)
    assert _listing(tmp_path) == set()


def test_write_never_overwrites_without_force(tmp_path):
    path = tmp_path / "mine.png"
    path.write_bytes(b"the user's file")
    for bits in (8, 16):
        with pytest.raises(InputError, match="--force"):
            write_png(path, np.ones((3, 3, 3)), bits=bits)
        assert path.read_bytes() == b"the user's file"
    assert _listing(tmp_path) == {"mine.png"}  # no temporary files left behind
    write_png(path, np.ones((3, 3, 3)), force=True)
    np.testing.assert_array_equal(read_image(path), np.ones((3, 3, 3), dtype=np.float32))
    assert _listing(tmp_path) == {"mine.png"}


def test_write_into_missing_folder(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        write_png(tmp_path / "missing" / "x.png", np.zeros((2, 2, 3)))
    assert _listing(tmp_path) == set()


def test_failed_write_leaves_original_and_no_partial_file(tmp_path, monkeypatch):
    """An encoder that dies half way must not touch the existing file (even with force)."""
    path = tmp_path / "keep.png"
    write_png(path, np.zeros((4, 4, 3)))
    original = path.read_bytes()

    def broken_save(self, fp, *args, **kwargs):
        Path(fp).write_bytes(b"\x89PNG partial")
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        write_png(path, np.ones((4, 4, 3)), force=True)
    assert path.read_bytes() == original
    assert _listing(tmp_path) == {"keep.png"}
    with pytest.raises(OSError, match="disk full"):
        write_png(tmp_path / "new.png", np.ones((4, 4, 3)))
    assert _listing(tmp_path) == {"keep.png"}


def test_written_file_gets_ordinary_permissions(tmp_path):
    """Outputs are created like any file (0666 minus the umask), not private 0600 temp files."""
    old = os.umask(0o022)
    try:
        path = tmp_path / "perm.png"
        write_png(path, np.zeros((2, 2, 3)))
        assert path.stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(old)
