"""What lets the OpenXR layer build its correction off the application's frame (issue 46), on Mesa's
real EGL/llvmpipe: the program-binary cache of :mod:`vrcorrect.runtime.glcache` (a second context
loads what the first compiled, and corrects bit for bit as a compiling one does; a damaged file is
compiled again), the eye models kept between runs (:mod:`vrcorrect.runtime.eye_cache`), and a
Corrector warmed up and reset starting cold again, as a fresh one does."""

from __future__ import annotations

import json

import numpy as np
import pytest

RX = {"schema": "vrcorrect.prescription/1",
      "right": {"sphere_D": -3.0, "cylinder_D": -1.0, "axis_deg": 20, "pupil_diameter_mm": 4.0},
      "left": {"sphere_D": -1.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0}}
SIZE = (64, 48)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from vrcorrect.runtime.eye_model import CorrectorOptions, build_eye_model
    from vrcorrect.specs.display import get_display
    from vrcorrect.specs.prescription import load_prescription

    folder = tmp_path_factory.mktemp("glcache")
    rx = folder / "rx.json"
    rx.write_text(json.dumps(RX))
    prescription = load_prescription(rx)
    display = get_display("quest2")
    model = build_eye_model(prescription.eye("right"), display, CorrectorOptions())
    picture = np.random.default_rng(7).integers(0, 256, (SIZE[1], SIZE[0], 4), dtype=np.uint8)
    return prescription, display, model, picture


def _frames(ctx, setup, count: int = 3, warm_up: bool = False) -> tuple[list[np.ndarray], object]:
    """``count`` frames of a Corrector on the picture (after a warm-up on other content and a reset)."""
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.runtime.gl import read_framebuffer, release, render_target, upload_texture

    prescription, display, model, picture = setup
    corrector = Corrector(ctx, prescription, display, "right", eye_model=model)
    tex = upload_texture(ctx, picture)
    target, fb = render_target(ctx, width=SIZE[0], height=SIZE[1])
    try:
        if warm_up:
            other = np.random.default_rng(1).integers(0, 256, picture.shape, dtype=np.uint8)
            for content in (other, other[::-1].copy()):
                tex.write(np.ascontiguousarray(content[::-1]).tobytes())
                corrector.apply(tex, fb)
            corrector.reset()
            tex.write(np.ascontiguousarray(picture[::-1]).tobytes())
        out = []
        for _ in range(count):
            corrector.apply(tex, fb)
            out.append(read_framebuffer(fb, components=3))
        return out, corrector.describe()
    finally:
        release(fb, target, tex)
        corrector.release()


def test_a_second_context_loads_the_programs_the_first_compiled_and_corrects_alike(setup, tmp_path):
    from vrcorrect.runtime.glcache import egl_context

    first = egl_context(430, cache=tmp_path / "programs")
    try:
        expected, _ = _frames(first, setup)
        stats = first.extra.stats
    finally:
        first.release()
    if stats.disabled:
        pytest.fail(f"the program cache is off: {stats.disabled} (Mesa's own shader cache disabled?)")
    assert stats.linked > 10 and stats.stored == stats.linked, stats
    assert list((tmp_path / "programs").glob("*/*.bin"))
    second = egl_context(430, cache=tmp_path / "programs")
    try:
        got, _ = _frames(second, setup)
        again = second.extra.stats
    finally:
        second.release()
    assert again.linked == 0 and again.loaded == stats.loaded + stats.linked, (stats, again)
    for a, b in zip(expected, got):
        assert np.array_equal(a, b)


def test_a_damaged_program_binary_is_compiled_again(setup, tmp_path):
    from vrcorrect.runtime.glcache import egl_context

    ctx = egl_context(430, cache=tmp_path / "programs")
    try:
        expected, _ = _frames(ctx, setup, count=1)
    finally:
        ctx.release()
    files = list((tmp_path / "programs").glob("*/*.bin"))
    for f in files:
        f.write_bytes(f.read_bytes()[:4] + b"\0" * 64)          # the format kept, the binary garbage
    ctx = egl_context(430, cache=tmp_path / "programs")
    try:
        got, _ = _frames(ctx, setup, count=1)
        stats = ctx.extra.stats
    finally:
        ctx.release()
    assert stats.linked >= len(files) and stats.stored == stats.linked, stats
    assert np.array_equal(expected[0], got[0])


def test_the_cache_folder_follows_the_environment(tmp_path):
    from vrcorrect.runtime.glcache import cache_dir

    assert cache_dir({"VRCORRECT_CACHE_DIR": str(tmp_path / "v")}) == tmp_path / "v"
    assert cache_dir({"XDG_CACHE_HOME": str(tmp_path / "x"), "HOME": "/nowhere"}) == tmp_path / "x" / "vrcorrect"
    assert cache_dir({"HOME": str(tmp_path)}) == tmp_path / ".cache" / "vrcorrect"


LONG_CALL_SCRIPT = """
import json, sys, threading, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from vrcorrect.runtime.corrector import Corrector
from vrcorrect.runtime.eye_model import CorrectorOptions, build_eye_model
from vrcorrect.runtime.gl import release, render_target, upload_texture
from vrcorrect.runtime.glcache import egl_context
from vrcorrect.specs.display import get_display
from vrcorrect.specs.prescription import load_prescription

rx = load_prescription(sys.argv[2]); display = get_display("quest2")
model = build_eye_model(rx.eye("right"), display, CorrectorOptions())
done = threading.Event()

def work():
    try:
        ctx = egl_context(430, cache=False)          # no binaries: everything compiled
        c = Corrector(ctx, rx, display, "right", eye_model=model)
        tex = upload_texture(ctx, np.zeros((48, 64, 4), np.uint8)); target, fb = render_target(ctx, width=64, height=48)
        c.apply(tex, fb); ctx.finish()               # the first frame: compiles and llvmpipe's code generation
        c.release(); release(fb, target, tex); ctx.release()
    finally:
        done.set()

worker = threading.Thread(target=work)
start = time.perf_counter(); ticks = [start]
worker.start()
while not done.wait(0.01):
    ticks.append(time.perf_counter())
worker.join()
print(json.dumps({"seconds": time.perf_counter() - start, "ticks": len(ticks), "gap": float(np.diff(ticks).max())}))
"""


def test_a_long_gl_call_lets_other_python_threads_run(setup, tmp_path):
    """moderngl holds the GIL through its calls; through the caching loader the slow ones (here a
    Corrector's first frame with Mesa's shader cache off: compiles and llvmpipe's code generation,
    seconds) release it: another thread keeps its 10 ms ticks meanwhile.  (A process of its own:
    Mesa reads its cache setting when the first context is made.)"""
    import os
    import subprocess
    import sys
    from pathlib import Path

    rx = tmp_path / "rx.json"
    rx.write_text(json.dumps(RX))
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, "-c", LONG_CALL_SCRIPT, str(root), str(rx)], capture_output=True,
                            text=True, timeout=600, env={**os.environ, "MESA_SHADER_CACHE_DISABLE": "true"})
    assert result.returncode == 0, result.stderr[-2000:]
    got = json.loads(result.stdout.strip().splitlines()[-1])
    assert got["seconds"] > 1.0 and got["ticks"] > 50, got      # a first frame that takes long
    assert got["gap"] < 0.25, got


def test_a_corrector_warmed_up_then_reset_starts_cold_as_a_fresh_one(setup):
    """The layer's build worker runs every pass once on other content (the warm-up that compiles
    them), then resets: its frames are a fresh Corrector's, bit for bit."""
    from vrcorrect.runtime.gl import headless_context

    ctx = headless_context(require=430)
    try:
        fresh, _ = _frames(ctx, setup, count=3)
        warmed, _ = _frames(ctx, setup, count=3, warm_up=True)
    finally:
        ctx.release()
    for a, b in zip(fresh, warmed):
        assert np.array_equal(a, b)
    assert not np.array_equal(fresh[0], fresh[2])          # frames that differ: the iterations went on


def test_an_eye_sources_key_names_its_prescriptions_age(tmp_path):
    """The key the layer's builder stores a design under, at a start and after a reload alike
    (a reload once stored without the age, so a later launch missed it): two prescriptions
    that differ in the wearer's age alone are two keys, each the one a start computes."""
    from vrcorrect.runtime import eye_cache
    from vrcorrect.runtime.eye_model import CorrectorOptions
    from vrcorrect.runtime.eye_source import EyeSource
    from vrcorrect.specs.display import get_display
    from vrcorrect.specs.prescription import load_prescription

    keys = []
    for age in (35, 70):
        rx = tmp_path / f"rx{age}.json"
        rx.write_text(json.dumps(dict(RX, age_years=age)))
        source = EyeSource(rx, get_display("quest2"), CorrectorOptions(), worker=False)
        try:
            keys.append(eye_cache.source_key(source, "quest2", (96, 64)))
        finally:
            source.close()
        loaded = load_prescription(rx)
        eyes = {eye: loaded.eye(eye) for eye in ("right", "left")}
        assert keys[-1] == eye_cache.key(eyes, "quest2", (96, 64), CorrectorOptions(), age_years=loaded.age_years)
    assert keys[0] != keys[1]


def test_eye_models_are_kept_under_a_key_of_everything_they_depend_on(setup, tmp_path):
    from dataclasses import replace

    from vrcorrect.runtime import eye_cache
    from vrcorrect.runtime.eye_model import CorrectorOptions

    prescription, display, model, _ = setup
    env = {"VRCORRECT_CACHE_DIR": str(tmp_path)}
    eyes = {"right": prescription.eye("right"), "left": prescription.eye("left")}
    key = eye_cache.key(eyes, None, (96, 64), CorrectorOptions())
    assert eye_cache.load(key, env) is None
    assert eye_cache.store(key, display, "why", {"right": model}, env) is not None
    doc = eye_cache.load(key, env)
    assert doc["why"] == "why" and doc["display"].name == display.name
    assert np.array_equal(doc["models"]["right"].kernel.kernel, model.kernel.kernel)
    changed = {"right": eyes["right"].with_changes(sphere_D=-3.25), "left": eyes["left"]}
    others = [eye_cache.key(changed, None, (96, 64), CorrectorOptions()),
              eye_cache.key(eyes, "quest2", (96, 64), CorrectorOptions()),
              eye_cache.key(eyes, None, (128, 64), CorrectorOptions()),
              eye_cache.key(eyes, None, (96, 64), replace(CorrectorOptions(), iterations_per_frame=3)),
              # the wearer's age alone (the prescription's age_years: the pupil's formula takes it)
              eye_cache.key(eyes, None, (96, 64), CorrectorOptions(), age_years=70),
              eye_cache.key(eyes, None, (96, 64), CorrectorOptions(), age_years=25)]
    assert len({key, *others}) == 7
    profile = tmp_path / "display.json"
    profile.write_text("{}")
    before = eye_cache.key(eyes, str(profile), (96, 64), CorrectorOptions())
    profile.write_text('{"edited": 1}')                   # a profile file is keyed by its bytes
    assert eye_cache.key(eyes, str(profile), (96, 64), CorrectorOptions()) != before
    (tmp_path / "eyes" / f"{key}.pickle").write_bytes(b"damaged")
    assert eye_cache.load(key, env) is None


def test_a_pupil_design_is_kept_under_its_display_by_content_and_everything_else_it_depends_on(setup, tmp_path):
    """The pupil bank's designs (the layer's second launch): keyed by the display profile's content,
    so a profile read back from the eye models' cache (its pickle's bytes differ) finds the design a
    freshly loaded one kept; any other input is another key; a damaged file is a miss.  A window's
    first design (``start_key``) likewise, never under a bank design's key."""
    import pickle
    from dataclasses import replace

    from vrcorrect.runtime import eye_cache
    from vrcorrect.runtime.eye_model import CorrectorOptions
    from vrcorrect.specs.display import get_display

    prescription, display, model, _ = setup
    env = {"VRCORRECT_CACHE_DIR": str(tmp_path)}
    eye, options = prescription.eye("right"), CorrectorOptions()
    args = (eye, display, options, None, 2.901, 41, 4.2079)
    key = eye_cache.design_key(*args)
    assert eye_cache.design_key(eye, pickle.loads(pickle.dumps(display)), *args[2:]) == key
    others = {eye_cache.design_key(eye.with_changes(sphere_D=-3.25), *args[1:]),
              eye_cache.design_key(eye, get_display("desktop" if display.name != "desktop" else "quest2"), *args[2:]),
              eye_cache.design_key(eye, display, replace(options, iterations_per_frame=3), *args[3:]),
              eye_cache.design_key(*args[:3], 70, *args[4:]),
              eye_cache.design_key(*args[:4], 3.125, *args[5:]),
              eye_cache.design_key(*args[:5], 43, args[6]),
              eye_cache.design_key(*args[:6], 4.5328)}
    assert len(others | {key}) == 8
    assert eye_cache.load_design(key, env) is None
    assert eye_cache.store_design(key, model, env) is not None
    assert np.array_equal(eye_cache.load_design(key, env).kernel.kernel, model.kernel.kernel)
    assert eye_cache.load_design(next(iter(others)), env) is None
    (tmp_path / "designs" / f"{key}.pickle").write_bytes(b"damaged")
    assert eye_cache.load_design(key, env) is None
    # a window's first design: the same inputs, the same key; any other (the pupil its first frame's light
    # gives among them), another
    start = (eye, display, options, None, 3.125)
    first = eye_cache.start_key(*start)
    assert eye_cache.start_key(eye, pickle.loads(pickle.dumps(display)), options, None, 3.125) == first
    firsts = {eye_cache.start_key(eye.with_changes(sphere_D=-3.25), *start[1:]),
              eye_cache.start_key(eye, get_display("desktop" if display.name != "desktop" else "quest2"), *start[2:]),
              eye_cache.start_key(eye, display, replace(options, pupil="auto"), None, 3.125),
              eye_cache.start_key(*start[:3], 70, 3.125),
              eye_cache.start_key(*start[:4], 2.901)}
    assert len(firsts | {first} | others | {key}) == 14
