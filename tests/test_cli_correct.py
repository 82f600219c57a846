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


def _sphere_alone_rx(tmp_path: Path, age: float | None = 40, **eye_fields) -> Path:
    """A -1.00 D eye of sphere alone, 40 years old: 0.67 D from focus at the desktop's 0.6 m, which an
    eye of 40 (6.5 D of accommodation expected) focuses away; ``eye_fields`` added to each eye."""
    eye = {"sphere_D": -1.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0, **eye_fields}
    rx = tmp_path / "rx.json"
    doc = {"schema": "vrcorrect.prescription/1", "right": eye, "left": eye}
    rx.write_text(json.dumps(doc if age is None else {**doc, "age_years": age}))
    return rx


def test_an_eye_that_focuses_on_the_display_gets_the_picture_as_it_is_and_says_why(tmp_path, small_png, capsys):
    """The eye's amplitude from its age (none stated) takes the desktop into focus: the output is the
    input to the code value, the command says there is nothing to correct and where the amplitude came
    from, and gives no note about eyes of sphere alone.  Stated as 0 (a presbyope), the same eye is
    corrected and the note is given."""
    out = tmp_path / "out.png"
    assert run("correct", str(small_png), "-o", str(out), "--rx", str(_sphere_alone_rx(tmp_path)),
               "--display", "desktop") == 0
    said = capsys.readouterr()
    assert np.array_equal(np.asarray(Image.open(out)), np.asarray(Image.open(small_png)))
    assert "the picture as it is" in said.out and "nothing to correct" in said.out
    assert "6.50 D, the amplitude expected at age 40" in said.err and "eye of sphere alone" not in said.err
    assert "accommodative_lag_D" in said.err                       # the lag it may have, and how to state it
    presbyope = tmp_path / "presbyope"
    presbyope.mkdir()
    corrected = tmp_path / "corrected.png"
    assert run("correct", str(small_png), "-o", str(corrected), "--display", "desktop",
               "--rx", str(_sphere_alone_rx(presbyope, accommodation_D=0.0))) == 0
    said = capsys.readouterr()
    assert not np.array_equal(np.asarray(Image.open(corrected)), np.asarray(Image.open(small_png)))
    assert "nothing to correct" not in said.out and "eye of sphere alone" in said.err
    assert "amplitude expected" not in said.err and "cannot focus" not in said.err      # stated, with an age
    unknown = tmp_path / "unknown"                                 # no age and no amplitude: modelled as 0, and said
    unknown.mkdir()
    assert run("correct", str(small_png), "-o", str(unknown / "out.png"), "--display", "desktop",
               "--rx", str(_sphere_alone_rx(unknown, age=None))) == 0
    said = capsys.readouterr()
    assert "eye of sphere alone" in said.err and "modelled as one that cannot focus" in said.err
    assert "give the prescription's age_years" in said.err


def test_an_eye_that_focuses_with_a_lag_is_corrected_for_what_it_leaves_out_of_focus(tmp_path, small_png, capsys):
    """The eye above, in focus at the desktop without a lag, with 1.50 D of lag at 40 cm: it focuses
    0.4 of the 0.67 D asked and is left +0.27 D from focus, so it is corrected, and what it sees is
    judged better than none; the report's eye states the lag."""
    out, report = tmp_path / "out.png", tmp_path / "r.json"
    assert run("correct", str(small_png), "-o", str(out), "--display", "desktop", "--report", str(report),
               "--rx", str(_sphere_alone_rx(tmp_path, accommodative_lag_D=1.5))) == 0
    said = capsys.readouterr()
    assert "nothing to correct" not in said.out
    assert not np.array_equal(np.asarray(Image.open(out)), np.asarray(Image.open(small_png)))
    r = json.loads(report.read_text())
    assert r["objective"] < r["objective_uncorrected"]
    assert "accommodative_lag_D" not in said.err                   # stated: no note asking for it


def test_render_says_an_eye_in_focus_has_nothing_to_correct_and_a_lagging_one_is_corrected(tmp_path, small_png, capsys):
    """``render`` on llvmpipe: the eye of 40 in focus at the desktop is shown as it is, and the summary
    says so (no solver line, no note on the image's size against a kernel it does not use); with a
    lag stated, the summary names the eye's focus and the frames are corrected."""
    out = tmp_path / "out.png"
    assert run("render", str(small_png), "-o", str(out), "--frames", "2", "--display", "desktop",
               "--rx", str(_sphere_alone_rx(tmp_path))) == 0
    said = capsys.readouterr().out
    assert "the picture as it is, nothing to correct)" in said and "iteration(s) per frame" not in said
    assert "accommodation 6.50 D on desktop" in said
    assert np.abs(np.asarray(Image.open(out), dtype=int) - np.asarray(Image.open(small_png), dtype=int)).max() <= 1
    lagging = tmp_path / "lagging"
    lagging.mkdir()
    assert run("render", str(small_png), "-o", str(lagging / "out.png"), "--frames", "2", "--display", "desktop",
               "--rx", str(_sphere_alone_rx(lagging, accommodative_lag_D=1.5))) == 0
    said = capsys.readouterr().out
    assert "accommodation 6.50 D, lag 1.50 D at 40 cm on desktop" in said and "nothing to correct" not in said
    assert "iteration(s) per frame" in said


def test_a_clip_for_an_eye_in_focus_is_shown_as_it_is_frame_by_frame(tmp_path, small_png, capsys):
    source = np.asarray(Image.open(small_png))
    clip = tmp_path / "clip"
    clip.mkdir()
    for i in range(2):
        Image.fromarray(np.roll(source, 2 * i, axis=1)).save(clip / f"shot{i + 1}.png")
    out, report = tmp_path / "shown", tmp_path / "r.json"
    assert run("correct", str(clip), "-o", str(out), "--rx", str(_sphere_alone_rx(tmp_path)), "--display", "desktop",
               "--report", str(report)) == 0
    said = capsys.readouterr()
    assert "2 of 2 frames shown as they are" in said.out and "eye of sphere alone" not in said.err
    for i in range(2):
        assert np.array_equal(np.asarray(Image.open(out / f"frame_{i:05d}.png")),
                              np.asarray(Image.open(clip / f"shot{i + 1}.png")))
    assert all(f["nothing_to_correct"] and f["iterations"] == 0 for f in json.loads(report.read_text())["frames"])
