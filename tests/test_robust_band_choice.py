"""The study tool of the robust band's choice (tools/robust_band_choice.py): its grey stand-ins, its
paper cap and its refusals, without solving anything."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    """tools/robust_band_choice.py as a module (tools/ is not a package; sys.path is left alone)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("robust_band_choice", ROOT / "tools" / "robust_band_choice.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


rbc = _tool()


def _page(paper: float) -> np.ndarray:
    """(64, 64, 3) linear light: paper at ``paper`` with one black stroke, 4 px wide, across it."""
    page = np.full((64, 64, 3), paper, np.float32)
    page[:, 30:34] = 0.0
    return page


def test_the_paper_cap_keeps_a_grey_page_at_its_paper_and_white_at_one():
    grey = rbc.paper_cap(_page(0.58), 1.0)
    assert grey.shape == (64, 64, 3) and grey.dtype == np.float32
    np.testing.assert_allclose(grey, 0.58, rtol=1e-6)           # the stroke too: paper within reach
    np.testing.assert_allclose(rbc.paper_cap(_page(0.58), 1.3), 0.754, rtol=1e-6)
    np.testing.assert_allclose(rbc.paper_cap(_page(0.9), 1.3), 1.0)   # never above white
    wide = _page(0.58)
    wide[:, 16:48] = 0.0                                         # a stroke wider than the reach
    middle = rbc.paper_cap(wide, 1.0)[:, 32]
    np.testing.assert_allclose(middle, 0.0)                      # nothing to light in its middle


def test_the_paper_cap_reads_both_layouts_alike():
    page = _page(0.7)
    page[10:14, :, 1] = 0.2
    hwc = rbc.paper_cap(page, 1.0)
    chw = rbc.paper_cap(np.moveaxis(page, -1, 0), 1.0)
    np.testing.assert_allclose(np.moveaxis(chw, 0, -1), hwc)


@pytest.mark.parametrize("text, expected", [
    ("", ("", None)), ("pf=1.04;so=0,0.25;sp=5,1+paper", ("pf=1.04;so=0,0.25;sp=5,1", 1.0)),
    ("off+paper=1.3", ("off", 1.3)), ("pf=1+nocap", ("pf=1+nocap", None))])
def test_a_bands_paper_cap_is_read_from_its_text(text, expected):
    assert rbc._split_paper(text) == expected


def test_the_white_rules_band_is_the_one_correct_designs_a_white_page_over():
    """What the ninth look judged is what ``vrcorrect correct --band auto`` uses: the white-rule-3's
    band, read from its text, is the product's page band (and its white paper the product's)."""
    from dataclasses import replace

    from vrcorrect.physics.page import PAGE_BAND, WHITE_PAPER
    from vrcorrect.physics.robust import RobustBand, design_eye, oriented_band
    from vrcorrect.specs.display import get_display

    # the ninth look's (2026-12-03); oriented towards the sharper eye, which for the tool's eye, a myope,
    # is the band as written
    assert replace(rbc.parse_band(rbc.WHITE_RULE_3["white"]), towards_sharper=True) == PAGE_BAND
    assert PAGE_BAND.pull == 0.005 and rbc.parse_band(rbc.WHITE_RULE_2["white"]).pull == 0.0   # the eighth's: none
    for display in ("desktop", "quest2"):
        m = design_eye(rbc.EYE, get_display(display), 3.0, robust=False).nominal.report.focus.residual.M_D
        assert m < 0 and oriented_band(PAGE_BAND, m).sphere_offsets_D == PAGE_BAND.sphere_offsets_D
    assert rbc.parse_band(rbc.WHITE_RULE["white"]) != PAGE_BAND            # the seventh's, before it
    for rule in (rbc.WHITE_RULE, rbc.WHITE_RULE_2, rbc.WHITE_RULE_3):
        assert rbc.parse_band(rule["other"]) == RobustBand() and rule["grey"] == ""
    assert rbc.WHITE_PAPER == WHITE_PAPER
    assert rbc.parse_band("pf=1").light_cap and not rbc.parse_band("pf=1+nocap").light_cap


def test_a_grey_stand_in_has_the_pages_light_times_the_paper_light(tmp_path, monkeypatch):
    from PIL import Image

    from vrcorrect.specs.display import decode

    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (256, 256, 3), dtype=np.uint8)
    Image.fromarray(image).save(tmp_path / "scan.png")
    monkeypatch.setitem(rbc._files, "scan", str(tmp_path / "scan.png"))
    page = decode("srgb", rbc.choice_image("scan")).astype(np.float64)
    grey = decode("srgb", rbc.choice_image("scan@0.58")).astype(np.float64)
    np.testing.assert_allclose(grey, 0.58 * page, atol=2e-5)


def test_a_grey_ink_stand_in_lifts_the_ink_and_keeps_the_paper(tmp_path, monkeypatch):
    """NAME^INK (ninth look): each primary's light L shown as INK + (1 - INK) L: black ink at INK,
    white paper still white."""
    from PIL import Image

    from vrcorrect.specs.display import decode

    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (256, 256, 3), dtype=np.uint8)
    image[:8], image[8:16] = 0, 255                                  # some ink, some paper
    Image.fromarray(image).save(tmp_path / "scan.png")
    monkeypatch.setitem(rbc._files, "scan", str(tmp_path / "scan.png"))
    page = decode("srgb", rbc.choice_image("scan")).astype(np.float64)
    grey = decode("srgb", rbc.choice_image("scan^0.15")).astype(np.float64)
    np.testing.assert_allclose(grey, 0.15 + 0.85 * page, atol=2e-5)
    np.testing.assert_allclose(grey[:8], 0.15, atol=2e-5)
    np.testing.assert_allclose(grey[8:16], 1.0, atol=2e-5)


@pytest.mark.parametrize("args, message", [
    (["--image", "PAGE", "--grey-ink", "0.7", ""], "--grey-ink 0.7: an ink light above 0 and at most 0.5 of white"),
    (["--image", "PAGE", "--grey-ink", "0", ""], "--grey-ink 0.0: an ink light above 0"),
    (["--grey-paper", "0.5", ""], "--held-out and --grey-paper need --documents DIR"),
    (["--documents", "DOCS", "--grey-paper", "1.5", ""], "--grey-paper 1.5: a paper light from 0.05 to 1 of white"),
    (["--documents", "DOCS", "--held-out", "--grey-paper", "0.5", ""], "not with --held-out"),
    (["--documents", "DOCS", "pf=1+paper2"], "the paper cap is '+paper' or '+paper=F'"),
    (["--documents", "DOCS", "--solver", "twin:0", ""], "'fast' or 'twin:N' with N frames from 1 to 2000"),
    (["--documents", "DOCS", "--solver", "admm", ""], "--solver 'admm'"),
    (["--rx", "DOCS/nothere.json", ""], "prescription file not found"),               # another eye's file
])
def test_bad_arguments_get_one_line_and_status_2(tmp_path, args, message):
    docs = tmp_path / "docs"
    docs.mkdir()
    for name in ("linn", "typewriter", "baiona", "c02-22", "epson", "francais", "sudoku", "imageTextN", "masks", "kcs"):
        (docs / f"{name}.png").write_bytes(b"")                  # never read: refused before
    from PIL import Image

    Image.new("RGB", (256, 256), (255, 255, 255)).save(tmp_path / "blank.png")
    args = [str(docs) if a == "DOCS" else str(tmp_path / "blank.png") if a == "PAGE" else a.replace("DOCS", str(docs))
            for a in args]
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "robust_band_choice.py"), "--no-builtin", *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in done.stderr


@pytest.mark.parametrize("number, names", [
    (1, ["serif12", "sans11", "stix14", "mono12", "cmr18", "links14"]),
    (2, ["italic13", "cmss15", "stix12", "bold10", "cmtt14", "grey16"]),
    (3, ["serifb14", "oblique12", "cmti16", "monob11", "stixb13", "grey20"])])
def test_rendered_pages_are_pages_on_white_paper_and_are_not_overwritten(tmp_path, number, names):
    """tools/render_pages.py: each set's six 256 px pages, which the page judge calls pages on white
    paper (the seventh and eighth looks' condition); a second run refuses to overwrite them without
    --force."""
    from PIL import Image

    from vrcorrect.physics.page import page_verdict
    from vrcorrect.specs.display import decode, get_display

    tool = [sys.executable, str(ROOT / "tools" / "render_pages.py"), "--set", str(number), str(tmp_path)]
    done = subprocess.run(tool, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    pages = sorted(tmp_path.glob("*.png"))
    assert [p.stem for p in pages] == sorted(names)
    display = get_display("desktop")
    for path in pages:
        image = np.asarray(Image.open(path).convert("RGB"))
        assert image.shape == (256, 256, 3)
        verdict = page_verdict(decode(display, image / 255.0), display)
        assert verdict.page and verdict.paper_light >= rbc.WHITE_PAPER, (path.stem, verdict)
    before = pages[0].read_bytes()
    again = subprocess.run(tool, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert again.returncode == 2 and "pass --force to overwrite it" in again.stderr
    assert "Traceback" not in again.stderr and pages[0].read_bytes() == before


def test_the_objective_guard_holds_each_guard_eye_within_rho_of_none_and_leaves_a_safe_correction_alone():
    """``guarded`` (eleventh look): an over-sharpened correction, seen by an eye 0.5 D nearer focus than
    the one it was designed for, is blended towards the target until that eye's objective is RHO times
    none's; with a RHO the correction already meets it is shown unchanged (blend 1)."""
    from vrcorrect.physics.robust import design_eye
    from vrcorrect.solvers import make_problem, objective, solve
    from vrcorrect.specs.display import get_display
    from vrcorrect.specs.prescription import EyeRx

    display = get_display("quest2")
    eye = EyeRx(-1.5, 0.0, 0.0, 3.0, accommodation_D=0.0)
    rng = np.random.default_rng(3)
    target = np.clip(0.5 + 0.25 * rng.standard_normal((48, 48, 3)), 0, 1).astype(np.float32)
    design = design_eye(eye, display, 3.0, robust=False)
    shown = solve(make_problem(target, design.kernel, design.reference), "fast").image
    nearer = design_eye(eye.with_changes(sphere_D=-1.0), display, 3.0, robust=False)   # 0.23 D from focus
    seen = make_problem(target, nearer.nominal, nearer.nominal_reference)
    none, before = objective(target, seen), objective(shown, seen)
    assert before > 1.25 * none                                       # the exact design over-sharpens for it
    out, beta = rbc.guarded(shown, target, [nearer], 1.25)
    assert 0.0 < beta < 1.0 and out.dtype == np.float32
    assert objective(out, seen) == pytest.approx(1.25 * none, rel=1e-3)
    same, one = rbc.guarded(shown, target, [nearer], 2.0 * before / none)
    assert one == 1.0 and np.array_equal(same, shown)
