"""``video_jod``: ColorVideoVDP in video mode under a display's viewing conditions (real cvvdp on the
CPU, small clips so the file stays quick)."""

from __future__ import annotations

import importlib.util
import json
import math
import os

import numpy as np
import pytest
import scipy.ndimage

from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.specs.display import get_display
from vrcorrect.vision.vdp import VIDEO_JOD_MAX_FPS, jod, video_jod

SIZE = 48


@pytest.fixture(scope="module")
def photo() -> np.ndarray:
    return dict(bundled_images(SIZE))["astronaut"]


@pytest.fixture(scope="module")
def quest2():
    return get_display("quest2")


def _blur(image: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    return np.stack([scipy.ndimage.gaussian_filter(image[..., c], sigma) for c in range(3)], axis=-1)


def _moving(image: np.ndarray, frames: int) -> np.ndarray:
    """A clip of ``image`` panning one pixel a frame (something that changes from frame to frame)."""
    return np.stack([np.roll(image, k, axis=1) for k in range(frames)]).astype(np.float32)


def test_identical_clips_score_ten(photo, quest2):
    clip = _moving(photo, 12)
    assert video_jod(clip, clip, quest2, 90) == pytest.approx(10.0, abs=1e-4)
    assert video_jod(list(clip), list(clip), quest2, 30) == pytest.approx(10.0, abs=1e-4)   # a list of frames


def test_a_one_second_clip_at_90_hz_runs(photo, quest2):
    """90 frames of a pan with a little noise: a valid score below 10 (the memory of a 1-second clip;
    its time at 256x256 is in the docstring, not asserted)."""
    clip = _moving(photo, 90)
    noisy = np.clip(clip + np.random.default_rng(0).normal(0.0, 0.03, clip.shape), 0.0, 1.0).astype(np.float32)
    score = video_jod(clip, noisy, quest2, 90)
    assert 5.0 < score < 9.9


def test_flicker_is_seen_where_the_same_mean_change_held_steady_is_not(photo, quest2):
    """Every other frame dimmed by 10 % (a 15 Hz flicker at 30 fps) against all frames dimmed by
    5 %: the same average change; only the video mode's temporal channels tell them apart."""
    still = np.stack([photo] * 24)
    flicker = still.copy()
    flicker[1::2] *= 0.9
    steady = still * 0.95
    flickering, held = video_jod(still, flicker, quest2, 30), video_jod(still, steady, quest2, 30)
    assert flickering < held - 0.5, (flickering, held)
    assert flickering < 9.5


def test_a_per_frame_blur_scores_lower_than_none_and_every_frame_lower_than_half(photo, quest2):
    clip = _moving(photo, 16)
    every = np.stack([_blur(f) for f in clip])
    half = clip.copy()
    half[1::2] = every[1::2]
    s_every, s_half = video_jod(clip, every, quest2, 90), video_jod(clip, half, quest2, 90)
    assert s_every < s_half < 10.0 - 0.1, (s_every, s_half)


def _cvvdp_parameter(name: str) -> float:
    """A calibrated constant from ColorVideoVDP's own parameter file (not computed by vrcorrect)."""
    folder = os.path.dirname(importlib.util.find_spec("pycvvdp").origin)
    with open(os.path.join(folder, "vvdp_data", "cvvdp_parameters.json"), encoding="utf-8") as f:
        return float(json.load(f)[name])


@pytest.mark.parametrize("name", ["astronaut", "text"])
def test_a_still_clip_scores_like_the_image_after_colorvideovdps_image_integration(name, quest2):
    """One frame is the image mode (equal to jod); a still clip of N frames loses the image's JOD
    loss times image_int ** -jod_exp (about 1.67): ColorVideoVDP scales an image's quality by its
    image integration factor, a clip's not.  Measured within 1e-4 JOD; asserted within 1e-3, for
    two lengths and two rates."""
    image = dict(bundled_images(SIZE))[name]
    test = _blur(image)
    still = jod(image, test, quest2)
    assert still < 9.0
    assert video_jod(image[None], test[None], quest2, 90) == pytest.approx(still, abs=1e-5)
    factor = _cvvdp_parameter("image_int") ** -_cvvdp_parameter("jod_exp")
    assert 1.6 < factor < 1.7
    for frames, fps in ((3, 90), (8, 24)):
        clip = video_jod(np.stack([image] * frames), np.stack([test] * frames), quest2, fps)
        assert 10.0 - clip == pytest.approx((10.0 - still) * factor, abs=1e-3), (frames, fps, clip, still)


def test_viewing_conditions_are_the_displays(photo):
    """The same clips on a coarse headset and a fine desktop monitor score differently (ppd and
    photometry reach the metric)."""
    clip = _moving(photo, 6)
    blurred = np.stack([_blur(f) for f in clip])
    assert abs(video_jod(clip, blurred, get_display("quest2"), 90)
               - video_jod(clip, blurred, get_display("desktop"), 90)) > 0.2


def _good(photo):
    return np.stack([photo] * 3)


@pytest.mark.parametrize("case, field", [
    ("reference 3-D", "reference_frames.shape"),
    ("test 2 channels", "test_frames.shape"),
    ("no frames", "reference_frames.shape"),
    ("empty list", "reference_frames.shape"),
    ("one frame of another size", "test_frames[1].shape"),
    ("shape mismatch", "test_frames.shape"),
    ("tiny frames", "reference_frames.shape"),
    ("NaN in a frame", "test_frames[2]"),
    ("out of range", "reference_frames[0]"),
    ("strings", "reference_frames.dtype"),
    ("not an array", "reference_frames"),
    ("8-bit codes", "test_frames[0]"),
])
def test_bad_clips_name_the_field(case, field, photo, quest2):
    ref, test = _good(photo), _good(photo)
    if case == "reference 3-D":
        ref = photo
    elif case == "test 2 channels":
        test = test[..., :2]
    elif case == "no frames":
        ref = ref[:0]
    elif case == "empty list":
        ref = []
    elif case == "one frame of another size":
        test = [photo, photo[:-2], photo]
    elif case == "shape mismatch":
        test = np.stack([photo] * 4)
    elif case == "tiny frames":
        ref = np.zeros((3, 1, 8, 3), np.float32)
    elif case == "NaN in a frame":
        test = test.copy()
        test[2, 0, 0, 0] = np.nan
    elif case == "out of range":
        ref = ref * 1.5
    elif case == "strings":
        ref = np.full((3, 4, 4, 3), "a")
    elif case == "not an array":
        ref = "clip.mp4"
    elif case == "8-bit codes":
        test = np.round(test * 255).astype(np.uint8)
    with pytest.raises(ValidationError) as info:
        video_jod(ref, test, quest2, 90)
    assert info.value.field == field, (case, str(info.value))


@pytest.mark.parametrize("fps", [0, -30, math.nan, math.inf, VIDEO_JOD_MAX_FPS * 2, True, "90"])
def test_bad_rates_and_displays_are_refused(fps, photo, quest2):
    with pytest.raises(ValidationError) as info:
        video_jod(_good(photo), _good(photo), quest2, fps)
    assert info.value.field == "fps"
    with pytest.raises(ValidationError, match="display"):
        video_jod(_good(photo), _good(photo), "quest2", 90)
