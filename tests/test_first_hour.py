"""A newcomer's first hour (issue 46): the stumbles of someone following the README, each fixed and
held here.  ``render`` shows its progress and says what it will do (frames, rate, its estimate on this
renderer); every command that falls back to the bundled sample prescription says so; no command
writes over its input; an image smaller than the eye's blur is noted with what the result means;
``correct`` reports the time the user waited and its parts, without iterations a one-pass method
does not have; help strings say what the code does.  (``unroll -o runs/x``, its progress and
checkpoint: tests/test_unrolled_train.py.)"""

from __future__ import annotations

import io
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vrcorrect.plumbing.imageio import write_png

ROOT = Path(__file__).resolve().parents[1]


def _cli(args: list[str], cwd: Path, **env: str) -> subprocess.CompletedProcess:
    """The command as a user runs it: its own process, standard error not a terminal; ``env``: more
    environment variables."""
    return subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli", *args], cwd=cwd, capture_output=True,
                          text=True, env={**__import__("os").environ, "PYTHONPATH": str(ROOT), **env}, timeout=900)


@pytest.fixture(scope="module")
def pictures(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("first_hour")
    rng = np.random.default_rng(46)
    write_png(folder / "small.png", rng.random((40, 48, 3)), bits=8)
    write_png(folder / "dot.png", np.full((1, 1, 3), 0.5), bits=8)
    from PIL import Image

    frames = [Image.fromarray((rng.random((32, 40, 3)) * 255).astype(np.uint8)) for _ in range(10)]
    frames[0].save(folder / "clip.gif", save_all=True, append_images=frames[1:], duration=40, loop=0)   # 25 fps
    (folder / "rx.json").write_text(json.dumps({
        "schema": "vrcorrect.prescription/1",
        "right": {"sphere_D": -2.0, "cylinder_D": -0.5, "axis_deg": 90, "pupil_diameter_mm": 4.0},
        "left": {"sphere_D": -2.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0}}))
    return folder


# --------------------------------------------------------------------------- progress


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_off_a_terminal_writes_a_line_every_interval_with_the_time_a_unit_takes_and_the_time_left():
    from vrcorrect.apps.progress import Progress

    clock, out = Clock(), io.StringIO()
    bar = Progress("render", "frame", 108, stream=out, interval=5.0, clock=clock)
    clock.now += 10.0
    bar.update(1)                                          # the first frame holds the set-up (compiles)
    for n in range(2, 12):
        clock.now += 0.5
        bar.update(n)
    bar.close()
    lines = out.getvalue().splitlines()
    assert lines[0] == "render: 1/108 frames, 10 s a frame, about 17 min 50 s left"
    assert lines[1] == "render: 11/108 frames, 500 ms a frame, about 48 s left"     # after the first: 0.5 s each
    assert lines[-1] == "render: 11 frames in 15 s (500 ms a frame)"
    assert len(lines) == 3                                 # the 0.5 s steps in between wrote nothing


def test_progress_on_a_terminal_redraws_one_line_and_clears_it():
    from vrcorrect.apps.progress import Progress

    clock, out = Clock(), Terminal()
    with Progress("unroll: training", "step", 4, stream=out, clock=clock) as bar:
        for n in range(1, 5):
            clock.now += 1.0
            bar.update(n, note=f"loss {-n / 10:.3f}")
    text = out.getvalue()
    assert "\n" not in text and text.count("\r") >= 5
    assert "unroll: training: 1/4 steps, 1000 ms a step, about 3.0 s left, loss -0.100" in text
    assert "4/4 steps" in text and text.endswith("\r")


def test_progress_says_it_is_still_working_during_a_long_step():
    import time

    from vrcorrect.apps.progress import Progress

    out = io.StringIO()
    bar = Progress("unroll: kernels", "eye", 3, stream=out, interval=0.2)
    bar.update(1)
    time.sleep(0.7)                                        # a long second eye: no update
    bar.close()
    assert "(working: " in out.getvalue() and "since the last eye" in out.getvalue()


# --------------------------------------------------------------------------- render


def test_render_says_what_it_will_do_and_shows_its_progress_off_a_terminal(pictures):
    """A 25 fps GIF played at the headset's 90 fps is said so, with how to keep its own rate; the
    estimate on this renderer comes before the frames; progress lines come every few seconds on
    standard error, though it is not a terminal. The interval is set short (0.25 s, through
    ``VRCORRECT_PROGRESS_S``) so that the 36 frames span many intervals however fast this machine
    compiles its first frame; the default 5 s would depend on the clock."""
    result = _cli(["render", "clip.gif", "-o", "clip_out", "--rx", "rx.json"], pictures,
                  VRCORRECT_PROGRESS_S="0.25")
    assert result.returncode == 0, result.stderr[-2000:]
    lines = result.stdout.splitlines()
    plan = next(line for line in lines if line.startswith("render: animation"))
    assert "of 10 frames" in plan and "-> 36 frames at 90 fps" in plan                 # not silent about the rate
    assert "--fps 25 keeps one frame per source frame" in plan
    estimate = next(line for line in lines if "expect roughly" in line)
    assert "llvmpipe" in estimate and "for the 36 frames" in estimate
    assert lines.index(plan) < lines.index(estimate) < len(lines) - 1
    progress = [line for line in result.stderr.splitlines() if line.startswith("render: ")]
    assert progress and all(re.match(r"render: \d+(/36)? frames", line) for line in progress), result.stderr
    assert progress[-1].startswith("render: 36 frames in "), progress
    assert any(re.fullmatch(r"render: \d+/36 frames, \d+ ms a frame, about \S+( min \S+)? s left", line)
               for line in progress), progress
    assert len(list((pictures / "clip_out").glob("frame_*.png"))) == 36
    assert "sample prescription" not in result.stdout


def test_render_at_the_clips_own_rate_says_nothing_of_another_rate(pictures):
    result = _cli(["render", "clip.gif", "-o", "clip_25", "--rx", "rx.json", "--fps", "25"], pictures)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "-> 10 frames at 25 fps" in result.stdout and "keeps one frame" not in result.stdout


# --------------------------------------------------------------------------- the sample prescription


@pytest.mark.parametrize("command", [["simulate", "small.png", "-o", "seen.png"],
                                     ["correct", "small.png", "-o", "shown.png", "--method", "wiener"],
                                     ["psf", "-o", "psf.npy"]])
def test_a_command_without_rx_says_on_one_line_that_it_uses_the_sample(pictures, capsys, monkeypatch, command):
    from vrcorrect.apps.cli import main

    monkeypatch.chdir(pictures)

    assert main([*command, "--force"]) == 0
    out = capsys.readouterr().out
    said = [line for line in out.splitlines() if "using the sample prescription" in line]
    assert len(said) == 1 and "pass --rx" in said[0] and "sample_rx.json" in said[0], out
    assert main([*command, "--force", "--rx", str(pictures / "rx.json")]) == 0
    assert "sample prescription" not in capsys.readouterr().out


# --------------------------------------------------------------------------- never over the input


@pytest.mark.parametrize("command", ["correct", "simulate", "render"])
@pytest.mark.parametrize("force", [[], ["--force"]], ids=["", "--force"])
def test_no_command_writes_over_its_input_even_with_force(pictures, tmp_path, capsys, command, force):
    from vrcorrect.apps.cli import main

    source = tmp_path / "in.png"
    source.write_bytes((pictures / "small.png").read_bytes())
    before = source.read_bytes()
    for output in (str(source), str(tmp_path / "." / "in.png")):
        assert main([command, str(source), "-o", output, "--rx", str(pictures / "rx.json"), *force]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--output" in err and "never writes over its input" in err, err
    assert source.read_bytes() == before


# --------------------------------------------------------------------------- an image smaller than the blur


def test_an_image_smaller_than_the_eyes_blur_is_corrected_with_a_note_of_what_that_means(pictures, capsys):
    from vrcorrect.apps.cli import main

    assert main(["correct", str(pictures / "dot.png"), "-o", str(pictures / "dot_out.png"), "--rx",
                 str(pictures / "rx.json"), "--method", "wiener", "--force"]) == 0
    err = capsys.readouterr().err
    note = [line for line in err.splitlines() if "smaller than this eye's blur" in line]
    assert len(note) == 1 and "1x1 px" in note[0] and "can recover little" in note[0], err
    assert (pictures / "dot_out.png").is_file()
    assert main(["correct", str(pictures / "small.png"), "-o", str(pictures / "small_out.png"), "--rx",
                 str(pictures / "rx.json"), "--method", "wiener", "--force"]) == 0
    assert "smaller than this eye's blur" not in capsys.readouterr().err          # 48x40 holds this eye's blur


# --------------------------------------------------------------------------- what the user waited for


def test_correct_reports_the_whole_command_and_its_parts(pictures):
    result = _cli(["correct", "small.png", "-o", "fast.png", "--rx", "rx.json", "--force"], pictures)
    assert result.returncode == 0, result.stderr[-2000:]
    took = next(line for line in result.stdout.splitlines() if line.strip().startswith("took "))
    m = re.match(r"\s*took (\S+) s: eye model (\S+) s, fast \((\d+) iterations\) (\S+) s, "
                 r"start-up, reading and writing (\S+) s$", took)
    assert m, took
    total, parts = float(m.group(1)), [float(m.group(i)) for i in (2, 4, 5)]
    assert int(m.group(3)) > 0 and abs(sum(parts) - total) <= 0.15 + 0.05 * total, took


def test_a_one_pass_method_reports_no_iterations(pictures):
    result = _cli(["correct", "small.png", "-o", "learned.png", "--rx", "rx.json", "--method", "learned", "--force"],
                  pictures)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "learned (one pass)" in result.stdout and "iterations" not in result.stdout, result.stdout


# --------------------------------------------------------------------------- help strings


def test_layer_install_help_names_the_default_method():
    result = _cli(["layer", "install", "--help"], ROOT)
    text = " ".join(result.stdout.split())
    assert "FISTA" not in text and "ADMM by default" in text and "2 for ADMM" in text
    assert "write the layer's manifest" in _cli(["layer", "--help"], ROOT).stdout.replace("\n", " ").replace("  ", " ")


# --------------------------------------------------------------------------- the tour's first step

def test_the_tours_prescription_line_writes_a_file_that_validates(tmp_path):
    """The README's step 1, exactly as written there: the lines of a spectacle prescription and an age,
    no JSON to edit; then ``rx validate`` accepts the file and names both eyes, moved from the lenses to the eye."""
    import shlex

    lines = [line.split("#")[0].strip() for line in (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
             if line.startswith("vrcorrect rx new ")]
    assert len(lines) == 1, lines
    made = _cli(shlex.split(lines[0])[1:], tmp_path)
    assert made.returncode == 0, made.stderr[-2000:]
    checked = _cli(["rx", "validate", "my_rx.json"], tmp_path)
    assert checked.returncode == 0, checked.stderr[-2000:]
    # the lenses moved to the eye, 12 mm behind them: -2.00/-3.00 meridians -> -1.953/-2.896, -1.50 -> -1.473
    assert "right -1.95 / -0.94 x 120" in checked.stdout and "left  -1.47 / +0.00 x 0" in checked.stdout
    assert "expected at age 45" in checked.stdout
