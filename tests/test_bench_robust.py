"""``vrcorrect bench robust`` (the eye as it is against the eye as modelled), run small: it sweeps the
eyes it says, scores every method on each, and writes its section; and the 4 mm design it replaces
is worse than the default through a small pupil."""

from __future__ import annotations

import json
import math

import numpy as np

from vrcorrect.studies.bench.robust import METHODS, run_robust_bench


def test_a_small_sweep_scores_every_method_and_writes_its_section(tmp_path):
    out = tmp_path / "bench.md"
    small = dict(displays=("quest2",), images=("page",), boundary=False, size=64, seen_pupils=(2.5, 3.0),
                 seen_spheres=(0.5,))
    run_robust_bench(out, write=False, plot=tmp_path / "sweep.png", **small)
    assert not out.exists() and not (tmp_path / "sweep.png").exists()        # --no-write: nothing written
    report = run_robust_bench(out, plot=tmp_path / "sweep.png", json_out=tmp_path / "r.json", **small)
    assert (tmp_path / "sweep.png").stat().st_size > 0
    text = out.read_text()
    assert "<!-- bench:robust -->" in text and "### The checks" in text and "quest2, page" in text
    case = report["cases"][0]
    assert [(r["pupil_mm"], r["sphere_offset_D"]) for r in case["rows"]] == [
        (2.5, 0.0), (3.0, 0.0), (case["pupil_mm"], 0.5)]
    for r in case["rows"]:
        assert set(r["scores"]) == set(METHODS)
        assert all(math.isfinite(v) for s in r["scores"].values() for v in s.values())
    at = {r["pupil_mm"]: r["scores"] for r in case["rows"]}
    gain = {m: at[2.5][m]["jod"] - at[2.5]["none"]["jod"] for m in METHODS}
    assert gain["4 mm"] < gain["default"]
    assert json.loads((tmp_path / "r.json").read_text())["cases"][0]["checks"]["share_at_3mm"] is not None


def test_the_held_out_images_include_light_text_on_a_dark_ground():
    from vrcorrect.studies.bench.robust import IMAGES, held_out_image

    assert "darktext" in IMAGES
    codes = held_out_image("darktext", 64)
    assert codes.shape == (64, 64, 3)
    assert float(np.median(codes)) < 0.3                       # a dark ground
    assert float(codes.max()) > 0.85                           # light strokes
    assert float(np.mean(codes > 0.5)) < 0.3                   # strokes, not a light page


def test_a_sweep_for_ones_own_eye_and_age_designs_for_it_and_says_so(tmp_path):
    """``bench robust --rx``: the sweep's eye and age are the prescription's.  The pupil from the light
    narrows with age (Watson & Yellott), and the designs are for that eye, not the bench's."""
    from vrcorrect.specs.prescription import EyeRx

    hyperope = EyeRx(sphere_D=3.0, cylinder_D=-1.0, axis_deg=90.0, pupil_diameter_mm=4.0)
    small = dict(displays=("quest2",), images=("page",), boundary=False, size=64, seen_pupils=(3.0,),
                 seen_spheres=(0.5,))
    young = run_robust_bench(tmp_path / "a.md", write=False, eye=hyperope, age_years=20, **small)
    old = run_robust_bench(tmp_path / "b.md", write=False, eye=hyperope, age_years=80, **small)
    assert "+3.00/-1.00 x 90, age 80" in old["markdown"] and "-2.00/-1.00" not in old["markdown"]
    assert old["cases"][0]["pupil_mm"] < young["cases"][0]["pupil_mm"] - 0.2
    ours = run_robust_bench(tmp_path / "c.md", write=False, age_years=80, **small)   # the bench's own myope
    jods = [[r["scores"]["default"]["jod"] for r in rep["cases"][0]["rows"]] for rep in (old, ours)]
    assert not np.allclose(jods[0], jods[1], atol=1e-3)


def test_bench_robust_sweeps_the_eye_asked_for(tmp_path):
    """``bench robust --rx F --eye left`` sweeps the left eye of F, at F's age (right by default)."""
    from vrcorrect.apps.bench import _robust_eye
    from vrcorrect.apps.cli import build_parser

    rx = tmp_path / "rx.json"
    rx.write_text(json.dumps({"schema": "vrcorrect.prescription/1", "age_years": 61,
                              "right": {"sphere_D": -0.5, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0},
                              "left": {"sphere_D": 1.25, "cylinder_D": -0.75, "axis_deg": 15, "pupil_diameter_mm": 4.0}}))
    for argv, sphere in ((["--eye", "left"], 1.25), ([], -0.5)):
        args = build_parser().parse_args(["bench", "robust", "--rx", str(rx), "--no-write", *argv])
        got = _robust_eye(args)
        assert got["eye"].sphere_D == sphere and got["age_years"] == 61
    assert _robust_eye(build_parser().parse_args(["bench", "robust", "--no-write"])) == {}    # the bench's eye


def test_an_eye_the_learned_model_does_not_take_leaves_its_column_empty_and_says_why(tmp_path):
    """``bench robust --rx`` with an eye outside the shipped model's range (cylinder -3.5 D; it was
    trained on -3 to 0): the sweep runs, the learned column is empty, and the case says why."""
    from vrcorrect.specs.prescription import EyeRx

    strong = EyeRx(sphere_D=-0.5, cylinder_D=-3.5, axis_deg=0.0, pupil_diameter_mm=4.0)
    rep = run_robust_bench(tmp_path / "a.md", write=False, eye=strong, displays=("quest2",), images=("page",),
                           boundary=False, size=64, seen_pupils=(3.0,), seen_spheres=(0.5,))
    case = rep["cases"][0]
    assert all("learned" not in r["scores"] and "default" in r["scores"] for r in case["rows"])
    assert "learned: not run" in case["design"] and "cylinder_D" in case["design"]
    assert case["checks"]["least_learned"] is None and case["checks"]["share_at_3mm_learned"] is None
    assert not math.isnan(case["checks"]["least_default"])
    json.dumps(case["checks"], allow_nan=False)                   # --json: strict JSON, no NaN
    assert "nan" not in rep["markdown"] and "+-" not in rep["markdown"]


def test_the_boundary_gap_is_not_shared_out_of_no_gain():
    """An eye in focus at the display: the exact expectation gains nothing over none (its solution ended a
    little above none's tiny objective in a run of 2026-12-05, where the share read -1.4e24 %)."""
    from vrcorrect.studies.bench.robust_boundary import gap_left

    assert gap_left({"none": 2.052e-07, "effective": 2.052e-07, "exact": 2.323e-07}) == "- (no gain)"
    assert gap_left({"none": 1.0, "effective": 1.0, "exact": 1.0}) == "- (no gain)"
    assert gap_left({"none": 0.0005, "effective": 0.00021, "exact": 0.0002}) == "3.3 %"


def test_an_eye_in_focus_at_the_display_is_swept_without_dividing_by_zero(tmp_path):
    """A young myope at the monitor accommodates into focus: no correction has anything to gain, none's
    objective is 0, and the sweep still writes its table (the ratio marked in focus)."""
    from vrcorrect.specs.prescription import EyeRx

    young = EyeRx(sphere_D=-1.5, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0, accommodation_D=3.0)
    rep = run_robust_bench(tmp_path / "a.md", write=False, eye=young, displays=("desktop",), images=("page",),
                           boundary=False, size=64, seen_pupils=(3.0,), seen_spheres=(0.5,))
    rows = rep["cases"][0]["rows"]
    assert any(r["scores"]["none"]["objective"] == 0.0 for r in rows)
    assert "- (in focus)" in rep["markdown"]
