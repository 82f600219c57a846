"""`vrcorrect correct`: the correction command as a user runs it."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps.cli import main


@pytest.fixture()
def small_png(tmp_path: Path) -> Path:
    from skimage import data, transform

    img = transform.resize(data.astronaut(), (48, 48), anti_aliasing=True)
    path = tmp_path / "in.png"
    Image.fromarray((img * 255).round().astype(np.uint8)).save(path)
    return path


def run(*args: str) -> int:
    return main(list(args))


@pytest.mark.parametrize("method", ["wiener", "fast", "paper"])
def test_correct_writes_image_and_report(tmp_path, small_png, method, capsys):
    out, rep = tmp_path / "out.png", tmp_path / "r.json"
    rc = run("correct", str(small_png), "-o", str(out), "--method", method, "--distance-m", "inf",
             "--report", str(rep))
    assert rc == 0
    assert Image.open(out).size == (48, 48)
    r = json.loads(rep.read_text())
    assert r["method"] == method and r["reference"] == "glasses"
    assert r["objective"] <= r["objective_uncorrected"] + 1e-12
    for key in ("jod", "flip", "ssim", "psnr", "objective", "flip_lms"):
        assert np.isfinite(r["metrics"][key]) and np.isfinite(r["metrics_uncorrected"][key])
    # ColorVideoVDP of what the eye sees: below 10 (the eye's blur is visible) and, for the solvers that
    # reach the optimum, above no correction.
    assert 0.0 < r["metrics_uncorrected"]["jod"] < 9.9 and r["metrics"]["jod"] <= 10.0
    if method in ("fast", "paper"):
        assert r["metrics"]["jod"] > r["metrics_uncorrected"]["jod"]
    assert r["seconds"]["solve"] >= 0 and r["iterations"] >= 0
    assert "wrote" in capsys.readouterr().out


def test_correct_sixteen_bit_and_paper_iterations(tmp_path, small_png):
    out = tmp_path / "o.png"
    assert run("correct", str(small_png), "-o", str(out), "--method", "paper", "--iterations", "5",
               "--16bit", "--reference", "ideal", "--contrast", "0.8") == 0
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    assert (width, height) == Image.open(small_png).size
    assert depth == 16 and colour == 2                       # 16 bits per sample, truecolour (RGB)
    idat, pos = b"", 8                                        # the pixels: one filter byte and 6 bytes a pixel per row
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"IDAT":
            idat += data[pos + 8:pos + 8 + length]
        pos += 12 + length
    assert len(zlib.decompress(idat)) == height * (1 + 6 * width)


@pytest.mark.parametrize("extra,field", [
    (["--method", "wiener", "--iterations", "5"], "--iterations"),
    (["--method", "paper", "--tolerance", "0.1"], "--tolerance"),
    (["--contrast", "0"], "--contrast"),
    (["--report", "r.txt"], "--report"),
])
def test_correct_bad_options_fail_fast_without_output(tmp_path, small_png, extra, field, capsys):
    out = tmp_path / "o.png"
    rc = run("correct", str(small_png), "-o", str(out), *extra)
    assert rc == 2
    err = capsys.readouterr().err
    assert field in err and "Traceback" not in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.png"]


def test_correct_never_overwrites_without_force(tmp_path, small_png, capsys):
    out = tmp_path / "o.png"
    out.write_bytes(b"mine")
    assert run("correct", str(small_png), "-o", str(out), "--method", "wiener") == 2
    assert out.read_bytes() == b"mine"
    assert "--force" in capsys.readouterr().err
    assert run("correct", str(small_png), "-o", str(out), "--method", "wiener", "--force") == 0
    assert out.read_bytes() != b"mine"
