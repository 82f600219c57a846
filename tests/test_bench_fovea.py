"""``bench fovea``'s judges beside FovVideoVDP on stills: FovVideoVDP on clips (video mode,
``foveated_video_jod``), FLIP and the objective; and the bench's clips played through the full
field's and the window's twins."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage
import skimage.data

from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.specs.display import get_display
from vrcorrect.studies.bench import fovea as F
from vrcorrect.vision.vdp import foveated_video_jod


def _clip(frames: int = 3) -> np.ndarray:
    """A 256x256 photograph drifting a pixel a frame: ``(F, H, W, 3)`` sRGB in [0, 1]."""
    big = skimage.data.astronaut()[::2, ::2].astype(np.float64) / 255.0
    return np.stack([np.roll(big, i, axis=1) for i in range(frames)])


def test_a_clip_blurred_where_the_eye_looks_scores_lower_than_one_blurred_away_from_it():
    """Identical clips score 10; a clip blurred on its left half scores lower for an eye fixating the
    blur than for one fixating the sharp half 20 degrees away (FovVideoVDP in video mode)."""
    quest2 = get_display("quest2")
    ref = _clip()
    assert foveated_video_jod(ref, ref.copy(), quest2, (128, 128), 90.0) == pytest.approx(10.0, abs=1e-3)
    test = ref.copy()
    test[:, :, :128] = scipy.ndimage.gaussian_filter(ref, sigma=(0, 2.0, 2.0, 0), mode="nearest")[:, :, :128]
    at_blur = foveated_video_jod(ref, test, quest2, (40, 128), 90.0)
    away = foveated_video_jod(ref, test, quest2, (215, 128), 90.0)
    assert at_blur < away < 10.0, (at_blur, away)


@pytest.mark.parametrize("args, field", [
    (dict(fixation_px=(-1, 10)), "fixation_px"),
    (dict(fixation_px=(10, 300)), "fixation_px"),
    (dict(fixation_px=(float("nan"), 3)), "fixation_px"),
    (dict(fixation_px="centre"), "fixation_px"),
    (dict(fps=0.0), "fps"),
    (dict(fps=True), "fps"),
    (dict(test_frames=np.zeros((2, 256, 256, 3))), "test_frames.shape"),
    (dict(reference_frames=np.zeros((3, 256, 256))), "reference_frames.shape"),
    (dict(display="quest2"), "display"),
])
def test_foveated_video_jod_names_what_is_wrong(args, field):
    ref = np.zeros((3, 256, 256, 3))
    call = dict(reference_frames=ref, test_frames=ref.copy(), display=get_display("quest2"), fixation_px=(1, 1),
                fps=90.0)
    call.update(args)
    with pytest.raises(ValidationError) as info:
        foveated_video_jod(**call)
    assert info.value.field == field


def test_the_bench_plays_its_clips_through_the_full_field_and_the_window():
    """The held-out clips as ``vrcorrect render`` plays them, at a 448 px view (24 degrees) and a 3 degree
    window (the module's scale, shrunk): every score in range; on the pan cut to a slide the
    correction's gain is seen where the eye looks, for the full field and for the window around
    that point.  The light text on dark blue is played but not asked to gain: for this mild eye
    (-2.00/-1.00 through 3 mm) the correction of it scored 0.06-0.27 JOD under none here (FLIP agreed),
    and the bench reports that as it is."""
    display = get_display("quest2")
    K, R = build_kernel(F.EYE, display), build_reference_kernel(F.EYE, display)
    rows = F.video_cases(display, K, R, view=448, frames=6, clips=("text", "cut"), radius=3.0)
    assert [r["clip"] for r in rows] == ["text", "cut"]
    for r in rows:
        assert r["frames"] == 6
        for name in ("none", "full", "foveated"):
            s = r[name]
            assert 0.0 <= s["centre"] <= 10.0 and 0.0 <= s["off"] <= 10.0 and 0.0 <= s["flip"] <= 1.0, (r["clip"], s)
        assert r["foveated"]["flip"] != r["full"]["flip"]       # the window's frames are not the full field's
    cut = rows[1]
    assert cut["full"]["centre"] > cut["none"]["centre"] + 0.1, cut
    assert cut["foveated"]["centre"] > cut["none"]["centre"] + 0.1, cut
    with pytest.raises(ValidationError) as info:
        F.video_cases(display, K, R, view=448, frames=2, clips=("text", "no such clip"))
    assert info.value.field == "clips" and info.value.value == "no such clip"


def test_the_bench_table_shows_the_clips_and_flip():
    """The report's markdown carries a row per clip with the foveated - full difference and the
    share of the gain off the centre, computed from the scores given (not re-scored)."""
    video = [{"clip": "text", "what": "", "frames": 30,
              "none": {"centre": 7.0, "off": 8.0, "flip": 0.30},
              "full": {"centre": 8.0, "off": 9.0, "flip": 0.20},
              "foveated": {"centre": 7.9, "off": 8.5, "flip": 0.22}}]
    report = {"view": 960, "ppd": 18.89, "frames": 16, "off_deg": 10.0, "eye": "right", "machine": "m",
              "renderer": "r", "seconds": 60.0, "periphery_iterations": {}, "cases": [], "video": video}
    md = F._markdown(report)
    line = next(x for x in md.splitlines() if x.startswith("| text"))
    assert "-0.10" in line and "50 %" in line and "0.300 / 0.200 / 0.220" in line, line


def test_the_clips_refuse_an_unknown_periphery_before_any_work():
    display = get_display("quest2")
    K, R = build_kernel(F.EYE, display), build_reference_kernel(F.EYE, display)
    with pytest.raises(ValidationError, match="periphery.*one of quarter, half, target"):
        F.video_cases(display, K, R, view=448, frames=2, clips=("cut",), radius=3.0, periphery="eighth")
