"""The command line, per the product's rules: bad input exits non-zero with one
clear line, never a traceback, and never writes a partial output file; never
overwrites a user's file without --force.

Most commands run in-process through ``vrcorrect.apps.cli.main``; a few run the
real console script to prove what a user's shell sees.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps import cli
from vrcorrect.studies.bench import machine_description
from vrcorrect.studies.bench.kernel import HEADSETS
from vrcorrect.specs.display import get_display, preset_names
from vrcorrect.specs.prescription import template_text

CONSOLE_SCRIPT = Path(sys.executable).parent / "vrcorrect"


# ---------------------------------------------------------------- helpers

def run(capsys, *argv: str) -> tuple[int, str, str]:
    """``vrcorrect ARGV`` in-process: (exit status, stdout, stderr)."""
    try:
        rc = cli.main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        rc = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return rc, out, err


def run_quiet(*argv: str) -> tuple[int, str, str]:
    """Like :func:`run` for module-scoped fixtures (no capsys there)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def write_colour_png(path: Path, height: int = 32, width: int = 40, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    codes = rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)
    Image.fromarray(codes, mode="RGB").save(path)
    return path


def write_grey_png(path: Path, size: int = 32, level: int = 128) -> Path:
    Image.fromarray(np.full((size, size, 3), level, dtype=np.uint8), mode="RGB").save(path)
    return path


def listing(folder: Path) -> set[str]:
    return set(os.listdir(folder))


def assert_clean_failure(rc: int, out: str, err: str, folder: Path, before: set[str], *,
                         contains: tuple[str, ...] = (), lines: int = 1) -> None:
    """Non-zero exit, a short message on stderr, no traceback, nothing new in ``folder``."""
    assert rc != 0
    assert "Traceback" not in err and "Traceback" not in out
    text = err.strip()
    assert text.startswith("vrcorrect: error:"), err
    assert len(text.splitlines()) == lines, err
    for phrase in contains:
        assert phrase in text, f"{phrase!r} not in {text!r}"
    assert "internal error" not in text
    assert listing(folder) == before  # no output, no .OUT.png.* temporary files


def strip_comment_lines(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//"))


def write_rx(path: Path, right: dict, left: dict | None = None) -> Path:
    doc = {"schema": "vrcorrect.prescription/1", "right": right, "left": left or right}
    path.write_text(json.dumps(doc, indent=2))
    return path


EMMETROPE = {"sphere_D": 0.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0}


# ---------------------------------------------------------------- simulate: success

@pytest.fixture(scope="module")
def colour_run(tmp_path_factory):
    """One out-of-focus simulation of a colour image with --explain (one kernel build)."""
    folder = tmp_path_factory.mktemp("simulate")
    src = write_colour_png(folder / "in.png")
    dst = folder / "out.png"
    rc, out, err = run_quiet("simulate", src, "-o", dst, "--explain")
    return rc, out, err, src, dst


def test_simulate_writes_png_of_same_size(colour_run):
    rc, out, err, src, dst = colour_run
    assert rc == 0, err
    assert "Traceback" not in err
    with Image.open(dst) as im:
        assert im.format == "PNG" and im.mode == "RGB"
        assert im.size == Image.open(src).size == (40, 32)
        seen = np.asarray(im, dtype=np.float64)
    shown = np.asarray(Image.open(src), dtype=np.float64)
    # The sample eyes are myopic: the random pattern is blurred, so neighbouring pixels differ less.
    assert np.abs(np.diff(seen, axis=1)).mean() < 0.5 * np.abs(np.diff(shown, axis=1)).mean()
    assert f"wrote {dst}" in out
    assert sorted(listing(dst.parent)) == ["in.png", "out.png"]


def test_simulate_convolution_chooses_the_path_and_its_old_name_still_works(colour_run, tmp_path, capsys):
    """``--convolution`` (``--method`` before: it read like correct's solver choice) picks the blur's
    path, which --explain names; the FFT and direct paths agree to a code value; the old flag still
    works but is no longer offered in --help."""
    src = colour_run[3]
    seen = {}
    for path in ("fft", "direct"):
        dst = tmp_path / f"{path}.png"
        rc, out, err = run_quiet("simulate", src, "-o", dst, "--convolution", path, "--explain")
        assert rc == 0, err
        assert f"forward model: {path} path" in out
        seen[path] = np.asarray(Image.open(dst), dtype=int)
    assert np.abs(seen["fft"] - seen["direct"]).max() <= 1
    rc, out, err = run_quiet("simulate", src, "-o", tmp_path / "old.png", "--method", "direct", "--explain")
    assert rc == 0 and "forward model: direct path" in out
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--help"])
    text = capsys.readouterr().out
    assert "--convolution {auto,fft,direct}" in text and "--method" not in text


def test_simulate_explain_prints_the_decisions(colour_run):
    rc, out, _, _, _ = colour_run
    assert rc == 0
    assert "sphere -3.00 D, cylinder -1.50 D, axis 20 deg" in out      # bundled sample, right eye
    assert "quest2 (Meta Quest 2)" in out
    assert "convolution needed" in out
    assert re.search(r"wavelength step \d+ nm \(\d+ PSFs over", out)
    size = re.search(r"kernel (\d+)x(\d+) px holds", out)
    assert size and size.group(1) == size.group(2) and int(size.group(1)) % 2 == 1 and int(size.group(1)) > 1
    assert re.search(r"forward model: (fft|direct) path, colour image, 9 convolution\(s\) of 40x32 px", out)
    assert "pupil sampling" in out
    assert "identity path" not in out


def test_simulate_grey_image_takes_achromatic_shortcut(tmp_path, capsys):
    src = write_grey_png(tmp_path / "grey.png", level=128)
    dst = tmp_path / "seen.png"
    rc, out, err = run(capsys, "simulate", src, "-o", dst, "--explain")
    assert rc == 0, err
    assert "grey image: exact achromatic shortcut, 3 convolution(s)" in out
    seen = np.asarray(Image.open(dst), dtype=np.int64)
    assert seen.shape == (32, 32, 3)
    # A uniform field stays itself where the kernel sees no edge; the black surround darkens the corners.
    assert np.all(np.abs(seen[16, 16] - 128) <= 1)
    assert np.all(seen[0, 0] < 120)


def test_simulate_in_focus_eye_takes_identity_path(tmp_path, capsys):
    """An emmetrope at optical infinity without chromatic aberration sees the image unchanged."""
    src = write_colour_png(tmp_path / "in.png", seed=3)
    rx = write_rx(tmp_path / "rx.json", EMMETROPE)
    dst = tmp_path / "seen.png"
    rc, out, err = run(capsys, "simulate", src, "-o", dst, "--rx", rx, "--no-lca", "--distance-m", "inf",
                       "--explain")
    assert rc == 0, err
    assert "identity path" in out and "forward model: identity path" in out
    assert "convolution needed" not in out
    diff = np.asarray(Image.open(dst), dtype=np.int64) - np.asarray(Image.open(src), dtype=np.int64)
    assert np.abs(diff).max() <= 1


def test_simulate_refuses_to_overwrite_without_force(tmp_path, capsys):
    src = write_colour_png(tmp_path / "in.png")
    dst = tmp_path / "out.png"
    dst.write_bytes(b"precious user data")
    before = listing(tmp_path)
    rc, out, err = run(capsys, "simulate", src, "-o", dst)
    assert_clean_failure(rc, out, err, tmp_path, before, contains=("--force", "out.png"))
    assert dst.read_bytes() == b"precious user data"


def test_simulate_force_replaces_existing_output(tmp_path, capsys):
    src = write_colour_png(tmp_path / "in.png", seed=5)
    rx = write_rx(tmp_path / "rx.json", EMMETROPE)
    dst = tmp_path / "out.png"
    dst.write_bytes(b"old")
    rc, _, err = run(capsys, "simulate", src, "-o", dst, "--rx", rx, "--no-lca", "--distance-m", "inf",
                     "--force")
    assert rc == 0, err
    with Image.open(dst) as im:
        assert im.format == "PNG" and im.size == (40, 32)
    assert listing(tmp_path) == {"in.png", "rx.json", "out.png"}


def test_simulate_16bit_output(tmp_path, capsys):
    src = write_colour_png(tmp_path / "in.png", seed=6)
    rx = write_rx(tmp_path / "rx.json", EMMETROPE)
    dst = tmp_path / "out16.png"
    rc, _, err = run(capsys, "simulate", src, "-o", dst, "--rx", rx, "--no-lca", "--distance-m", "inf", "--16bit")
    assert rc == 0, err
    assert dst.read_bytes()[24] == 16  # IHDR bit depth


# ---------------------------------------------------------------- simulate: failures

def _bad_json(folder: Path) -> list[str]:
    (folder / "bad.json").write_text('{\n  "schema": "vrcorrect.prescription/1",\n  "right": {\n'
                                     '    "sphere_D": -2,,\n  }\n}\n')
    return ["--rx", "bad.json"]


def _invalid_values(folder: Path) -> list[str]:
    write_rx(folder / "inv.json", {"sphere_D": -99, "cylinder_D": 0, "axis_deg": 400, "pupil_diameter_mm": 4},
             EMMETROPE)
    return ["--rx", "inv.json"]


# name: (extra files maker -> extra args, input, output, phrases, stderr lines)
SIMULATE_FAILURES = {
    "missing input": (None, "nope.png", "out.png", ("nope.png", "no such file"), 1),
    "text file named .png": (None, "text.png", "out.png", ("text.png", "not an image"), 1),
    "truncated png": (None, "cut.png", "out.png", ("cut.png", "cannot read image"), 1),
    "corrupt png body": (None, "corrupt.png", "out.png", ("corrupt.png",), 1),
    "bad json": (_bad_json, "in.png", "out.png", ("bad.json", "invalid JSON", "line 4"), 1),
    "invalid values": (_invalid_values, "in.png", "out.png",
                       ("inv.json", "2 problems", "right.sphere_D", "right.axis_deg", "-20 to 20"), 3),
    "missing rx": (lambda f: ["--rx", "gone.json"], "in.png", "out.png", ("gone.json", "not found"), 1),
    "unknown display": (lambda f: ["--display", "holodeck"], "in.png", "out.png",
                        ("holodeck",) + preset_names(), 1),
    "output not png": (None, "in.png", "out.jpg", ("out.jpg", ".png"), 1),
    "output folder missing": (None, "in.png", "nowhere/out.png", ("nowhere", "does not exist"), 1),
    "bad distance": (lambda f: ["--distance-m", "far"], "in.png", "out.png", ("--distance-m", "far"), 1),
    "negative distance": (lambda f: ["--distance-m=-2"], "in.png", "out.png", ("viewing_distance_m",), 1),
    "bad energy fraction": (lambda f: ["--energy-fraction", "1.5"], "in.png", "out.png", ("energy_fraction",), 1),
}


@pytest.fixture
def failure_folder(tmp_path):
    write_colour_png(tmp_path / "in.png")
    (tmp_path / "text.png").write_text("hello, I am text\n")
    good = (tmp_path / "in.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(good[:len(good) // 2])
    body = bytearray(good)
    body[60:200] = bytes(140)  # zero out part of the compressed data: CRC and zlib both broken
    (tmp_path / "corrupt.png").write_bytes(bytes(body))
    return tmp_path


@pytest.mark.parametrize("case", list(SIMULATE_FAILURES))
def test_simulate_bad_input_fails_cleanly(failure_folder, capsys, monkeypatch, case):
    make, src, dst, phrases, lines = SIMULATE_FAILURES[case]
    monkeypatch.chdir(failure_folder)
    extra = make(failure_folder) if make else []
    before = listing(failure_folder)
    rc, out, err = run(capsys, "simulate", src, "-o", dst, *extra)
    assert rc == cli.EXIT_USAGE
    assert_clean_failure(rc, out, err, failure_folder, before, contains=phrases, lines=lines)


# ---------------------------------------------------------------- the real console script

def _script(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "VRCORRECT_DEBUG"}
    return subprocess.run([str(CONSOLE_SCRIPT), *argv], cwd=cwd, capture_output=True, text=True, timeout=120,
                          env=env)


@pytest.mark.parametrize("src", ["missing.png", "cut.png"])
def test_console_script_bad_input_no_traceback(failure_folder, src):
    before = listing(failure_folder)
    proc = _script("simulate", src, "-o", "out.png", cwd=failure_folder)
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    assert proc.stderr.startswith("vrcorrect: error:") and len(proc.stderr.strip().splitlines()) == 1
    assert src in proc.stderr
    assert proc.stdout == ""
    assert listing(failure_folder) == before


def test_console_script_unknown_command(tmp_path):
    proc = _script("frobnicate", cwd=tmp_path)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert "invalid choice" in proc.stderr and "frobnicate" in proc.stderr
    assert listing(tmp_path) == set()


# ---------------------------------------------------------------- argparse usage errors

@pytest.mark.parametrize("argv", [["frobnicate"], [], ["simulate", "in.png"], ["rx"], ["psf", "--bogus"],
                                  ["simulate", "in.png", "-o", "o.png", "--eye", "middle"],
                                  ["overlay", "--source", "screen", "--eye", "both"],
                                  ["overlay", "--source", "screen", "--backend", "vulkan"]])
def test_usage_errors_exit_2(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    rc, out, err = run(capsys, *argv)
    assert rc == 2
    assert "Traceback" not in err
    assert "usage: vrcorrect" in err
    assert listing(tmp_path) == set()


# ---------------------------------------------------------------- --help (issue 26's newcomer stumbles)

def _parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    """Every parser a user can ask for --help: ``vrcorrect``, each command, each nested action."""
    found = []

    def walk(name: str, parser: argparse.ArgumentParser) -> None:
        found.append((name, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub_name, sub in action.choices.items():
                    walk(f"{name} {sub_name}", sub)

    walk("vrcorrect", cli.build_parser())
    return found


def _commands() -> list[str]:
    return [name.split()[1] for name, _ in _parsers() if len(name.split()) == 2]


def test_no_help_shows_a_doubled_percent_sign():
    """``%%`` is argparse's escape in an option's help; a description is printed as written."""
    for name, parser in _parsers():
        assert "%%" not in parser.format_help(), name


def test_choices_read_one_way_in_every_help():
    """A fixed set of values is shown as argparse shows choices, ``{right,left}``, never ``right|left``
    (``demo|IMAGE|VIDEO|DIR``, a keyword or a kind of path, is not a set of choices)."""
    alternatives = re.compile(r"(?<![\w|])[a-z][a-z0-9-]*(?:\|[a-z][a-z0-9-]*)+(?![\w|])")
    for name, parser in _parsers():
        assert not alternatives.findall(parser.format_help()), name


@pytest.mark.parametrize("command", _commands())
def test_every_command_help_has_a_description(command, capsys):
    """``vrcorrect COMMAND --help``: the usage, then a paragraph saying what the command does, then the
    arguments."""
    rc, out, err = run(capsys, command, "--help")
    assert rc == 0, err
    paragraphs = [p for p in out.split("\n\n") if p.strip()]
    assert paragraphs[0].startswith("usage: vrcorrect " + command)
    assert not paragraphs[1].startswith(("positional arguments:", "options:")), out


def test_overlay_summary_says_it_shows_full_screen_or_in_a_window(capsys):
    rc, out, err = run(capsys, "--help")
    assert rc == 0, err
    text = " ".join(out.split())
    summary = re.search(r" overlay (.*?) xr ", text)
    assert summary and "full-screen" in summary.group(1) and "window" in summary.group(1), text


# ---------------------------------------------------------------- psf

def test_psf_monochromatic_from_edited_template(tmp_path, capsys):
    rx = tmp_path / "me.json"
    rc, out, err = run(capsys, "rx", "new", rx)
    assert rc == 0, err
    doc = json.loads(strip_comment_lines(rx.read_text()))
    for eye in ("right", "left"):
        doc[eye]["sphere_D"] = -2.0
    rx.write_text(json.dumps(doc, indent=2))

    npy, plot = tmp_path / "psf.npy", tmp_path / "psf.png"
    rc, out, err = run(capsys, "psf", "--rx", rx, "--wavelength-nm", "550", "-o", npy, "--png", plot)
    assert rc == 0, err
    psf = np.load(npy)
    assert psf.ndim == 2 and psf.shape[0] == psf.shape[1] and psf.shape[0] % 2 == 1 and psf.shape[0] > 1
    assert abs(psf.sum() - 1.0) < 1e-9
    assert psf.min() >= 0.0
    c = psf.shape[0] // 2
    assert np.unravel_index(np.argmax(psf), psf.shape) == (c, c)
    # A pure sphere is rotationally symmetric: the sampled PSF has the square's symmetries.
    np.testing.assert_allclose(psf, psf.T, atol=1e-12)
    np.testing.assert_allclose(psf, psf[::-1, :], atol=1e-12)
    np.testing.assert_allclose(psf, psf[:, ::-1], atol=1e-12)

    meta = json.loads((tmp_path / "psf.json").read_text())
    assert meta["kernel_size"] == psf.shape[0]
    assert meta["pixels_per_degree"] == pytest.approx(get_display("quest2").pixels_per_degree)
    assert meta["wavelengths_nm"] == [550.0]
    assert meta["reference_wavelength_nm"] == 555.0
    assert meta["prescription"] == str(rx) and meta["eye"] == "right" and meta["display"] == "quest2"
    with Image.open(plot) as im:
        assert im.format == "PNG"
    assert listing(tmp_path) == {"me.json", "psf.npy", "psf.json", "psf.png"}


def test_psf_full_kernel_sums_equal_rgb_to_lms(tmp_path, capsys):
    npy = tmp_path / "k.npy"
    rc, out, err = run(capsys, "psf", "-o", npy)
    assert rc == 0, err
    K = np.load(npy)
    assert K.ndim == 4 and K.shape[:2] == (3, 3)
    s = K.shape[-1]
    assert K.shape[-2] == s and s % 2 == 1
    meta = json.loads((tmp_path / "k.json").read_text())
    assert meta["kernel_size"] == s
    A = np.asarray(meta["rgb_to_lms"])
    assert A.shape == (3, 3) and np.all(A >= 0) and A[0, 0] > 0
    np.testing.assert_allclose(K.sum(axis=(2, 3)), A, rtol=1e-9, atol=1e-12)
    assert len(meta["wavelengths_nm"]) > 1 and meta["wavelengths_nm"] == sorted(meta["wavelengths_nm"])
    assert meta["pixels_per_degree"] == pytest.approx(get_display("quest2").pixels_per_degree)
    assert meta["identity"] is False
    assert f"{s}x{s}" in out
    assert listing(tmp_path) == {"k.npy", "k.json"}


@pytest.mark.parametrize("existing", ["psf.npy", "psf.json", "psf.png"])
def test_psf_refuses_to_overwrite_any_output(tmp_path, capsys, existing):
    (tmp_path / existing).write_bytes(b"mine")
    before = listing(tmp_path)
    rc, out, err = run(capsys, "psf", "--wavelength-nm", "550", "-o", tmp_path / "psf.npy",
                       "--png", tmp_path / "psf.png")
    assert_clean_failure(rc, out, err, tmp_path, before, contains=("--force", existing))
    assert (tmp_path / existing).read_bytes() == b"mine"


def test_psf_force_overwrites_both_files(tmp_path, capsys):
    for name in ("psf.npy", "psf.json"):
        (tmp_path / name).write_bytes(b"old")
    rc, _, err = run(capsys, "psf", "--wavelength-nm", "600", "-o", tmp_path / "psf.npy", "--force")
    assert rc == 0, err
    assert np.load(tmp_path / "psf.npy").ndim == 2
    assert json.loads((tmp_path / "psf.json").read_text())["wavelength_nm"] == 600.0


@pytest.mark.parametrize("argv, phrases", [
    (["-o", "psf.txt"], ("psf.txt", ".npy")),
    (["-o", "psf.npy", "--png", "plot.jpg"], ("plot.jpg", ".png")),
    (["-o", "psf.npy", "--wavelength-nm", "5"], ("wavelength_nm",)),
    (["-o", "psf.npy", "--display", "nosuch"], ("nosuch", "quest2")),
    (["-o", "nowhere/psf.npy"], ("does not exist",)),
])
def test_psf_bad_input_fails_cleanly(tmp_path, capsys, monkeypatch, argv, phrases):
    monkeypatch.chdir(tmp_path)
    rc, out, err = run(capsys, "psf", *argv)
    assert_clean_failure(rc, out, err, tmp_path, set(), contains=phrases)


def test_psf_sidecar_never_replaces_the_prescription(tmp_path, capsys):
    """``-o eye.npy`` would write its sidecar to eye.json: not if that is the prescription, even with --force."""
    rx = write_rx(tmp_path / "eye.json", EMMETROPE)
    original = rx.read_bytes()
    rc, out, err = run(capsys, "psf", "--rx", rx, "--wavelength-nm", "550", "-o", tmp_path / "eye.npy", "--force")
    assert_clean_failure(rc, out, err, tmp_path, {"eye.json"}, contains=("eye.json",))
    assert rx.read_bytes() == original


# ---------------------------------------------------------------- rx

def test_rx_new_writes_a_template_that_validates(tmp_path, capsys):
    path = tmp_path / "rx.json"
    rc, out, err = run(capsys, "rx", "new", path)
    assert rc == 0, err
    assert path.read_text() == template_text()
    assert "//" in path.read_text()  # commented
    rc, out, err = run(capsys, "rx", "validate", path)
    assert rc == 0, err
    assert "valid" in out and "right" in out and "left" in out
    assert err == ""


def test_rx_new_writes_the_file_from_a_spectacle_prescription(tmp_path, capsys):
    """``rx new --right --left --age``: the lines of a spectacle prescription, no JSON to edit; the file
    keeps the template's comments and loads as those eyes (the left given in plus-cylinder form, the
    same eye as its minus form)."""
    from vrcorrect.specs.prescription import load_prescription

    path = tmp_path / "rx.json"
    rc, out, err = run(capsys, "rx", "new", path, "--right", "-2.00 -1.00 x 120", "--left", "-3.00/+0.50x60",
                       "--age", "45")
    assert rc == 0, err
    text = path.read_text()
    assert text.startswith(template_text().split("{")[0])                              # the comments, as in the template
    rx = load_prescription(path)
    right, left = rx.eye("right"), rx.eye("left")
    # the lenses 12 mm in front of the eye (the default), each meridian's F / (1 - 0.012 F), by hand:
    # -2.00 -> -1.953, -3.00 -> -2.896 (cylinder -0.943); -3.00 -> -2.896, -2.50 -> -2.427 (cylinder +0.469)
    assert (right.sphere_D, right.cylinder_D, right.axis_deg) == (-1.953, -0.943, 120.0)
    assert (left.sphere_D, left.cylinder_D, left.axis_deg) == (-2.896, 0.469, 60.0)
    assert left.power_vector().M_D == pytest.approx(-2.6615) and rx.age_years == 45
    assert right.accommodation_D == pytest.approx(18.5 - 0.3 * 45)                    # from the age, as validate says
    assert "right -1.95 / -0.94 x 120" in out and "expected at age 45" in out and "placeholder" not in out
    assert "12 mm in front of the eye" in out and "the powers here are at the eye" in path.read_text()
    rc, out, err = run(capsys, "rx", "new", path, "--force", "--right", "-2.00 -1.00 x 120", "--left",
                       "-3.00/+0.50x60", "--vertex", "0")                          # a contact-lens prescription
    assert rc == 0, err
    rx = load_prescription(path)
    assert (rx.right.sphere_D, rx.right.cylinder_D) == (-2.0, -1.0) and (rx.left.sphere_D, rx.left.cylinder_D) == (-3.0, 0.5)
    assert "in front of the eye" not in out and "(--vertex 0)" in path.read_text()


def test_rx_new_moves_a_strong_spectacle_prescription_to_the_eye(tmp_path, capsys):
    """A -8.00 lens 14 mm from the eye is a -7.19 eye (-8 / 1.112); a +8.00 one a +9.01 eye (8 / 0.888);
    a vertex distance out of 0 to 25 mm is refused naming --vertex, nothing written."""
    from vrcorrect.specs.prescription import load_prescription

    path = tmp_path / "rx.json"
    rc, out, err = run(capsys, "rx", "new", path, "--right", "-8.00", "--left", "+8.00", "--vertex", "14")
    assert rc == 0, err
    rx = load_prescription(path)
    assert rx.right.sphere_D == pytest.approx(-8.0 / 1.112, abs=5e-4) and rx.left.sphere_D == pytest.approx(8.0 / 0.888, abs=5e-4)
    for bad in ("30", "-1", "nan"):
        other = tmp_path / f"v{bad}.json"
        rc, out, err = run(capsys, "rx", "new", other, "--right", "-8.00", "--vertex", bad)
        assert rc == 2 and "--vertex" in err and "0 to 25 mm" in err and not other.exists(), err


def test_rx_validate_says_what_a_strong_hand_written_prescription_would_be_at_the_eye(tmp_path, capsys):
    """A file written by hand with -8.00 D (the old template asked for the glasses' numbers): validate says
    the eye's would be -7.30 (-8 / 1.096) if they are; a file rx new wrote, already at the eye, gets no
    such line, nor does a weak prescription."""
    doc = json.loads(strip_comment_lines(template_text()))
    doc["right"]["sphere_D"] = -8.0
    path = tmp_path / "rx.json"
    path.write_text(json.dumps(doc))
    rc, out, err = run(capsys, "rx", "validate", path)
    assert rc == 0 and "the right eye's powers reach 4 D" in out and "-7.30 / +0.00 x 0 for the right eye" in out
    made = tmp_path / "made.json"
    assert run(capsys, "rx", "new", made, "--right", "-8.00", "--left", "-8.00")[0] == 0
    rc, out, err = run(capsys, "rx", "validate", made)
    assert rc == 0 and "powers reach" not in out
    doc["right"]["sphere_D"] = -3.75
    path.write_text(json.dumps(doc))
    rc, out, err = run(capsys, "rx", "validate", path)
    assert rc == 0 and "powers reach" not in out


def test_rx_new_writes_a_measured_lag_and_validate_says_it(tmp_path, capsys):
    from vrcorrect.specs.prescription import load_prescription

    path = tmp_path / "rx.json"
    rc, out, err = run(capsys, "rx", "new", path, "--right", "-1.00", "--left", "-1.25", "--age", "30", "--lag", "0.75")
    assert rc == 0, err
    rx = load_prescription(path)
    assert rx.right.accommodative_lag_D == 0.75 == rx.left.accommodative_lag_D
    assert out.count("lag 0.75 D at 40 cm") == 2
    rc, out, err = run(capsys, "rx", "validate", path)
    assert rc == 0 and out.count("lag 0.75 D at 40 cm") == 2
    for bad, field in (("2.5", "accommodative_lag_D = 2.5"), ("nan", "--lag = nan")):
        other = tmp_path / f"bad{bad}.json"
        rc, out, err = run(capsys, "rx", "new", other, "--right", "-1.00", "--lag", bad)
        assert rc == 2 and field in err and "Traceback" not in err and not other.exists()


def test_rx_new_with_one_eye_says_the_other_is_a_placeholder(tmp_path, capsys):
    path = tmp_path / "rx.json"
    rc, out, err = run(capsys, "rx", "new", path, "--right", "plano -0.75 x 90")
    assert rc == 0, err
    assert "the left eye is plano (0.00) as a placeholder: give --left" in out
    assert "no age_years" in out


def test_rx_new_reads_a_line_with_a_reading_addition_and_says_the_add_is_not_used(tmp_path, capsys):
    from vrcorrect.specs.prescription import load_prescription

    path = tmp_path / "rx.json"
    rc, out, err = run(capsys, "rx", "new", path, "--right", "-2.00 -1.00 x 120 ADD +2.00", "--left", "-1.00",
                       "--age", "60")
    assert rc == 0, err
    right = load_prescription(path).eye("right")
    assert (right.sphere_D, right.cylinder_D, right.axis_deg) == (-1.953, -0.943, 120.0)  # the distance lens, at the eye
    assert "the right eye's ADD +2.00 (the reading addition) is not used" in out
    assert "left eye's ADD" not in out


@pytest.mark.parametrize("argv, field", [
    (["--right", "-2.00 -1.00"], "--right"),                       # a cylinder without its axis
    (["--left", "two dioptres"], "--left"),
    (["--right", "-2.00 -1.00 x 200"], "--right axis"),
    (["--right", "-25", "--vertex", "0"], "right.sphere_D = -25"),  # read, but out of a prescription's range
    (["--right", "-30"], "right.sphere_D (at the eye, from the lens's -30.00 D 12 mm in front of it) = -22.059"),
    (["--left", "+18.00"], "left.sphere_D (at the eye, from the lens's +18.00 D 12 mm in front of it) = 22.959"),
    (["--left", "+40", "--vertex", "25"], "left.sphere_D = 40"),   # a lens focusing at the eye: as written, refused
    (["--right", "-1.00", "--age", "150"], "age_years"),
    (["--right", "-1.00", "--age", "nan"], "--age"),
])
def test_rx_new_refuses_a_bad_prescription_line_and_writes_nothing(argv, field, tmp_path, capsys):
    rc, out, err = run(capsys, "rx", "new", tmp_path / "rx.json", *argv)
    assert rc == 2 and field in err and "Traceback" not in err, err
    assert listing(tmp_path) == set()


def test_rx_validate_says_each_eyes_accommodation_and_whether_it_came_from_the_age(tmp_path, capsys):
    doc = json.loads(strip_comment_lines(template_text()))
    doc["age_years"] = 50
    doc["right"]["accommodation_D"] = 1.25
    path = tmp_path / "rx.json"
    path.write_text(json.dumps(doc))
    rc, out, err = run(capsys, "rx", "validate", path)
    assert rc == 0, err
    right, left = (line for line in out.splitlines() if line.lstrip().startswith(("right", "left")))
    assert right.endswith("accommodation 1.25 D")                                    # as stated
    assert left.endswith("accommodation 3.50 D (expected at age 50: none stated)")   # 18.5 - 0.3 x 50
    assert "no age_years" not in out
    del doc["age_years"]                                                             # the left eye: 0, and said
    path.write_text(json.dumps(doc))
    rc, out, err = run(capsys, "rx", "validate", path)
    assert rc == 0 and "accommodation 0.00 D" in out and "no age_years: an eye with accommodation 0" in out


def test_rx_new_refuses_to_overwrite_and_force_overwrites(tmp_path, capsys):
    path = tmp_path / "rx.json"
    path.write_text("my real prescription")
    rc, out, err = run(capsys, "rx", "new", path)
    assert_clean_failure(rc, out, err, tmp_path, {"rx.json"}, contains=("--force", "rx.json"))
    assert path.read_text() == "my real prescription"
    rc, out, err = run(capsys, "rx", "new", path, "--force")
    assert rc == 0, err
    assert path.read_text() == template_text()
    assert listing(tmp_path) == {"rx.json"}


def test_rx_validate_reports_every_problem(tmp_path, capsys):
    doc = json.loads(strip_comment_lines(template_text()))
    doc["right"]["sphere_D"] = 35.0
    doc["left"]["axis_deg"] = 270
    doc["left"]["pupil_diameter_mm"] = "four"
    path = tmp_path / "three.json"
    path.write_text(json.dumps(doc))
    rc, out, err = run(capsys, "rx", "validate", path)
    # like every command's bad input: exit 2, one "vrcorrect: error:" line naming the file, then the list
    assert rc == cli.EXIT_USAGE
    assert_clean_failure(rc, out, err, tmp_path, {"three.json"}, contains=("three.json", "3 problems"), lines=4)
    problems = [line for line in err.splitlines() if line.startswith("  - ")]
    assert len(problems) == 3
    fields = {"right.sphere_D": "35", "left.axis_deg": "270", "left.pupil_diameter_mm": "four"}
    for field, value in fields.items():
        assert any(field in p and value in p for p in problems), (field, err)
    assert "valid" not in out


def test_rx_validate_syntax_error_has_line_number(tmp_path, capsys):
    path = tmp_path / "broken.json"
    path.write_text('{\n  "schema": "vrcorrect.prescription/1",\n  "right": {"sphere_D": -1 "x": 2}\n}\n')
    rc, out, err = run(capsys, "rx", "validate", path)
    assert_clean_failure(rc, out, err, tmp_path, {"broken.json"}, contains=("broken.json", "line 3"))


# ---------------------------------------------------------------- displays

def test_displays_lists_every_preset(capsys):
    rc, out, err = run(capsys, "displays")
    assert rc == 0, err
    for name in preset_names():
        d = get_display(name)
        row = next((line for line in out.splitlines() if line.startswith(f"| {name} |")), None)
        assert row is not None, name
        assert d.title in row and f"{d.pixels_per_degree:.1f}" in row


def test_displays_verbose_prints_sources(capsys):
    rc, out, err = run(capsys, "displays", "-v")
    assert rc == 0, err
    for name in preset_names():
        sources = get_display(name).sources
        assert sources and f"{name}: {sources}" in out


def _gaussian_csv(path: Path) -> Path:
    lines = ["# synthetic primaries: three smooth Gaussians", "wavelength_nm,r,g,b"]
    for wl in range(380, 781, 5):
        g = [math.exp(-0.5 * ((wl - c) / s) ** 2) for c, s in ((610, 15), (540, 20), (460, 12))]
        lines.append(f"{wl},{g[0]:.6f},{0.8 * g[1]:.6f},{1.2 * g[2]:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_displays_fit_reports_errors_and_plots(tmp_path, capsys):
    csv = _gaussian_csv(tmp_path / "spectra.csv")
    plot = tmp_path / "fit.png"
    rc, out, err = run(capsys, "displays", "--fit", csv, "--plot", plot)
    assert rc == 0, err
    assert "81 samples, 380-780 nm" in out
    rms = dict(re.findall(r"(red|green|blue)\s+smooth non-negative fit: rms error ([0-9.]+)% of peak", out))
    assert set(rms) == {"red", "green", "blue"}
    assert all(float(v) < 1.0 for v in rms.values())  # smooth Gaussians are fitted well
    with Image.open(plot) as im:
        assert im.format == "PNG"
    assert listing(tmp_path) == {"spectra.csv", "fit.png"}


def test_displays_fit_plot_refuses_to_overwrite(tmp_path, capsys):
    csv = _gaussian_csv(tmp_path / "spectra.csv")
    plot = tmp_path / "fit.png"
    plot.write_bytes(b"mine")
    rc, out, err = run(capsys, "displays", "--fit", csv, "--plot", plot)
    assert_clean_failure(rc, out, err, tmp_path, {"spectra.csv", "fit.png"}, contains=("--force",))
    assert plot.read_bytes() == b"mine"


@pytest.mark.parametrize("body, line, phrase", [
    ("wavelength_nm,r,g,b\n400,1,2,3\n410,1,x,3\n", 3, "g = 'x'"),
    ("# comment\nwavelength,red,green,blue\n400,1,2,3\n", 2, "header"),
    ("wavelength_nm,r,g,b\n400,1,2,3\n410,1,2\n", 3, "columns"),
    ("wavelength_nm,r,g,b\n400,1,2,3\n390,1,2,3\n", 3, "increase"),
    ("wavelength_nm,r,g,b\n400,1,-2,3\n", 2, "negative"),
])
def test_displays_fit_malformed_csv(tmp_path, capsys, body, line, phrase):
    csv = tmp_path / "bad.csv"
    csv.write_text(body)
    rc, out, err = run(capsys, "displays", "--fit", csv, "--plot", tmp_path / "fit.png")
    assert_clean_failure(rc, out, err, tmp_path, {"bad.csv"}, contains=("bad.csv", f"line {line}:", phrase))


# ---------------------------------------------------------------- demo

DEMO_FILES = {"right_eye_sees.png", "left_eye_sees.png", "demo_panel.png", "dioptre_sweep.png"}


@pytest.mark.slow
def test_demo_writes_four_pngs_and_refuses_to_overwrite(tmp_path, capsys):
    out_dir = tmp_path / "demo"
    rc, out, err = run(capsys, "demo", "--out", out_dir)
    assert rc == 0, err
    assert listing(out_dir) == DEMO_FILES
    assert len([line for line in out.splitlines() if line.startswith("wrote ")]) == 4
    sizes = {}
    for name in DEMO_FILES:
        with Image.open(out_dir / name) as im:
            assert im.format == "PNG"
            sizes[name] = im.size
    assert sizes["right_eye_sees.png"] == sizes["left_eye_sees.png"] == (512, 512)
    assert sizes["demo_panel.png"][0] > 3 * 512
    right = np.asarray(Image.open(out_dir / "right_eye_sees.png"), dtype=np.int64)
    left = np.asarray(Image.open(out_dir / "left_eye_sees.png"), dtype=np.int64)
    assert np.abs(right - left).max() > 0  # two different eyes

    stamp = {name: (out_dir / name).read_bytes() for name in DEMO_FILES}
    rc, out, err = run(capsys, "demo", "--out", out_dir)
    assert_clean_failure(rc, out, err, out_dir, DEMO_FILES, contains=("--force",))
    assert {name: (out_dir / name).read_bytes() for name in DEMO_FILES} == stamp


def test_demo_refuses_existing_file_before_any_work(tmp_path, capsys):
    out_dir = tmp_path / "demo"
    out_dir.mkdir()
    (out_dir / "demo_panel.png").write_bytes(b"mine")
    rc, out, err = run(capsys, "demo", "--out", out_dir)
    assert_clean_failure(rc, out, err, out_dir, {"demo_panel.png"}, contains=("--force", "demo_panel.png"))
    assert (out_dir / "demo_panel.png").read_bytes() == b"mine"


def test_demo_unknown_display_creates_nothing(tmp_path, capsys):
    rc, out, err = run(capsys, "demo", "--out", tmp_path / "new", "--display", "nosuch")
    assert_clean_failure(rc, out, err, tmp_path, set(), contains=("nosuch",))


# ---------------------------------------------------------------- bench

@pytest.mark.slow
def test_bench_kernel_writes_markdown_table(tmp_path, capsys):
    md = tmp_path / "bench.md"
    md.write_text("# my notes\n\nkeep this paragraph\n")
    rc, out, err = run(capsys, "bench", "kernel", "--repeats", "1", "--out", md)
    assert rc == 0, err
    text = md.read_text()
    assert "keep this paragraph" in text  # the section is added, the rest of the file kept
    assert f"Machine: {machine_description()}." in text
    assert "| display | px/deg | median s |" in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and not line.startswith("| display")]
    for name in [n for n in HEADSETS if n in preset_names()] + ["desktop"]:
        title = get_display(name).title
        assert any(row.startswith(f"| {title} |") for row in rows), title
    assert "Median of 1 runs" in text
    assert "| display | px/deg | median s |" in out  # also printed
    assert listing(tmp_path) == {"bench.md"}


REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def kernel_bench_calls(monkeypatch):
    """``bench kernel`` without the benchmark: the (out, write) it would have been given."""
    calls = []

    def fake(repeats: int = 5, out: Path = Path("docs/benchmarks.md"), write: bool = True) -> str:
        calls.append((Path(out), write))
        return "| display | px/deg | median s |"

    monkeypatch.setattr("vrcorrect.studies.bench.kernel.run_kernel_bench", fake)
    return calls


def test_bench_outside_the_repository_needs_out(tmp_path, capsys, monkeypatch, kernel_bench_calls):
    """Issue 26: the default --out, docs/benchmarks.md, was taken relative to wherever bench ran."""
    (tmp_path / "docs").mkdir()                                  # a user's own docs folder
    monkeypatch.chdir(tmp_path)
    rc, out, err = run(capsys, "bench", "kernel")
    assert_clean_failure(rc, out, err, tmp_path, {"docs"}, contains=("--out",))
    assert listing(tmp_path / "docs") == set() and kernel_bench_calls == []    # refused before any work
    rc, out, err = run(capsys, "bench", "kernel", "--out", "docs/mine.md")
    assert rc == 0, err
    assert kernel_bench_calls == [(Path("docs/mine.md"), True)]                 # as given, as before
    rc, out, err = run(capsys, "bench", "kernel", "--no-write")
    assert rc == 0, err
    assert kernel_bench_calls[-1][1] is False and listing(tmp_path / "docs") == set()


def test_bench_inside_the_repository_updates_its_benchmarks_file(capsys, monkeypatch, kernel_bench_calls):
    monkeypatch.chdir(REPO / "tests")                            # any folder of the checkout
    rc, _, err = run(capsys, "bench", "kernel")
    assert rc == 0, err
    assert kernel_bench_calls == [(REPO / "docs" / "benchmarks.md", True)]


# ---------------------------------------------------------------- correct --panel

def test_correct_panel_shows_the_goal_none_and_the_correction_side_by_side(tmp_path, capsys):
    """``correct --panel``: one picture of three columns (with glasses, no correction, this correction),
    each the picture's size with its FLIP map under it, written with the output; its captions carry the
    report's own scores."""
    src = write_colour_png(tmp_path / "in.png")
    rc, out, err = run(capsys, "correct", src, "-o", tmp_path / "shown.png", "--display", "desktop", "--pupil", "4",
                       "--panel", tmp_path / "panel.png", "--report", tmp_path / "r.json")
    assert rc == 0, err
    assert listing(tmp_path) == {"in.png", "shown.png", "panel.png", "r.json"}
    assert "; panel " in out
    with Image.open(tmp_path / "panel.png") as im:
        w, h = im.size
        panel = np.asarray(im.convert("RGB"))
    assert w == 3 * 40 + 2 * 6 and h > 2 * 32                                  # three 40 px columns, map under each
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["metrics"]["jod"] > report["metrics_uncorrected"]["jod"]
    none, corrected = (panel[h - 32:, x:x + 40] for x in (46, 92))                # the FLIP maps
    assert np.abs(none.astype(int) - corrected.astype(int)).sum() > 0


@pytest.mark.parametrize("panel, says", [("panel.jpg", ".png"), ("shown.png", "other than"), ("in.png", "other than")])
def test_correct_panel_is_refused_where_it_would_overwrite_or_is_not_png(panel, says, tmp_path, capsys):
    src = write_colour_png(tmp_path / "in.png")
    before = listing(tmp_path)
    rc, out, err = run(capsys, "correct", src, "-o", tmp_path / "shown.png", "--panel", tmp_path / panel, "--force")
    assert_clean_failure(rc, out, err, tmp_path, before, contains=("--panel", says))
