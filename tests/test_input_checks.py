"""Every public entry point that takes an image refuses what it cannot model, with one shared
checker (``forward.check_image``): wrong shape, integer or boolean dtype (8-bit code values where
linear light is expected), NaN/inf, and values outside [0, 1] (a display cannot show them), each
with a ValidationError naming the argument, the value and what is allowed.  Before this, uint8
0-255 went in as linear light (an all-white retina) and NaN became black."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vrcorrect.specs.display import get_display
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.physics.kernel import KernelOptions, build_kernel
from vrcorrect.physics.options import OpticsOptions
from vrcorrect.specs.prescription import EyeRx

GOOD = np.full((8, 8, 3), 0.5)


@pytest.fixture(scope="module")
def kernel():
    return build_kernel(EyeRx(sphere_D=-1.0, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=3.0),
                        get_display("quest2"), KernelOptions(optics=OpticsOptions(viewing_distance_m=math.inf)))


def _bad_images():
    nan = GOOD.copy()
    nan[2, 3, 1] = np.nan
    inf = GOOD.copy()
    inf[0, 0, 0] = np.inf
    return [
        ("uint8 codes", (GOOD * 255).astype(np.uint8), "dtype"),
        ("int64", np.ones((8, 8, 3), np.int64), "dtype"),
        ("bool", np.ones((8, 8, 3), bool), "dtype"),
        ("grey 2-D", GOOD[..., 0], "shape"),
        ("RGBA", np.full((8, 8, 4), 0.5), "shape"),
        ("empty", np.zeros((0, 8, 3)), "shape"),
        ("NaN", nan, "NaN"),
        ("inf", inf, "NaN/inf"),
        ("negative", GOOD - 0.6, "values from"),
        ("above 1", GOOD * 3, "values from"),
    ]


def _entry_points(kernel):
    from vrcorrect.vision.forward import simulate_lms, what_the_eye_sees
    from vrcorrect.vision.metrics import evaluate_seen
    from vrcorrect.solvers import make_problem, objective

    problem = make_problem(GOOD.astype(np.float32), kernel)
    display = get_display("quest2")
    return {
        "forward.simulate_lms": (lambda im: simulate_lms(im, kernel), "image"),
        "forward.what_the_eye_sees": (lambda im: what_the_eye_sees(im, kernel), "image"),
        "solvers.make_problem": (lambda im: make_problem(im, kernel), "target"),
        "solvers.objective": (lambda im: objective(im, problem), "displayed"),
        "metrics.evaluate_seen": (lambda im: evaluate_seen(im, GOOD, kernel, display, with_jod=False),
                                  "displayed_linear"),
    }


@pytest.mark.parametrize("label, bad, words", _bad_images(), ids=[b[0] for b in _bad_images()])
def test_every_image_entry_point_refuses_bad_input(kernel, label, bad, words):
    for entry, (call, field) in _entry_points(kernel).items():
        with pytest.raises(ValidationError) as info:
            call(bad)
        message = str(info.value)
        assert field in message and words in message, (entry, label, message)


def test_the_good_image_passes_every_entry_point_and_rounding_is_clipped(kernel):
    for entry, (call, _) in _entry_points(kernel).items():
        call(GOOD)
        call(GOOD * (1 + 5e-7))                     # float rounding above 1 is clipped, not refused
    from vrcorrect.vision.forward import check_image

    assert check_image(np.full((2, 2, 3), 1 + 5e-7)).max() == 1.0
    assert check_image(np.zeros((2, 2, 3), np.float16)).dtype == np.float32


def test_uint8_message_says_how_to_decode(kernel):
    from vrcorrect.vision.forward import simulate_lms

    with pytest.raises(ValidationError, match="decode"):
        simulate_lms((GOOD * 255).astype(np.uint8), kernel)


@pytest.mark.parametrize("label, bad, words", [b for b in _bad_images() if b[0] != "uint8 codes"],
                         ids=[b[0] for b in _bad_images() if b[0] != "uint8 codes"])
def test_render_frame_refuses_bad_codes_before_any_gl(label, bad, words, monkeypatch):
    """render_frame takes display code values (float in [0, 1], or uint8); the check comes before
    a GL context is made (a context would fail the test here)."""
    from vrcorrect.runtime import gl
    from vrcorrect.runtime.shell.render import render_frame

    def no_context(*args, **kwargs):
        raise AssertionError("a GL context was made before the input was checked")

    monkeypatch.setattr(gl, "headless_context", no_context)
    with pytest.raises(ValidationError) as info:
        render_frame(bad, None, "quest2")
    assert "image" in str(info.value) and words in str(info.value), str(info.value)
