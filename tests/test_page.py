"""Whether a picture is a page of dark text on light paper (issue 44): the verdict
(:func:`vrcorrect.physics.page.page_verdict`) on pages, photographs and the extremes (black, white,
a flat grey, light text on dark, a large frame, a page lit unevenly, grey paper)."""

from __future__ import annotations

import numpy as np
import pytest

from vrcorrect.physics.perception import luminance_weights
from vrcorrect.physics.page import INK_SHARE, MID_SHARE, PAPER_SHARE, page_verdict
from vrcorrect.plumbing.charts import text_chart
from vrcorrect.plumbing.images import prepare_image
from vrcorrect.specs.display import decode, get_display
from vrcorrect.studies.bench.sequences import dark_text_page, text_page

DESKTOP = get_display("desktop")
QUEST2 = get_display("quest2")


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
    assert v.describe().startswith("a page of dark text")


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



@pytest.mark.parametrize("level", [1.0, 0.7, 0.45])
def test_the_papers_light_is_told_white_or_grey(level):
    """The verdict tells the paper's light (relative luminance, white 1): white paper at the top of
    the box [0, 1], or grey or tinted paper below it, where a correction can lift the paper's grain."""
    words = linear(text_page(256, 192))
    paper = float(np.median(words @ luminance_weights(DESKTOP)))                 # most of the page is paper
    v = page_verdict(words * np.float32(level), DESKTOP)
    assert v.page
    assert v.paper_light == pytest.approx(level * paper, rel=0.03)
    assert f"paper at {level * paper:.2f} of white" in v.describe()
