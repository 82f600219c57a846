"""``vrcorrect evaluate``: the paper's five refractive problems, the outputs and their safety.

One small evaluation (48 px, 2 images, paper and fast) is run once per module
and inspected by several tests.
"""

from __future__ import annotations

import argparse
import csv
import math

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps import evaluate as ev_cmd
from vrcorrect.studies import evaluation as ev
from vrcorrect.plumbing import images
from vrcorrect.plumbing.errors import InputError, ValidationError

SIZE = 48
METHODS = ("paper", "fast")


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="vrcorrect")
    sub = ap.add_subparsers(dest="command")
    ev_cmd.add_parser(sub)
    return ap


def _images() -> list[tuple[str, np.ndarray]]:
    imgs = dict(images.bundled_images(SIZE))
    return [("astronaut", imgs["astronaut"]), ("siemens_star", imgs["siemens_star"])]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("evaluation")
    result = ev.run_evaluation(out, _images(), "desktop", methods=METHODS, size=SIZE, progress=False,
                               acuity=False)
    return out, result


# ---------------------------------------------------------------- prescriptions

EXPECTED_MERIDIANS = {
    "myopia": (-1.5, -1.5),
    "hyperopia": (1.5, 1.5),
    "myopic_astig": (0.0, -1.5),
    "hyperopic_astig": (1.5, 0.0),
    "mixed_astig": (0.75, -0.75),
}


@pytest.mark.parametrize("rx", ev.PRESCRIPTIONS, ids=lambda rx: rx.key)
def test_principal_meridians_from_power_vectors(rx):
    key, title, s, c, axis = rx                       # a plain tuple as documented
    m = s + c / 2
    j0 = -(c / 2) * math.cos(math.radians(2 * axis))
    j45 = -(c / 2) * math.sin(math.radians(2 * axis))
    j = math.hypot(j0, j45)
    assert (m + j, m - j) == pytest.approx(EXPECTED_MERIDIANS[key], abs=1e-12)
    assert ev.principal_meridians_D(rx) == pytest.approx(EXPECTED_MERIDIANS[key], abs=1e-12)
    assert c <= 0                                     # minus-cylinder form
    eye = ev.prescription_eye(rx)
    assert eye.pupil_diameter_mm == 4.0 and eye.accommodation_D == 0.0


def test_five_distinct_problems():
    assert [rx.key for rx in ev.PRESCRIPTIONS] == list(EXPECTED_MERIDIANS)
    # mixed astigmatism: one meridian myopic, the other hyperopic
    hi, lo = ev.principal_meridians_D(ev.PRESCRIPTIONS[-1])
    assert hi > 0 > lo


# ---------------------------------------------------------------- images

def test_bundled_images_are_square_srgb():
    imgs = images.bundled_images(SIZE)
    names = [n for n, _ in imgs]
    assert {"text", "siemens_star", "colour_bars"} <= set(names)
    assert len(names) == len(set(names)) >= 4
    for name, img in imgs:
        assert img.shape == (SIZE, SIZE, 3) and img.dtype == np.float32, name
        assert 0.0 <= img.min() and img.max() <= 1.0


def test_prepare_image_centre_crops():
    wide = np.zeros((20, 60, 3), np.float32)
    wide[:, 20:40] = 1.0                              # the centre square is white
    out = images.prepare_image(wide, 16)
    assert out.shape == (16, 16, 3)
    assert out.min() > 0.99


def test_folder_images(tmp_path):
    Image.fromarray(np.full((30, 40, 3), 200, np.uint8)).save(tmp_path / "b.png")
    Image.fromarray(np.full((50, 20, 3), 10, np.uint8)).save(tmp_path / "a.jpg")
    (tmp_path / "notes.txt").write_text("not an image")
    imgs = images.folder_images(tmp_path, 24)
    assert [n for n, _ in imgs] == ["a", "b"]
    assert all(img.shape == (24, 24, 3) for _, img in imgs)


def test_images_folder_empty_or_missing_is_a_clear_error(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no PNG or JPEG"):
        images.folder_images(empty, SIZE)
    with pytest.raises(InputError, match="no such folder"):
        images.folder_images(tmp_path / "missing", SIZE)
    out = tmp_path / "out"
    args = _parser().parse_args(["evaluate", "--images", str(empty), "--out", str(out), "--size", str(SIZE)])
    with pytest.raises(InputError, match="no PNG or JPEG"):
        args.func(args)
    assert not out.exists()                           # nothing written


# ---------------------------------------------------------------- outputs

def test_outputs_and_row_count(run):
    out, result = run
    n_rows = 2 * len(ev.PRESCRIPTIONS) * (len(METHODS) + 1)
    assert len(result["rows"]) == n_rows
    assert (out / "results.csv").is_file() and (out / "results.md").is_file()
    panels = sorted((out / "panels").glob("*.png"))
    assert len(panels) == 2 * len(ev.PRESCRIPTIONS)
    assert (out / "panels" / "astronaut_mixed_astig.png") in panels
    assert len(result["summary"]) == len(ev.PRESCRIPTIONS) * (len(METHODS) + 1)


def test_csv_parses_and_is_finite(run):
    out, _ = run
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * len(ev.PRESCRIPTIONS) * (len(METHODS) + 1)
    assert tuple(rows[0]) == ev.CSV_COLUMNS
    assert {r["method"] for r in rows} == {"none", *METHODS}
    assert {r["prescription"] for r in rows} == {rx.key for rx in ev.PRESCRIPTIONS}
    for r in rows:
        for k in ("flip", "ssim", "psnr", "objective", "flip_lms", "ssim_lms", "psnr_lms", "seconds"):
            assert math.isfinite(float(r[k])), (k, r)
        assert 0.0 <= float(r["flip"]) <= 1.0 and -1.0 <= float(r["ssim"]) <= 1.0
        assert 0.0 < float(r["jod"]) <= 10.0
        assert int(r["iterations"]) >= 0
        if r["method"] == "none":
            assert int(r["iterations"]) == 0
        if r["method"] == "paper":
            assert int(r["iterations"]) > 0


def test_markdown_has_machine_tables_and_verdicts(run):
    out, result = run
    text = (out / "results.md").read_text()
    from vrcorrect.studies.bench import machine_description

    assert machine_description() in text
    assert result["summary_markdown"] in text
    assert text.count("\n| astronaut |") == len(ev.PRESCRIPTIONS) * (len(METHODS) + 1)


def test_markdown_states_wins_against_no_correction(run):
    out, result = run
    text = (out / "results.md").read_text()
    assert "Against no correction" in text and "JOD ↑" in text
    assert len(result["wins"]) == len(ev.PRESCRIPTIONS)
    for line in result["wins"]:
        for m in METHODS:
            assert f"{m} beats it by JOD on " in line


def _row(image, rx, method, jod, flip):
    return {"image": image, "prescription": rx, "method": method, "jod": jod, "flip": flip}


def test_wins_and_disagreements_count_what_the_scores_say():
    rows = [_row("a", "myopia", "none", 7.0, 0.20), _row("a", "myopia", "fast", 7.5, 0.25),   # JOD yes, FLIP no
            _row("b", "myopia", "none", 6.0, 0.30), _row("b", "myopia", "fast", 6.4, 0.20),   # both yes
            _row("c", "myopia", "none", 8.0, 0.10), _row("c", "myopia", "fast", 7.9, 0.09)]   # JOD no, FLIP yes
    wins = ev._beats_uncorrected(rows, ["none", "fast"], acuity={"myopia": {"none": 0.5, "fast": 0.3}})
    assert len(wins) == 1
    assert "fast beats it by JOD on 2/3 images" in wins[0] and "by FLIP on 2/3" in wins[0]
    assert "acuity logMAR 0.5 -> 0.3" in wins[0]
    split = ev.disagreements(rows)
    assert [(d["image"], d["jod_gain"] > 0) for d in split] == [("a", True), ("c", False)]
    assert split[0]["jod_gain"] == pytest.approx(0.5) and split[0]["flip_gain"] == pytest.approx(-0.05)


def test_acuity_column_and_verdict(tmp_path, monkeypatch):
    """With acuity on, each problem's eye reads the chart: a logMAR per method in the table and the verdicts."""
    monkeypatch.setattr(ev, "PRESCRIPTIONS", ev.PRESCRIPTIONS[:1])          # myopia only: keep it quick
    result = ev.run_evaluation(tmp_path, _images()[:1], "desktop", methods=("fast",), size=24, progress=False)
    logmar = result["acuity"]["myopia"]
    assert set(logmar) == {"none", "fast", "none:sharp", "fast:sharp"}
    assert logmar["none"] is not None and logmar["none"] >= 0.3        # -1.5 D at infinity: well below 20/20
    assert "acuity logMAR ↓" in result["summary_markdown"]
    assert f"| myopia | none | {result['summary'][0]['jod']:.3f} | {logmar['none']:.1f} |" in result["summary_markdown"]
    assert "eye-chart acuity logMAR" in result["wins"][0]


def test_verdicts_when_conventional_runs(tmp_path):
    imgs = _images()[:1]
    result = ev.run_evaluation(tmp_path, imgs, "desktop", methods=("conventional", "fast"), size=32,
                               progress=False, acuity=False, solver_options={"conventional": {"max_iterations": 20}})
    assert len(result["verdicts"]) == len(ev.PRESCRIPTIONS)
    assert all("fast" in line and "conventional" in line for line in result["verdicts"])
    assert "\n".join(result["verdicts"]) in (tmp_path / "results.md").read_text()


def test_panels_have_the_layout_size(run):
    out, _ = run
    columns = 1 + 1 + len(METHODS)                    # target | uncorrected | paper | fast
    expected = ev.panel_size(SIZE, columns)
    assert expected[0] == columns * SIZE + (columns - 1) * 6
    for path in (out / "panels").glob("*.png"):
        with Image.open(path) as im:
            assert im.format == "PNG" and im.mode == "RGB"
            assert im.size == expected, path.name


def test_fast_objective_not_above_uncorrected(run):
    _, result = run
    rows = result["rows"]
    none = {(r["image"], r["prescription"]): r["objective"] for r in rows if r["method"] == "none"}
    fast = [r for r in rows if r["method"] == "fast"]
    assert len(fast) == len(none)
    for r in fast:
        assert r["objective"] <= none[(r["image"], r["prescription"])] * (1 + 1e-6), r


# ---------------------------------------------------------------- safety

def test_refuses_to_overwrite_without_force(run):
    out, _ = run
    files = [out / "results.csv", out / "results.md", *sorted((out / "panels").glob("*.png"))]
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files}
    with pytest.raises(InputError, match="--force"):
        ev.run_evaluation(out, _images(), "desktop", methods=METHODS, size=SIZE, progress=False)
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files} == before
    assert not [p for p in out.rglob(".*") if p.is_file()]   # no temporary files left


def test_force_overwrites(tmp_path):
    from vrcorrect.plumbing.charts import siemens_star

    img = [("star", siemens_star(16))]
    ev.run_evaluation(tmp_path, img, "desktop", methods=("fast",), size=16, progress=False, acuity=False)
    before = (tmp_path / "results.csv").stat().st_mtime_ns
    result = ev.run_evaluation(tmp_path, img, "desktop", methods=("fast",), size=16, progress=False, force=True,
                               acuity=False)
    assert (tmp_path / "results.csv").stat().st_mtime_ns >= before
    assert len(result["rows"]) == len(ev.PRESCRIPTIONS) * 2


def test_bad_arguments(tmp_path):
    img = _images()[:1]
    with pytest.raises(ValidationError, match="methods"):
        ev.run_evaluation(tmp_path, img, "desktop", methods=("magic",), progress=False)
    with pytest.raises(ValidationError, match="size"):
        ev.run_evaluation(tmp_path, img, "desktop", size=4, progress=False)
    with pytest.raises(ValidationError, match="display"):
        ev.run_evaluation(tmp_path, img, "no-such-display", progress=False)
    with pytest.raises(ValidationError, match="image name"):
        ev.run_evaluation(tmp_path, [("../evil", img[0][1])], "desktop", progress=False)
    assert not any(tmp_path.iterdir())                # nothing written


def test_parser_defaults():
    args = _parser().parse_args(["evaluate"])
    assert args.out == "evaluation" and args.size == 256 and args.display == "desktop"
    assert args.methods == ["paper", "fast"] and args.images is None and not args.force
    assert args.func is ev_cmd.cmd_evaluate


def test_a_bare_evaluate_leaves_out_the_slow_conventional_method_unless_asked():
    """Issue 26: a bare ``vrcorrect evaluate`` ran conventional's L-BFGS for some 40 minutes unasked."""
    assert "conventional" not in _parser().parse_args(["evaluate"]).methods
    assert "conventional" not in ev.DEFAULT_METHODS
    asked = _parser().parse_args(["evaluate", "--methods", "conventional", "paper", "fast"])
    assert asked.methods == ["conventional", "paper", "fast"]          # as given, as before


def test_command_prints_outputs_and_summary(tmp_path, capsys):
    folder = tmp_path / "imgs"
    folder.mkdir()
    Image.fromarray((np.indices((40, 40)).sum(0) % 2 * 255).astype(np.uint8)).save(folder / "checker.png")
    out = tmp_path / "out"
    args = _parser().parse_args(["evaluate", "--images", str(folder), "--out", str(out), "--size", "24",
                                 "--methods", "fast", "--no-acuity"])
    assert args.func(args) == 0
    printed = capsys.readouterr().out
    assert str(out / "results.csv") in printed
    assert "| prescription | method |" in printed
    assert (out / "panels" / "checker_myopia.png").is_file()
