"""A page of dark text on light paper is designed for the one eye (issue 44): the verdict
(:func:`vrcorrect.physics.page.page_verdict`) on pages, photographs and the extremes (black, white,
a flat grey, light text on dark, a large frame), the design it asks for, and the commands that
take it from their picture or first frame (``correct``, ``render``, the windows, the Corrector)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps import cli
from vrcorrect.physics.page import INK_SHARE, MID_SHARE, PAPER_SHARE, page_verdict
from vrcorrect.physics.robust import design_eye
from vrcorrect.plumbing.charts import text_chart
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import prepare_image
from vrcorrect.runtime.eye_model import CorrectorOptions
from vrcorrect.runtime.pupil_bank import first_frame_facts, relative_luminance_of
from vrcorrect.runtime.shell.render import _with_first_frame
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx, Prescription
from vrcorrect.studies.bench.sequences import dark_text_page, text_page

DESKTOP = get_display("desktop")
QUEST2 = get_display("quest2")
EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)


def linear(codes_u8: np.ndarray, display=DESKTOP) -> np.ndarray:
    return decode(display, np.asarray(codes_u8, np.float32) / 255.0)


def photograph(name: str) -> np.ndarray:
    from skimage import data

    return np.round(prepare_image(getattr(data, name)(), 128, name) * 255).astype(np.uint8)


@pytest.mark.parametrize("page", [text_page(160, 128), text_page(160, 128, ink=(20, 40, 140)),
                                  text_page(160, 128, font_px=24),
                                  np.round(prepare_image(text_chart(128, 128), 128, "chart") * 255).astype(np.uint8)],
                         ids=["words", "blue ink", "large words", "chart"])
def test_pages_of_dark_text_on_light_paper_are_pages(page):
    v = page_verdict(linear(page), DESKTOP)
    assert v.page, v
    assert v.paper >= PAPER_SHARE and v.ink >= INK_SHARE and v.mid <= MID_SHARE
    assert "a page" in v.describe() and "one eye" in v.describe()


@pytest.mark.parametrize("name", ["astronaut", "coffee", "camera", "text"])
def test_photographs_are_not_pages(name):
    v = page_verdict(linear(photograph(name)), QUEST2)
    assert not v.page, v
    assert "not a page" in v.describe()


@pytest.mark.parametrize("level", [0, 3, 128, 255], ids=["black", "near black", "grey", "white"])
def test_a_flat_frame_is_no_page(level):
    """Black and near black have no paper; a flat grey or white frame has paper but no ink: a
    loading screen must not make a whole session's designs a page's."""
    v = page_verdict(linear(np.full((64, 80, 3), level, np.uint8)), DESKTOP)
    assert not v.page
    assert v.ink == 0.0


def test_light_text_on_a_dark_ground_is_no_page():
    v = page_verdict(linear(dark_text_page(128, 128)), DESKTOP)
    assert not v.page
    assert v.paper < PAPER_SHARE


def test_a_large_frame_is_looked_at_on_a_stride_and_judged_as_the_small_one():
    small = text_page(320, 256)
    large = np.tile(small, (8, 8, 1))                               # 2048 x 2560
    a, b = page_verdict(linear(small), DESKTOP), page_verdict(linear(large), DESKTOP)
    assert a.page and b.page
    assert abs(a.paper - b.paper) < 0.05 and abs(a.ink - b.ink) < 0.05


@pytest.mark.parametrize("shade", ["left to right, to 35 %", "vignette, to 50 %"])
def test_a_page_lit_unevenly_is_still_a_page(shade):
    """A scan or a lamp to one side: the paper's light is fitted (a quadratic), not one level."""
    words = linear(text_page(256, 192))
    yy, xx = np.mgrid[0:192, 0:256] / np.array([191.0, 255.0])[:, None, None]
    light = 1 - 0.65 * xx if shade.startswith("left") else 1 - ((xx - 0.5) ** 2 + (yy - 0.5) ** 2)
    v = page_verdict(words * light[..., None], DESKTOP)
    assert v.page, v
    assert v.misfit < 0.02
    flat = page_verdict(words * light.min(), DESKTOP)               # the same shares as evenly lit
    assert abs(v.paper - flat.paper) < 0.03


def test_a_picture_too_small_for_tiles_is_judged_on_one_paper_level():
    dots = np.full((8, 8, 3), 245, np.uint8)
    dots[2:4, 2:6] = 20                                                 # 8 ink pixels of 64
    v = page_verdict(linear(dots), DESKTOP)
    assert v.misfit == 0.0
    assert (v.paper, v.ink) == (pytest.approx(56 / 64), pytest.approx(8 / 64)) and v.page


def test_an_image_without_three_channels_is_refused():
    with pytest.raises(ValueError, match="linear_rgb"):
        page_verdict(np.zeros((8, 8)), DESKTOP)


def test_a_page_is_designed_for_the_one_eye_without_the_band():
    kernels: dict = {}
    page = design_eye(EYE, QUEST2, 2.9, kernels=kernels, page=True)
    robust = design_eye(EYE, QUEST2, 2.9, kernels=kernels)
    one = design_eye(EYE, QUEST2, 2.9, robust=False, kernels=kernels)
    assert page.page and not page.robust and page.members == ()
    assert robust.robust and not robust.page
    assert np.array_equal(page.kernel.kernel, one.kernel.kernel)
    assert np.array_equal(page.reference.kernel, one.reference.kernel)
    assert "page" in page.describe()[0] and "no light cap" in page.describe()[0]
    assert not design_eye(EYE, QUEST2, 2.9, robust=False, kernels=kernels, page=True).page   # --robust off: off


def test_the_first_frame_tells_the_light_and_the_page_only_where_asked():
    words = text_page(96, 64).astype(np.float32) / 255.0
    facts = first_frame_facts(words, QUEST2, light=True, page=True)
    assert facts["page"] is True
    assert facts["first_luminance"] == pytest.approx(relative_luminance_of(decode(QUEST2, words), QUEST2))
    assert first_frame_facts(words, QUEST2, light=False, page=True) == {"page": True}
    assert set(first_frame_facts(words, QUEST2, light=True, page=False)) == {"first_luminance"}
    assert first_frame_facts(words, QUEST2, light=False, page=False) == {}


def test_render_judges_its_first_frame_a_page_only_for_a_robust_design():
    words = text_page(96, 64)
    assert _with_first_frame({"pupil": "auto", "robust": True}, words, "quest2")["page"] is True
    assert _with_first_frame({"pupil": 3.0, "robust": True}, words, "quest2") == {"pupil": 3.0, "robust": True,
                                                                                  "page": True}
    assert "page" not in _with_first_frame({"pupil": "auto", "robust": False}, words, "quest2")
    assert _with_first_frame({"pupil": "auto", "robust": True}, photograph("astronaut"), "quest2")["page"] is False


def test_the_option_is_a_bool():
    with pytest.raises(ValidationError, match="page"):
        CorrectorOptions(page="yes")


def test_a_page_corrector_runs_uncapped_and_says_so(gl):
    from vrcorrect.runtime.corrector import Corrector

    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", pupil=3.125, robust=True, page=True)
    try:
        assert c.model.design.page and not c.model.design.robust
        assert c.describe()["page"] is True
        assert c.strategy.cap is False
    finally:
        c.release()


def _correct(capsys, tmp_path, picture: np.ndarray, *extra: str) -> tuple[str, dict]:
    src, out, report = tmp_path / "in.png", tmp_path / "out.png", tmp_path / "r.json"
    Image.fromarray(picture).save(src)
    rc = cli.main(["correct", str(src), "-o", str(out), "--display", "quest2", "--report", str(report), *extra])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    return captured.out, json.loads(report.read_text())


def test_correct_designs_a_page_for_the_one_eye_and_a_photograph_over_the_band(capsys, tmp_path):
    said, report = _correct(capsys, tmp_path, text_page(96, 64))
    assert "a page of dark text or lines on light paper" in said
    assert report["page"] is True and report["robust"] is False
    said, report = _correct(capsys, tmp_path, photograph("astronaut")[:64, :96], "--force")
    assert "not a page" in said
    assert report["page"] is False and report["robust"] is True
    said, report = _correct(capsys, tmp_path, text_page(96, 64), "--robust", "off", "--force")
    assert "a page of" not in said and "not a page" not in said
    assert report["page"] is False and report["robust"] is False


def test_a_clip_is_judged_frame_by_frame_and_said_when_the_verdict_changes(capsys, tmp_path):
    """A page, a page, then a photograph: the first two share the page's design, the third is designed
    over the band (with the light cap) and the change is said once."""
    folder = tmp_path / "clip"
    folder.mkdir()
    page, picture = text_page(96, 64), photograph("astronaut")[:64, :96]
    for i, frame in enumerate([page, page, picture]):
        Image.fromarray(frame).save(folder / f"f{i}.png")
    out, report = tmp_path / "out", tmp_path / "r.json"
    rc = cli.main(["correct", str(folder), "-o", str(out), "--display", "quest2", "--report", str(report)])
    said = capsys.readouterr().out
    assert rc == 0
    assert said.count("a page of dark text") == 1 and said.count("not a page") == 1
    assert said.index("a page of dark text") < said.index("not a page")
    shown = [np.asarray(Image.open(out / f), np.float32) / 255 for f in sorted(p.name for p in out.iterdir())]
    assert len(shown) == 3
    cap = np.clip(2 * decode(QUEST2, picture.astype(np.float32) / 255) + 0.02, 0, 1)
    assert np.all(decode(QUEST2, shown[2]) <= cap + 0.01)                  # the band's light cap holds
    assert np.any(decode(QUEST2, shown[0]) > np.clip(2 * decode(QUEST2, page.astype(np.float32) / 255) + 0.02, 0, 1)
                  + 0.01)                                                    # the page's design has none
