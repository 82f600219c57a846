"""The guard (``vrcorrect correct --guard RHO``): the correction blended towards the picture until the
eyes with the sphere 0.5 D off see at most RHO times none's objective; with ``--guard-measure
lightness``, a lightness-like error, over those eyes and the prescribed eye at 2.5 to 5.5 mm."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps.cli import main
from vrcorrect.physics.robust import design_eye
from vrcorrect.solvers import make_problem, objective, solve
from vrcorrect.solvers.guard import LIGHTNESS_STEPS, guard_blend, lightness_error
from vrcorrect.solvers.problem import make_design_problem
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx

SIZE = 48


def _picture() -> np.ndarray:
    from skimage import data, transform

    image = transform.resize(data.astronaut()[40:240, 140:340], (SIZE, SIZE), anti_aliasing=True)
    return decode(get_display("desktop"), (image * 255).round() / 255.0).astype(np.float32)


@pytest.fixture(scope="module")
def near_focus_case():
    """A -0.50 D eye of sphere alone on the desktop monitor at 3 mm, its one-eye ``fast`` correction, and
    the problems of the eyes with the sphere 0.5 D off (the eye nearer focus sees the correction worse
    than none by the objective: the case the guard is for)."""
    display = get_display("desktop")
    eye = EyeRx(sphere_D=-0.5, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0)
    target = _picture()
    design = design_eye(eye, display, 3.0, robust=False)
    shown = solve(make_design_problem(target, design), "fast").image
    guards = [design_eye(eye.with_changes(sphere_D=eye.sphere_D + s), display, 3.0, robust=False) for s in (-0.5, 0.5)]
    problems = [make_problem(target, g.nominal, g.nominal_reference) for g in guards]
    return target, shown, problems


def test_the_objective_of_a_blend_is_the_quadratic_the_guard_reads_off_three_points(near_focus_case):
    target, shown, problems = near_focus_case
    for problem in problems:
        f0, fh, f1 = (objective(target + b * (shown - target), problem) for b in (0.0, 0.5, 1.0))
        c = 2.0 * (f1 - 2.0 * fh + f0)
        g = 0.5 * (f1 - f0 - c)
        for b in (0.2, 0.7, 0.9):
            exact = objective((target + np.float32(b) * (shown - target)).astype(np.float32), problem)
            assert exact == pytest.approx(f0 + 2 * g * b + c * b * b, rel=1e-4, abs=1e-12)


@pytest.mark.parametrize("rho", [1.0, 1.25])
def test_the_guard_keeps_each_eye_within_rho_of_none_with_the_largest_weight(near_focus_case, rho):
    target, shown, problems = near_focus_case
    guarded = guard_blend(shown, target, problems, rho)
    assert max(guarded.ratios("before")) > 1.25          # the case is one the guard must act on
    assert 0.0 <= guarded.weight < 1.0
    assert max(guarded.ratios("after")) <= rho * (1 + 1e-5)
    after = [objective(guarded.image, p) / objective(target, p) for p in problems]
    assert np.allclose(after, guarded.ratios("after"), rtol=1e-6)
    # the largest such weight: a little more correction breaks the bound for one eye
    more = (target + np.float32(min(guarded.weight + 0.03, 1.0)) * (shown - target)).astype(np.float32)
    assert max(objective(more, p) / objective(target, p) for p in problems) > rho
    # and the blend is the picture moved towards the correction, in range
    assert guarded.image.min() >= 0.0 and guarded.image.max() <= 1.0
    assert np.allclose(guarded.image, target + guarded.weight * (shown - target), atol=1e-6)


def test_a_loose_guard_shows_the_correction_as_it_is(near_focus_case):
    target, shown, problems = near_focus_case
    guarded = guard_blend(shown, target, problems, 10.0)
    assert max(guarded.ratios("before")) <= 10.0
    assert guarded.weight == 1.0
    assert np.array_equal(guarded.image, shown)


def test_on_a_black_frame_any_light_is_harm_and_the_picture_is_shown(near_focus_case):
    """A black picture: none's objective is 0, so a correction that adds light (here: a grey) is blended
    back to black entirely; the ratio of a black frame's black correction is 1, not a division by 0."""
    _, _, problems = near_focus_case
    black = np.zeros((SIZE, SIZE, 3), np.float32)
    black_problems = [make_problem(black, p.kernel, p.reference_kernel) for p in problems]
    guarded = guard_blend(np.full_like(black, 0.2), black, black_problems, 1.25)
    assert guarded.weight == 0.0 and not guarded.image.any()
    same = guard_blend(black, black, black_problems, 1.0)
    assert same.weight == 1.0 and same.ratios("before") == (1.0, 1.0)


def test_a_white_frame_is_left_as_it_is(near_focus_case):
    """A white picture is its own best correction (nothing in range can sharpen a uniform field): the
    guard has nothing to blend."""
    _, _, problems = near_focus_case
    white = np.ones((SIZE, SIZE, 3), np.float32)
    white_problems = [make_problem(white, p.kernel, p.reference_kernel) for p in problems]
    guarded = guard_blend(white, white, white_problems, 1.0)
    assert guarded.weight == 1.0 and np.array_equal(guarded.image, white)


@pytest.mark.parametrize("rho", [0.99, float("nan"), float("inf")])
def test_a_factor_below_one_or_not_finite_is_refused(near_focus_case, rho):
    from vrcorrect.plumbing.errors import ValidationError

    target, shown, problems = near_focus_case
    with pytest.raises(ValidationError, match="guard.*finite factor of at least 1"):
        guard_blend(shown, target, problems, rho)


def test_the_lightness_error_sees_a_dark_grounds_error_the_objective_barely_weighs(near_focus_case):
    """The same error of light (0.01 of white, added to a third of the picture) on a dark and on a bright
    grey, seen by one eye against its own view of the grey (so that the image's border, dark to a wide
    blur, is the same in both): the objective, linear in light, weighs both alike; the lightness-like
    error weighs the dark one several times more, as the eye does."""
    _, _, problems = near_focus_case
    problem = problems[0]
    ratios = {}
    for name, level in (("dark", 0.02), ("bright", 0.8)):
        flat = np.full((SIZE, SIZE, 3), level, np.float32)
        off = flat.copy()
        off[:, : SIZE // 3] += 0.01
        p = make_problem(flat, problem.kernel, problem.kernel)
        ratios[name] = (objective(off, p), lightness_error(off, p))
    assert ratios["dark"][0] == pytest.approx(ratios["bright"][0], rel=0.05)
    assert ratios["dark"][1] > 5 * ratios["bright"][1]
    assert lightness_error(np.full((SIZE, SIZE, 3), 0.5, np.float32),
                           make_problem(np.full((SIZE, SIZE, 3), 0.5, np.float32), problem.kernel,
                                        problem.kernel)) < 1e-12


def test_the_lightness_guard_keeps_each_eye_within_rho_of_none_at_the_largest_grid_weight(near_focus_case):
    target, shown, problems = near_focus_case
    guarded = guard_blend(shown, target, problems, 1.0, measure="lightness")
    assert guarded.measure == "lightness"
    assert max(guarded.ratios("before")) > 1.0           # the case is one the guard must act on
    assert 0.0 <= guarded.weight < 1.0
    assert round(guarded.weight * LIGHTNESS_STEPS) == pytest.approx(guarded.weight * LIGHTNESS_STEPS, abs=1e-9)
    after = [lightness_error(guarded.image, p) / lightness_error(target, p) for p in problems]
    assert max(after) <= 1.0 + 1e-5
    assert np.allclose(after, guarded.ratios("after"), rtol=1e-4)
    step = (target + np.float32(guarded.weight + 1.0 / LIGHTNESS_STEPS) * (shown - target)).astype(np.float32)
    assert max(lightness_error(step, p) / lightness_error(target, p) for p in problems) > 1.0
    assert np.allclose(guarded.image, target + guarded.weight * (shown - target), atol=1e-6)


def test_the_lightness_guard_blacks_out_light_added_to_black_and_leaves_white(near_focus_case):
    _, _, problems = near_focus_case
    for level, shown_level, weight in ((0.0, 0.2, 0.0), (1.0, 1.0, 1.0)):
        flat = np.full((SIZE, SIZE, 3), level, np.float32)
        flat_problems = [make_problem(flat, p.kernel, p.reference_kernel) for p in problems]
        guarded = guard_blend(np.full_like(flat, shown_level), flat, flat_problems, 1.0, measure="lightness")
        assert guarded.weight == weight
        assert np.array_equal(guarded.image, flat)


def _visible(image: np.ndarray, problem) -> float:
    """The visibility scale of what ``problem``'s eye sees of ``image``, by its own simulation."""
    from vrcorrect.vision.forward import simulate_lms
    from vrcorrect.vision.visibility import ViewingLight, visibility_error

    seen = simulate_lms(image, problem.kernel, "fft")[0]
    return visibility_error(seen, problem.target_lms, problem.kernel.matrix.sum(axis=1),
                            ViewingLight.of(get_display("desktop")))


@pytest.mark.parametrize("rho", [1.0, 1.25])
def test_the_visibility_guard_keeps_each_eye_within_rho_of_none_with_the_largest_weight(near_focus_case, rho):
    from vrcorrect.vision.visibility import ViewingLight

    target, shown, problems = near_focus_case
    guarded = guard_blend(shown, target, problems, rho, measure="visibility",
                          viewing=ViewingLight.of(get_display("desktop")))
    assert guarded.measure == "visibility" and max(guarded.ratios("before")) > rho
    assert 0.0 < guarded.weight < 1.0
    none = [_visible(target, p) for p in problems]
    assert np.allclose(none, guarded.none, rtol=1e-4)
    after = [_visible(guarded.image, p) / n for p, n in zip(problems, none)]
    assert max(after) <= rho * (1 + 1e-4)
    assert np.allclose(after, guarded.ratios("after"), rtol=1e-4)
    more = (target + np.float32(min(guarded.weight + 0.03, 1.0)) * (shown - target)).astype(np.float32)
    assert max(_visible(more, p) / n for p, n in zip(problems, none)) > rho


def test_the_visibility_guard_blacks_out_light_added_to_black_leaves_white_and_needs_the_viewing(near_focus_case):
    from vrcorrect.plumbing.errors import ValidationError
    from vrcorrect.vision.visibility import ViewingLight

    target, shown, problems = near_focus_case
    light = ViewingLight.of(get_display("desktop"))
    for level, shown_level, weight in ((0.0, 0.2, 0.0), (1.0, 1.0, 1.0)):
        flat = np.full((SIZE, SIZE, 3), level, np.float32)
        flat_problems = [make_problem(flat, p.kernel, p.reference_kernel) for p in problems]
        guarded = guard_blend(np.full_like(flat, shown_level), flat, flat_problems, 1.0, measure="visibility",
                              viewing=light)
        assert guarded.weight == weight
        assert np.array_equal(guarded.image, flat)
    with pytest.raises(ValidationError, match="viewing"):
        guard_blend(shown, target, problems, 1.0, measure="visibility")


def test_an_unknown_measure_is_refused(near_focus_case):
    from vrcorrect.plumbing.errors import ValidationError

    target, shown, problems = near_focus_case
    with pytest.raises(ValidationError, match="measure.*objective, lightness, visibility"):
        guard_blend(shown, target, problems, 1.0, measure="jod")


@pytest.fixture()
def sphere_alone(tmp_path: Path) -> tuple[Path, Path]:
    from skimage import data, transform

    image = transform.resize(data.astronaut()[40:240, 140:340], (SIZE, SIZE), anti_aliasing=True)
    picture = tmp_path / "in.png"
    Image.fromarray((image * 255).round().astype(np.uint8)).save(picture)
    rx = tmp_path / "rx.json"
    eye = {"sphere_D": -0.5, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0, "accommodation_D": 0.0}
    rx.write_text(json.dumps({"schema": "vrcorrect.prescription/1", "right": eye, "left": eye}))
    return picture, rx


@pytest.mark.parametrize("value", ["0.5", "11", "nan", "loose"])
def test_correct_refuses_a_bad_guard_before_any_work(tmp_path, sphere_alone, value, capsys):
    picture, rx = sphere_alone
    out = tmp_path / "out.png"
    assert main(["correct", str(picture), "-o", str(out), "--rx", str(rx), "--guard", value]) == 2
    err = capsys.readouterr().err
    assert "--guard" in err and value in err and "from 1 to 10" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.cvvdp                                   # --report judges what the eye sees with ColorVideoVDP
def test_correct_with_a_guard_reports_the_blend_and_without_one_says_why_it_might_be_wanted(tmp_path, sphere_alone,
                                                                                             capsys):
    """The -0.50 D eye of sphere alone at 3 mm: with --guard 1 the report holds the weight and each guard
    eye's objective over none's (at most 1 after), and the output says it; without --guard, the command
    notes that an eye of sphere alone may see the correction worse than none, and names the flag."""
    picture, rx = sphere_alone
    out, report = tmp_path / "out.png", tmp_path / "r.json"
    assert main(["correct", str(picture), "-o", str(out), "--rx", str(rx), "--pupil", "3", "--robust", "off",
                 "--guard", "1", "--report", str(report)]) == 0
    said = capsys.readouterr()
    guard = json.loads(report.read_text())["guard"]
    assert guard["rho"] == 1.0 and 0.0 <= guard["weight"] < 1.0
    assert max(guard["objective_ratio_before"]) > 1.0 and max(guard["objective_ratio_after"]) <= 1.0 + 1e-5
    # at 1, an eye whose error rises from the picture's at once allows no part of the correction
    assert guard["weight"] == 0.0 and "guard 1: the picture shown uncorrected" in said.out
    assert "--guard" not in said.err
    assert main(["correct", str(picture), "-o", str(tmp_path / "plain.png"), "--rx", str(rx), "--pupil", "3",
                 "--robust", "off"]) == 0
    said = capsys.readouterr()
    assert "eye of sphere alone" in said.err and "--guard 1.1 --guard-measure visibility" in said.err
    plain = np.asarray(Image.open(tmp_path / "plain.png"), np.float64)
    guarded = np.asarray(Image.open(out), np.float64)
    source = np.asarray(Image.open(picture), np.float64)
    # the guarded image lies between the picture and the plain correction (sRGB code values: not exactly)
    assert np.abs(guarded - source).mean() < np.abs(plain - source).mean()


@pytest.mark.cvvdp                                   # a clip's --report scores it with ColorVideoVDP
@pytest.mark.parametrize("measure", ["objective", "lightness", "visibility"])
def test_a_clip_is_guarded_frame_by_frame_as_each_still_is(tmp_path, sphere_alone, capsys, measure):
    """Each frame of a clip corrected with --guard is the guarded still of that frame; the report gives
    each frame's weight and the output how many frames were blended."""
    picture, rx = sphere_alone
    source = np.asarray(Image.open(picture))
    clip = tmp_path / "clip"
    clip.mkdir()
    for i in range(3):
        Image.fromarray(np.roll(source, 3 * i, axis=1)).save(clip / f"shot{i + 1}.png")
    common = ["--rx", str(rx), "--pupil", "3", "--robust", "off", "--guard", "1", "--guard-measure", measure]
    out, report = tmp_path / "shown", tmp_path / "r.json"
    assert main(["correct", str(clip), "-o", str(out), "--report", str(report), *common]) == 0
    written = json.loads(report.read_text())
    assert written["guard"]["measure"] == measure
    frames = written["frames"]
    assert all(0.0 <= f["guard_weight"] < 1.0 for f in frames), frames
    assert "3 of 3 frames blended towards the picture" in capsys.readouterr().out
    assert main(["correct", str(clip / "shot2.png"), "-o", str(tmp_path / "still.png"), *common]) == 0
    assert np.array_equal(np.asarray(Image.open(out / "frame_00001.png")), np.asarray(Image.open(tmp_path / "still.png")))


def test_a_guard_measure_without_a_guard_is_refused(tmp_path, sphere_alone, capsys):
    picture, rx = sphere_alone
    out = tmp_path / "out.png"
    assert main(["correct", str(picture), "-o", str(out), "--rx", str(rx), "--guard-measure", "lightness"]) == 2
    err = capsys.readouterr().err
    assert "--guard-measure" in err and "lightness" in err and "only with --guard" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


@pytest.mark.cvvdp                                   # --report judges what the eye sees with ColorVideoVDP
@pytest.mark.parametrize("measure", ["lightness", "visibility"])
def test_correct_with_a_pupil_guard_reports_six_guard_eyes_within_none(tmp_path, sphere_alone, capsys, measure):
    """--guard 1 --guard-measure lightness or visibility: the six guard eyes (the sphere 0.5 D off either
    way, then the pupils 2.5, 3, 4, 5.5 mm) each see at most none's error after the blend; lightness's
    weight is on its grid; the eye as designed (3 mm, the prescribed sphere) sees the correction better
    than none before any blend."""
    picture, rx = sphere_alone
    out, report = tmp_path / "out.png", tmp_path / "r.json"
    assert main(["correct", str(picture), "-o", str(out), "--rx", str(rx), "--pupil", "3", "--robust", "off",
                 "--guard", "1", "--guard-measure", measure, "--report", str(report)]) == 0
    said = capsys.readouterr().out
    guard = json.loads(report.read_text())["guard"]
    assert guard["measure"] == measure and guard["pupils_mm"] == [2.5, 3.0, 4.0, 5.5]
    assert guard["sphere_offsets_D"] == [-0.5, 0.5]
    before, after = guard[f"{measure}_ratio_before"], guard[f"{measure}_ratio_after"]
    assert len(before) == len(after) == 6
    assert before[3] < 1.0                           # the 3 mm eye: the one designed for
    assert max(before) > 1.0 and max(after) <= 1.0 + 1e-6
    assert 0.0 <= guard["weight"] < 1.0
    if measure == "lightness":
        assert (guard["weight"] * 40) == pytest.approx(round(guard["weight"] * 40))
    words = {"lightness": "lightness-like error", "visibility": "visibility scale"}[measure]
    assert words in said and "a pupil of 2.5 to 5.5 mm" in said


def test_the_guard_says_the_picture_is_shown_uncorrected_when_no_part_of_the_correction_is_kept():
    from vrcorrect.apps.correct import _guard_text
    from vrcorrect.solvers.guard import Guarded

    image = np.zeros((2, 2, 3), np.float32)
    none = Guarded(image=image, weight=0.0, before=(1.4, 0.8), after=(1.0, 1.0), none=(1.0, 1.0), measure="lightness")
    text = _guard_text(1.0, none)
    assert "the picture shown uncorrected" in text and "1.40 x none's error by the lightness-like error" in text
    part = Guarded(image=image, weight=0.5, before=(1.4, 0.8), after=(1.1, 0.9), none=(1.0, 1.0))
    text = _guard_text(1.25, part)
    assert "shown 0.50 of the way" in text and "by the objective" in text and "now 1.10 x" in text


def test_the_commands_offer_exactly_the_guards_measures_and_name_each_in_words():
    """The parsers keep their own copy of the measures (start-up loads no solver); this keeps them in step."""
    import argparse

    from vrcorrect.apps.cli import build_parser
    from vrcorrect.apps.correct import GUARD_WORDS
    from vrcorrect.solvers.guard import GUARD_MEASURES

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    offered = next(a for a in sub.choices["correct"]._actions if a.dest == "guard_measure")
    assert tuple(offered.choices) == GUARD_MEASURES and offered.default == GUARD_MEASURES[0]
    assert tuple(GUARD_WORDS) == GUARD_MEASURES
    with pytest.raises(SystemExit):
        build_parser().parse_args(["correct", "in.png", "-o", "out.png", "--guard", "1", "--guard-measure", "jod"])
