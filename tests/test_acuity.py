"""Simulated chart acuity (vrcorrect.vision.acuity, vrcorrect.studies.acuity_chart): by property, never by snapshot.

The calibration (an emmetrope reads logMAR 0), the published defocus relation (Blendowske 2015),
lines the display cannot draw, a correction that does not make reading worse, the command's JSON
and error paths, determinism.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from test_cli import run, run_quiet   # the command line in-process: (exit status, stdout, stderr)

from vrcorrect.vision import acuity as A
from vrcorrect.specs.display import get_display
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.physics.kernel import KernelOptions, build_kernel
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.specs.prescription import EyeRx

AT_INFINITY = KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf))
#: Where the calibration put the emmetrope's 60 % threshold (module docstring).
CALIBRATED_THRESHOLD = -0.05


def eye(sphere_D: float = 0.0, pupil_mm: float = 4.0, cylinder_D: float = 0.0) -> EyeRx:
    return EyeRx(sphere_D=sphere_D, cylinder_D=cylinder_D, axis_deg=0.0, pupil_diameter_mm=pupil_mm)


def blendowske_logmar(blur_D: float, logmar_0: float = CALIBRATED_THRESHOLD) -> float:
    """Blendowske (2015) Optom Vis Sci 92(6):e121: MAR = MAR_0 (1 + b^2)."""
    return logmar_0 + math.log10(1.0 + blur_D ** 2)


@pytest.fixture(scope="module")
def fine():
    return A.calibration_display(120.0)


@pytest.fixture(scope="module")
def medium():
    """60 ppd: lines down to logMAR 0.0 drawable; the defocus checks need no finer."""
    return A.calibration_display(60.0)


# ---------------------------------------------------------------- letters and chart

def test_sloan_letters_are_ten_distinct_five_stroke_squares():
    images = {ch: A.sloan_letter(ch, 50) for ch in A.SLOAN_LETTERS}
    for ch, im in images.items():
        assert im.shape == (50, 50) and im.dtype == np.float32
        ink = 1.0 - im.mean()
        assert 0.2 < ink < 0.65, (ch, ink)                          # strokes of 1/5 of the height
        assert im.min() == 0.0 and im.max() == 1.0
    letters = list(images)
    for i, a in enumerate(letters):
        for b in letters[i + 1:]:
            assert np.abs(images[a] - images[b]).mean() > 0.03, (a, b)       # C and O: the 1 x 1 stroke gap
    h = images["H"]                                                 # stems 10 px, crossbar rows 20-29
    assert h[5, 4] == 0.0 and h[5, 45] == 0.0 and h[25, 25] == 0.0
    assert h[5, 25] == 1.0 and h[45, 25] == 1.0 and h[5, 11] == 1.0
    o = images["O"]
    assert o[25, 25] == 1.0 and o[25, 4] == 0.0 and o[0, 0] == 1.0  # a ring: hollow, round corners
    assert images["C"][25, 47] == 1.0 and o[25, 47] == 0.0          # C: O opened on the right


def test_sloan_letter_rejects_bad_input():
    with pytest.raises(ValidationError, match="letter"):
        A.sloan_letter("E", 20)
    with pytest.raises(ValidationError, match="height_px"):
        A.sloan_letter("C", 0)


def test_chart_lines_follow_the_logmar_rules(medium):
    lines = A.chart_lines(medium)
    assert [ln.logmar for ln in lines] == [round(1.0 - 0.1 * i, 1) for i in range(14)]
    for ln in lines:
        assert len(ln.letters) == 5 and len(set(ln.letters)) == 5 and set(ln.letters) <= set(A.SLOAN_LETTERS)
        assert ln.letter_height_arcmin == pytest.approx(5.0 * 10 ** ln.logmar)
        assert ln.letter_height_px == pytest.approx(ln.letter_height_arcmin / 60.0 * 60.0)
    assert A.chart_lines(medium) == lines                          # fixed seed
    assert [ln.letters for ln in A.chart_lines(medium, seed=1)] != [ln.letters for ln in lines]
    assert A.snellen(0.0) == "20/20" and A.snellen(0.3) == "20/40" and A.snellen(1.0) == "20/200"
    for bad in ({"top_logmar": 0.25}, {"top_logmar": 0.0, "bottom_logmar": 0.5}, {"bottom_logmar": float("nan")}):
        with pytest.raises(ValidationError):
            A.chart_lines(medium, **bad)


# ---------------------------------------------------------------- 1. calibration

@pytest.mark.parametrize("pupil_mm", [3.0, 4.0])
def test_calibration_emmetrope_reads_logmar_0(fine, pupil_mm):
    """Emmetropic eye, 3-4 mm pupil, a display fine enough for every line: logMAR 0 (20/20)."""
    score = A.simulated_acuity(eye(0.0, pupil_mm), fine, AT_INFINITY)
    assert score.limit == "letters"                                # the eye, not the display, stops it
    assert -0.1 <= score.logmar <= 0.1
    assert -0.1 <= score.threshold_logmar <= 0.1
    assert all(s.proportion_correct is not None for s in score.lines)   # every line drawable at 120 ppd


def test_noise_is_per_solid_angle_not_per_pixel(fine, medium):
    """The same eye at 60 and 120 ppd: the same threshold (the display only matters by what it draws)."""
    e = eye(-1.0)
    thresholds = [A.simulated_acuity(e, d, AT_INFINITY, bottom_logmar=0.1).threshold_logmar for d in (medium, fine)]
    assert abs(thresholds[0] - thresholds[1]) < 0.03, thresholds
    per_pixel = A.Observer(noise_contrast_arcmin=A.NOISE_CONTRAST_ARCMIN * 2.0)   # 120 ppd with 60 ppd's pixel noise
    doubled = A.simulated_acuity(e, fine, AT_INFINITY, observer=per_pixel, bottom_logmar=0.1).threshold_logmar
    assert doubled > thresholds[1] + 0.1                           # the check can see a per-pixel noise


# ---------------------------------------------------------------- 2. the published defocus relation

@pytest.fixture(scope="module")
def defocus_scores(medium):
    return {d: A.simulated_acuity(eye(-d), medium, AT_INFINITY, bottom_logmar=0.0) for d in (0.0, 0.5, 1.0, 2.0)}


@pytest.mark.parametrize("blur_D", [1.0, 2.0])
def test_defocus_matches_blendowske_2015(defocus_scores, blur_D):
    """Myopic defocus, display at infinity, 4 mm pupil: the 60 % threshold within 0.25 logMAR of
    MAR = MAR_0 (1 + b^2) (Blendowske 2015) from the calibrated emmetrope's threshold."""
    score = defocus_scores[blur_D]
    assert score.limit == "letters"
    assert abs(score.threshold_logmar - blendowske_logmar(blur_D)) <= 0.25, score.threshold_logmar
    assert abs(score.logmar - (0.0 + math.log10(1.0 + blur_D ** 2))) <= 0.25   # the chart reading, from 0.0


def test_acuity_worsens_monotonically_with_defocus(defocus_scores):
    readings = [defocus_scores[d].logmar for d in (0.0, 0.5, 1.0, 2.0)]
    assert readings == sorted(readings) and readings[0] < readings[-1], readings
    thresholds = [defocus_scores[d].threshold_logmar for d in (0.5, 1.0, 2.0)]
    assert thresholds[0] < thresholds[1] < thresholds[2], thresholds
    assert defocus_scores[0.0].logmar <= 0.1                       # 60 ppd: pixel-limited near 0.0


# ---------------------------------------------------------------- 3. lines below the display's pixels

def test_lines_below_the_pixels_are_marked_and_not_scored():
    desktop = get_display("desktop")                                # 44.9 ppd: logMAR 0.1 letters are 4.7 px
    lines = A.chart_lines(desktop)
    drawable = [ln.logmar for ln in lines if ln.displayable]
    assert drawable == [round(1.0 - 0.1 * i, 1) for i in range(9)]  # +1.0 .. +0.2
    assert all((ln.letter_height_px >= 5.0) == ln.displayable for ln in lines)
    e = eye(0.0)
    kernel = build_kernel(e, desktop, AT_INFINITY)
    chart = A.build_chart(desktop, kernel.size, top_logmar=0.5)
    assert [s is None for s in chart.sheets] == [not ln.displayable for ln in chart.lines]
    score = A.score_acuity(chart, chart.targets, kernel, desktop, A.Observer(trials_per_letter=50))
    below = [s for s in score.lines if not s.line.displayable]
    assert below and all(s.proportion_correct is None and s.read is None and s.seen_lms is None for s in below)
    assert score.limit == "pixels" and score.logmar == 0.2          # the display stops the emmetrope at 20/32
    assert score.as_dict()["lines"][-1]["below_display_pixels"] is True
    shown = list(chart.targets)
    shown[-1] = np.ones((8, 8, 3), np.float32)                      # an image for a line that cannot be drawn
    with pytest.raises(ValidationError, match="below the display's pixels"):
        A.score_acuity(chart, shown, kernel, desktop)
    with pytest.raises(ValidationError, match="display's pixels"):
        A.line_sheet(chart.lines[-1], kernel.size)


def test_top_line_not_read_gives_no_acuity():
    quest2 = get_display("quest2")
    score = A.simulated_acuity(eye(-5.0), quest2, top_logmar=0.6, observer=A.Observer(trials_per_letter=100))
    assert score.lines[0].read is False
    assert score.logmar is None and score.threshold_logmar is None and score.limit == "top"
    assert score.snellen == "worse than 20/80"


# ---------------------------------------------------------------- 4. correction and the command

def write_rx(path: Path, sphere_D: float) -> Path:
    right = {"sphere_D": sphere_D, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0}
    path.write_text(json.dumps({"schema": "vrcorrect.prescription/1", "right": right, "left": right}))
    return path


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory):
    """``vrcorrect acuity`` for a 1 D myope on the desktop preset, display at infinity, with fast."""
    folder = tmp_path_factory.mktemp("acuity")
    rx = write_rx(folder / "rx.json", -1.0)
    rc, out, err = run_quiet("acuity", "--rx", rx, "--display", "desktop", "--distance-m", "inf", "--methods", "fast",
                             "--top-logmar", "0.8", "--bottom-logmar", "0.2", "--trials", "200",
                             "--json", folder / "a.json", "--png", folder / "a.png")
    return rc, out, err, folder


def test_fast_does_not_worsen_acuity_and_json_has_the_keys(fast_run):
    rc, out, err, folder = fast_run
    assert rc == 0, err
    doc = json.loads((folder / "a.json").read_text())
    assert {"uncorrected_logmar", "fast_logmar", "glasses_logmar", "noise_contrast_arcmin"} <= set(doc)
    assert doc["noise_contrast_arcmin"] == A.NOISE_CONTRAST_ARCMIN
    assert doc["uncorrected_logmar"] is not None and doc["uncorrected_logmar"] >= 0.3   # 1 D blurs the desktop chart
    assert doc["fast_logmar"] <= doc["uncorrected_logmar"]
    un, fa = doc["methods"]["uncorrected"], doc["methods"]["fast"]
    assert fa["threshold_logmar"] <= un["threshold_logmar"]
    assert [ln["logmar"] for ln in un["lines"]] == [0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2]
    assert all(0.0 <= ln["proportion_correct"] <= 1.0 for ln in fa["lines"])
    assert doc["glasses_logmar"] <= doc["uncorrected_logmar"]          # glasses are the correction's target
    assert doc["display"]["name"] == "desktop" and doc["viewing_distance_m"] is None
    assert f"uncorrected {doc['uncorrected_logmar']:.2f} (" in out and " -> fast " in out


def test_sharp_template_observer_is_reported_and_never_beats_the_ideal_one(fast_run):
    """The observer who knows only sharp letters reads no better than the one who knows its blur."""
    rc, out, _, folder = fast_run
    doc = json.loads((folder / "a.json").read_text())
    assert {"uncorrected_logmar_sharp_templates", "fast_logmar_sharp_templates"} <= set(doc)
    for method in ("uncorrected", "fast"):
        ideal, sharp = doc["methods"][method]["lines"], doc["methods_sharp_templates"][method]["lines"]
        for a, b in zip(ideal, sharp):
            assert b["proportion_correct"] <= a["proportion_correct"] + 0.05, (method, a, b)
    assert "sharp-template observer" in out


def test_one_observer_for_an_eye_that_needs_no_glasses(medium):
    """With no refractive error the glasses change nothing: both observers read the same."""
    from vrcorrect.studies.acuity_chart import measure_acuity

    r = measure_acuity(eye(0.0), medium, (), AT_INFINITY, top_logmar=0.3, bottom_logmar=0.0,
                       observer=A.Observer(trials_per_letter=100))
    assert [s.proportion_correct for s in r.scores["none"].lines] == pytest.approx(
        [s.proportion_correct for s in r.sharp_scores["none"].lines], abs=0.02)
    with pytest.raises(ValidationError, match="template_views"):
        A.score_acuity(r.chart, r.chart.targets, r.kernel, medium, template_views=[None])


def test_panel_is_a_png_with_a_column_per_method(fast_run):
    from PIL import Image

    rc, _, _, folder = fast_run
    with Image.open(folder / "a.png") as im:
        assert im.format == "PNG" and im.mode == "RGB"
        w, h = im.size
        rgb = np.asarray(im)
    assert w > 3 * 375 and h > 200                                  # uncorrected, fast, with glasses
    green = (rgb[..., 1] > 120) & (rgb[..., 0] < 60) & (rgb[..., 2] < 120)
    assert green.sum() > 100                                        # the last line read is marked


def test_json_to_stdout_is_pure_json(tmp_path, capsys):
    rx = write_rx(tmp_path / "rx.json", -1.0)
    # the form: --json with no file prints the readings (as does --json -)
    rc, out, err = run(capsys, "acuity", "--rx", rx, "--display", "quest2", "--trials", "50", "--methods", "wiener",
                       "--json")
    assert rc == 0, err
    doc = json.loads(out)
    assert {"uncorrected_logmar", "wiener_logmar"} <= set(doc)
    assert "uncorrected" in err                                     # the table went to stderr
    assert os.listdir(tmp_path) == ["rx.json"]


@pytest.mark.parametrize("extra, phrase", [
    (("--methods", "magic"), "methods"),
    (("--methods", "fast", "--json", "out.txt"), "--json"),
    (("--png", "out.jpg"), "--png"),
    (("--rx", "missing.json"), "missing.json"),
    (("--top-logmar", "0.25"), "top_logmar"),
    (("--json", "exists.json"), "exists"),
    (("--png", "exists.png"), "exists"),
])
def test_cli_errors_are_one_line_exit_2_and_no_output(tmp_path, capsys, monkeypatch, extra, phrase):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "exists.json").write_text("{}")
    (tmp_path / "exists.png").write_bytes(b"not a png")
    before = sorted(os.listdir(tmp_path))
    rc, out, err = run(capsys, "acuity", "--display", "desktop", *extra)
    assert rc == 2
    assert "Traceback" not in err + out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vrcorrect: error:") and phrase in lines[0], err
    assert sorted(os.listdir(tmp_path)) == before
    assert (tmp_path / "exists.json").read_text() == "{}"


# ---------------------------------------------------------------- 5. determinism

def test_fixed_seed_gives_the_same_reading_and_another_seed_other_trials():
    quest2 = get_display("quest2")
    e = eye(-1.5)
    kernel = build_kernel(e, quest2)
    chart = A.build_chart(quest2, kernel.size)

    def read(seed):
        s = A.score_acuity(chart, chart.targets, kernel, quest2, A.Observer(trials_per_letter=100, seed=seed))
        return s.logmar, s.threshold_logmar, [ln.proportion_correct for ln in s.lines]

    first, again, other = read(0), read(0), read(1)
    assert first == again
    assert first[2] != other[2]
    rebuilt = A.build_chart(quest2, kernel.size)                    # the chart's letters are fixed too
    assert [s.image.tobytes() for s in rebuilt.sheets if s] == [s.image.tobytes() for s in chart.sheets if s]


def test_observer_rejects_bad_settings():
    for bad in ({"noise_contrast_arcmin": 0.0}, {"trials_per_letter": 0}, {"criterion": 0.05}, {"seed": -1}):
        with pytest.raises(ValidationError):
            A.Observer(**bad)
    with pytest.raises(ValidationError, match="pixels_per_degree"):
        d = get_display("quest2")
        k = build_kernel(eye(0.0), d)
        other = dataclasses.replace(d, pixels_per_degree=30.0)
        A.score_acuity(A.build_chart(other, k.size, 1.0, 1.0), [None], k, other)
