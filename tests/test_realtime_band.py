"""The real-time path chooses the robust band by the picture (``band="auto"``, issue 44): the GPU's look
at the frame, the verdict, the bank's (pupil, band) designs, and the switch of band with its light cap
as a uniform, held equal to the CPU twin."""

from __future__ import annotations

import numpy as np
import pytest

from vrcorrect.physics.page import REALTIME_LOOK_SIDE, luminance_verdict, page_verdict
from vrcorrect.physics.perception import luminance_weights
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import prepare_image
from vrcorrect.runtime.eye_model import CorrectorOptions, band_switches, build_eye_model
from vrcorrect.runtime.pupil_bank import band_slack, codes_band, codes_light_and_band, codes_luminance
from vrcorrect.runtime.pupil_state import BAND_HOLD, LOOK_EVERY, LOOK_LATE, BandFollower
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx, Prescription
from vrcorrect.studies.bench.sequences import text_page

EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
QUEST2 = get_display("quest2")
W, H = 96, 80
AUTO = {"pupil": "auto", "robust": True, "band": "auto"}


def page() -> np.ndarray:
    return text_page(W, H)                                       # uint8 sRGB: dark words on white paper


def photograph() -> np.ndarray:
    from skimage import data

    return np.round(prepare_image(data.astronaut(), W, "astronaut")[:H] * 255).astype(np.uint8)


def linear(codes: np.ndarray) -> np.ndarray:
    return decode(QUEST2, codes.astype(np.float32) / 255.0).astype(np.float32)


def test_the_band_switches_only_where_the_bank_and_the_cap_can_follow():
    assert band_switches(CorrectorOptions(**AUTO))
    for other in ({"band": "default"}, {"pupil": 3.0}, {"robust": False}, {"filter": "fista"}, {"filter": "fft"},
                  {"fovea_deg": 2.0}):
        assert not band_switches(CorrectorOptions(**{**AUTO, **other})), other
    with pytest.raises(ValidationError, match="band"):
        CorrectorOptions(**{**AUTO, "band": "page"})             # the options choose; "page" is a design's band


def test_the_first_frames_band_is_the_verdict_of_its_codes():
    assert codes_band(page(), QUEST2) == "page"
    assert codes_band(photograph(), QUEST2) == "default"
    assert codes_band(np.zeros((H, W, 3), np.uint8), QUEST2) == "default"          # a black frame
    assert codes_band(np.full((H, W, 3), 255, np.uint8), QUEST2) == "default"      # a white frame: no ink
    for codes in (page(), photograph(), page().astype(np.float32) / 255):        # one decoding, the same answers
        assert codes_light_and_band(codes, QUEST2, True) == (codes_luminance(codes, QUEST2), codes_band(codes, QUEST2))
        assert codes_light_and_band(codes, QUEST2, False) == (codes_luminance(codes, QUEST2), None)


@pytest.mark.parametrize("first_band", ["page", "default"])
def test_a_banks_grids_hold_the_other_bands_designs_it_may_switch_to(first_band):
    """A bank first designed over one band sizes its grids with the other band's slack, so that a switch
    to the other band (or to its own) at the grids' reach fits them (a switch that does not fit would be
    a new strategy: a cold start on the render thread).  Myopes, a low myope and a hyperope: the page
    band's sphere offsets widen a hyperope's blur and narrow a myope's."""
    options = CorrectorOptions(**AUTO)
    other = {"page": "default", "default": "page"}[first_band]
    for eye in (EYE, EyeRx(-0.5, 0.0, 0.0, 4.0), EyeRx(-6.0, 0.0, 0.0, 4.0), EyeRx(3.0, -1.0, 90.0, 4.0)):
        first = build_eye_model(eye, QUEST2, options, pupil_mm=3.125, band=first_band)
        assert first.band == first_band and first.design.capped == (first_band == "default")
        assert band_slack(first.design) >= 1.0
        for band in (first_band, other):
            widest = build_eye_model(eye, QUEST2, options, pupil_mm=first.reach_mm, band=band,
                                     grid_kernel_size=first.grid_kernel_size, reach_mm=first.reach_mm)
            assert widest.design.capped == (band == "default")
            assert max(widest.kernel.size, widest.reference.size) <= first.grid_kernel_size, (eye, band)


@pytest.mark.parametrize("codes", [page(), photograph()], ids=["page", "photograph"])
def test_the_gpus_look_is_the_strided_luminance_the_verdict_reads(gl, codes):
    """``PageLook`` reads back what ``page_verdict`` looks at (every step-th pixel's clipped luminance),
    and the verdict of the read-back equals the CPU's of the picture."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.dispatch import Gpu
    from vrcorrect.runtime.strategies.base import PageLook

    big = np.repeat(np.repeat(codes, 4, axis=0), 4, axis=1)          # 384 x 320: a stride of 2 at a side of 256
    image = linear(big)
    tex = gl.texture((big.shape[1], big.shape[0]), 4, np.concatenate(
        [image[::-1], np.ones(image.shape[:2] + (1,), np.float32)], axis=2).tobytes(), dtype="f4")
    look = PageLook(Gpu(gl), luminance_weights(QUEST2), REALTIME_LOOK_SIDE)
    try:
        look.look(tex)
        y = look.take()
        assert look.take() is None                                    # taken once
        want = np.clip(image[::-1][::2, ::2], 0, 1).astype(np.float64) @ luminance_weights(QUEST2)
        assert y.shape == want.shape
        np.testing.assert_allclose(y, want[::-1], atol=1e-5)          # the picture's top row first
        assert luminance_verdict(y).page == page_verdict(image, QUEST2, REALTIME_LOOK_SIDE).page
    finally:
        look.release()
        G.release(tex)


def test_a_page_cut_to_a_photograph_and_back_switches_band_without_a_cold_start_and_equals_its_twin(gl):
    """Through the real-time default (``band="auto"``, single precision, the frame time of 90 Hz): the
    first frame is a page, so the first design is the page band's, uncapped; cut to a photograph, the
    band goes to the default's (capped) once :data:`BAND_HOLD` looks agree, and back on a cut to the
    page that the shell reports (``Corrector.reset``, as ``render`` and the layer do on a detected cut):
    that cut's frame is looked at at once and decides alone, so the switch lands :data:`LOOK_LATE`
    frames after it, among the cold start's own changes.  Every switch keeps the strategy (no cold start, no new programs: the cap is a uniform), and
    every frame the GPU's solution equals the CPU twin's, which switches design and cap at the same
    frames (``AdmmFrames.set_design``), to 3e-5 (float32 FFTs; an uncapped page reaches further than the
    pupil test's photographs)."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.solvers.realtime import AdmmFrames

    text, photo = page(), photograph()
    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", precision="single", early_stop=False,
                  first_luminance=codes_luminance(text, QUEST2), first_band=codes_band(text, QUEST2), **AUTO)
    c.frame_time_s = 1 / 90
    assert c.model.band == "page" and not c.strategy.cap and c.strategy.cap_switch
    twin = AdmmFrames(c.model.kernel, c.model.reference, (H, W), precision="single",
                      grid_kernel_size=c.model.grid_kernel_size, cap=False)
    strategy = c.strategy
    src = G.upload_texture(gl, text)
    tex, fbo = G.render_target(gl, width=W, height=H)
    bands, cut = [(0, "page")], 6
    hold = LOOK_EVERY * BAND_HOLD + LOOK_LATE + 1                     # frames a verdict needs, at most
    try:
        back = cut + hold + 2
        for f in range(back + hold):
            image = text if f < cut or f >= back else photo
            G.write_texture(src, image)
            if f == back:
                c.reset()
                twin.reset()
            before = c.model
            c.apply(src, fbo)
            if c.model is not before:
                twin.set_design(c.model.kernel, c.model.reference, cap=c.model.design.capped)
                bands.append((f, c.model.band))
            cpu = twin.frame(linear(image), 2)
            assert np.abs(c.solution((W, H)) - cpu.solution).max() <= 3e-5, f
            assert c.strategy is strategy, f                            # never a new strategy
            assert c.strategy.cap == (c.model.band == "default"), f
        changes = [(f, b) for i, (f, b) in enumerate(bands) if i == 0 or b != bands[i - 1][1]]   # pupils switch too
        assert [b for _, b in changes] == ["page", "default", "page"], bands
        assert cut < changes[1][0] <= cut + hold, bands
        assert changes[2][0] == back + LOOK_LATE, bands
        assert "page band" in c.pupil_status
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_the_default_band_option_never_looks(gl):
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", **{**AUTO, "band": "default"},
                  first_band="page")
    src = G.upload_texture(gl, page())
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        for _ in range(2 * LOOK_EVERY * BAND_HOLD):
            c.apply(src, fbo)
        assert c._pupil.look is None and c.model.band == "default" and c.strategy.cap and not c.strategy.cap_switch
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_render_designs_a_page_over_the_page_band_and_says_so(tmp_path, capsys):
    """``vrcorrect render`` (the real-time path on GL, ``--band auto`` by default) designs a page on
    white paper over the page band from its first frame and says so in the pupil's line; a photograph,
    ``--band default`` and ``--filter fft`` get the default band."""
    from PIL import Image

    from vrcorrect.apps import cli

    said = {}
    for name, codes, extra in (("page", page(), []), ("photo", photograph(), []), ("default", page(), ["--band", "default"]),
                               ("fft", page(), ["--filter", "fft"])):
        path = tmp_path / f"{name}.png"
        Image.fromarray(codes).save(path)
        assert cli.main(["render", str(path), "-o", str(tmp_path / f"{name}-out.png"), "--display", "quest2",
                         *extra]) == 0
        said[name] = capsys.readouterr().out
        assert (tmp_path / f"{name}-out.png").exists()
    assert ", page band, " in said["page"]
    assert ", default band, " in said["photo"]
    assert " band, " not in said["default"] and " band, " not in said["fft"]      # no look: the default band


def test_a_first_frame_nobody_judged_is_looked_at_at_once(gl):
    """Without ``first_band`` (the OpenXR layer's corrector, which primes on the application's frames)
    the first frame is a new scene: looked at at once and deciding alone, so a page gets the page band
    :data:`LOOK_LATE` frames in, not after :data:`BAND_HOLD` looks."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    c = Corrector(gl, Prescription(right=EYE, left=EYE), "quest2", "right", **AUTO)
    c.frame_time_s = 1 / 90                              # deterministic: the switch's design is made at once
    assert c.model.band == "default"
    src = G.upload_texture(gl, page())
    tex, fbo = G.render_target(gl, width=W, height=H)
    try:
        for f in range(LOOK_LATE + 1):
            c.apply(src, fbo)
            assert c.model.band == ("page" if f == LOOK_LATE else "default"), f
    finally:
        c.release()
        G.release(fbo, tex, src)


def test_the_band_follower_looks_every_few_frames_and_switches_on_verdicts_in_a_row():
    """:class:`BandFollower` (the real-time path's and ``bench robust``'s): a look at the first frame and
    every ``LOOK_EVERY`` frames, read ``LOOK_LATE`` frames later; ``BAND_HOLD`` verdicts in a row switch
    the band; after a cut the next frame is looked at and its verdict alone decides."""
    as_page = luminance_verdict(np.clip(linear(page()), 0, 1).astype(np.float64) @ luminance_weights(QUEST2))
    as_photo = luminance_verdict(np.clip(linear(photograph()), 0, 1).astype(np.float64) @ luminance_weights(QUEST2))
    assert as_page.page and not as_photo.page
    f = BandFollower("default")
    actions = [f.tick() for _ in range(2 * LOOK_EVERY + 1)]
    assert [i for i, a in enumerate(actions) if a == "look"] == [0, LOOK_EVERY, 2 * LOOK_EVERY]
    assert [i for i, a in enumerate(actions) if a == "read"] == [LOOK_LATE, LOOK_EVERY + LOOK_LATE]
    f = BandFollower("default")
    bands = []
    for _ in range(5 * LOOK_EVERY):                      # a page from the first frame
        if f.tick() == "read":
            bands.append(f.judge(as_page))
    assert bands[:BAND_HOLD] == ["default"] * (BAND_HOLD - 1) + ["page"] and set(bands[BAND_HOLD:]) == {"page"}
    assert f.verdict is as_page
    f.cut()                                              # a cut to a photograph: looked at at once, decisive
    assert f.tick() == "look"
    assert [f.tick() for _ in range(LOOK_LATE - 1)] == [None] * (LOOK_LATE - 1) and f.tick() == "read"
    assert f.judge(as_photo) == "default"
    odd = BandFollower("page")                           # one odd verdict between pages does not flip it
    verdicts = iter([as_page, as_photo, as_page, as_page])
    seen = []
    for _ in range(4 * LOOK_EVERY + LOOK_LATE):
        if odd.tick() == "read":
            seen.append(odd.judge(next(verdicts)))
    assert seen == ["page"] * 4
    first = BandFollower("default", cut=True)            # a first frame nobody judged: decisive at once
    assert first.tick() == "look" and [first.tick() for _ in range(LOOK_LATE)][-1] == "read"
    assert first.judge(as_page) == "page"
