"""The desktop mirror (``vrcorrect mirror``): the pure key state machine, the scene and
source helpers, the text layout, the sources on headless EGL, and the mirror window itself
under Xvfb (conftest.py's ``x_display``): its halves against the real Corrector's output,
keys driven through the GLFW key callback, screenshots, no GPU allocations per frame, and
the command line."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrcorrect.plumbing.errors import InputError, ValidationError
from vrcorrect.runtime import eye_source as eye_source_module
from vrcorrect.runtime import gl as G
from vrcorrect.apps.realtime_options import parse_iterations_per_frame
from vrcorrect.runtime.shell.mirror import (
    KEY_MAP, STAGES, VIEWS, Adjust, Mirror, MirrorConfig, MirrorState, eye_viewports, next_state,
)
from vrcorrect.runtime.shell.scene import DemoScene, SceneConfig, cube_mesh, open_source, perspective, scene_transforms
from vrcorrect.runtime.shell.sources import AnimatedImageSource, FolderSource, StillSource, VideoSource
from vrcorrect.runtime.shell.source_spec import SourceSpec, fit_rect, frame_at, frame_index, parse_size, parse_source
from vrcorrect.runtime.shell.text import build_font_atlas, layout_text, panel_instances, text_width
from vrcorrect.runtime.shell.keys import KEY_ESCAPE, KEY_LEFT_BRACKET, KEY_RIGHT_BRACKET, MOD_ALT, MOD_CONTROL, MOD_SHIFT, MOD_SUPER, Iterations, Screenshot, key_map_text, next_iterations
from vrcorrect.specs.vocabulary import ITERATIONS_PER_FRAME, VIEW_ORDER

REPO = Path(__file__).resolve().parents[1]
GLFW_PRESS, GLFW_RELEASE, GLFW_REPEAT = 1, 0, 2


def key(ch: str) -> int:
    """GLFW key code of a letter (its upper-case ASCII code)."""
    return ord(ch.upper())


# --------------------------------------------------------------------------
# The key state machine (pure)
# --------------------------------------------------------------------------


def test_initial_state():
    s = MirrorState()
    assert (s.correction, s.view, s.edit_eye, s.show_keys, s.show_panel, s.running) == \
        (True, "displayed", "right", False, True, True)


@pytest.mark.parametrize("field, value", [("view", "sideways"), ("edit_eye", "both")])
def test_state_is_validated(field, value):
    with pytest.raises(ValidationError, match=field):
        MirrorState(**{field: value})


def test_toggles():
    s = MirrorState()
    for ch, field in (("c", "correction"), ("h", "show_keys"), ("i", "show_panel")):
        t, actions = next_state(s, key(ch))
        assert getattr(t, field) != getattr(s, field) and actions == ()
        u, _ = next_state(t, key(ch))
        assert u == s
    t, _ = next_state(s, key("e"))
    assert t.edit_eye == "left" and next_state(t, key("e"))[0].edit_eye == "right"


def test_view_cycles_through_the_three_views():
    s = MirrorState()
    seen = []
    for _ in range(4):
        seen.append(s.view)
        s, actions = next_state(s, key("v"))
        assert actions == ()
    assert seen == [*VIEWS, VIEWS[0]] == ["displayed", "seen_uncorrected", "seen_corrected", "displayed"]


@pytest.mark.parametrize("ch, mods, change", [
    ("s", 0, (-0.25, 0, 0)), ("s", MOD_SHIFT, (0.25, 0, 0)),
    ("y", 0, (0, -0.25, 0)), ("y", MOD_SHIFT, (0, 0.25, 0)),
    ("a", 0, (0, 0, -5.0)), ("a", MOD_SHIFT, (0, 0, 5.0)),
])
@pytest.mark.parametrize("eye", VIEW_ORDER)
def test_live_edits_go_to_the_chosen_eye(ch, mods, change, eye):
    s = MirrorState(edit_eye=eye)
    t, actions = next_state(s, key(ch), mods)
    assert t == s
    assert actions == (Adjust(eye, *change),)


def test_screenshot_and_quit():
    s = MirrorState()
    assert next_state(s, key("p")) == (s, (Screenshot(),))
    for k in (KEY_ESCAPE, key("q")):
        t, actions = next_state(s, k)
        assert not t.running and actions == ()


def test_brackets_halve_and_double_the_iterations_within_1_to_64():
    s = MirrorState()
    assert next_state(s, KEY_LEFT_BRACKET) == (s, (Iterations(up=False),))
    assert next_state(s, KEY_RIGHT_BRACKET) == (s, (Iterations(up=True),))
    assert next_state(s, KEY_RIGHT_BRACKET, MOD_CONTROL) == (s, ())
    assert ITERATIONS_PER_FRAME == (1, 64)
    assert [next_iterations(k, True) for k in (1, 3, 4, 32, 40, 64, 200)] == [2, 6, 8, 64, 64, 64, 64]
    assert [next_iterations(k, False) for k in (1, 2, 3, 8, 64, 200)] == [1, 1, 1, 4, 32, 64]
    assert parse_iterations_per_frame(None) is None and parse_iterations_per_frame("8") == 8
    for bad in ("0", "65", "2.5", "four", "", "-1"):
        with pytest.raises(ValidationError, match="--iterations-per-frame"):
            parse_iterations_per_frame(bad)


@pytest.mark.parametrize("mods", [MOD_CONTROL, MOD_ALT, MOD_SUPER, MOD_CONTROL | MOD_SHIFT])
def test_keys_with_control_alt_super_change_nothing(mods):
    s = MirrorState()
    for ch in "cvehipsyaq":
        assert next_state(s, key(ch), mods) == (s, ())


def test_unknown_keys_change_nothing():
    s = MirrorState()
    for k in [key(c) for c in "bdfgjklmnortuwxz"] + [32, 48, 257, 290, -1, 0]:
        assert next_state(s, k) == (s, ())
        assert next_state(s, k, MOD_SHIFT) == (s, ())


def test_key_map_lists_every_key_that_does_something():
    handled = set()
    for k in list(range(ord("A"), ord("Z") + 1)) + [KEY_ESCAPE, KEY_LEFT_BRACKET, KEY_RIGHT_BRACKET]:
        for mods in (0, MOD_SHIFT):
            if next_state(MirrorState(), k, mods) != (MirrorState(), ()):
                handled.add("Esc" if k == KEY_ESCAPE else chr(k) if k in (KEY_LEFT_BRACKET, KEY_RIGHT_BRACKET)
                            else chr(k).upper() if mods else chr(k).lower())
    listed = {part.strip() for k, _ in KEY_MAP for part in k.split("/")}
    # an upper-case letter of a key that has no separate shift action is the same key
    assert {h for h in handled if h.lower() in listed or h in listed} == handled
    assert listed <= handled | {h.lower() for h in handled}
    text = key_map_text(KEY_MAP)
    assert text.startswith("keys:") and all(k in text for k, _ in KEY_MAP)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([key(c) for c in "cvehipsyaqxz"] + [KEY_ESCAPE, KEY_LEFT_BRACKET,
                                                                                KEY_RIGHT_BRACKET]),
                          st.sampled_from([0, MOD_SHIFT, MOD_CONTROL])), max_size=30))
def test_any_key_sequence_keeps_the_state_valid(presses):
    s = MirrorState()
    for k, mods in presses:
        before = s
        s, actions = next_state(s, k, mods)
        assert s.view in VIEWS and s.edit_eye in VIEW_ORDER
        for a in actions:
            assert isinstance(a, (Adjust, Screenshot, Iterations))
            if isinstance(a, Adjust):
                assert a.eye == before.edit_eye
                assert sorted(abs(v) for v in (a.sphere_D, a.cylinder_D, a.axis_deg))[:2] == [0, 0]
        if not before.running:
            assert not s.running  # quitting is final


def test_eye_viewports_left_eye_on_the_left():
    vp = eye_viewports(101, 40)
    assert vp["left"] == (0, 0, 50, 40) and vp["right"] == (50, 0, 51, 40)
    with pytest.raises(ValidationError):
        eye_viewports(1, 40)


# --------------------------------------------------------------------------
# Scene and source helpers (pure)
# --------------------------------------------------------------------------


@pytest.mark.parametrize("text, size", [("640x480", (640, 480)), ("1X1", (1, 1)), (" 32 x 24 ", (32, 24)),
                                        ("8192x8192", (8192, 8192))])
def test_parse_size(text, size):
    assert parse_size(text) == size


@pytest.mark.parametrize("text", ["", "640", "0x480", "640x0", "-4x4", "4.5x4", "8193x10", "axb", "640x480x3", None])
def test_parse_size_rejects(text):
    with pytest.raises(ValidationError, match="--size"):
        parse_size(text)


def _write_png(path: Path, image: np.ndarray) -> Path:
    from PIL import Image

    Image.fromarray(image).save(path)
    return path


def test_parse_source(tmp_path):
    assert parse_source("demo") == SourceSpec("demo")
    img = _write_png(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))
    assert parse_source(str(img)) == SourceSpec("image", img)
    assert parse_source(str(tmp_path)) == SourceSpec("folder", tmp_path)
    (tmp_path / "clip.mp4").write_bytes(b"")
    assert parse_source(str(tmp_path / "clip.mp4")).kind == "video"


def test_parse_source_errors_name_what_is_supported(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        parse_source(str(tmp_path / "missing.png"))
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match=r"unsupported file type '\.txt'.*demo.*png.*mp4.*folder"):
        parse_source(str(tmp_path / "notes.txt"))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no images"):
        parse_source(str(empty))
    with pytest.raises(ValidationError):
        parse_source("")


def test_video_without_ffmpeg_is_a_clear_error(tmp_path, monkeypatch):
    import vrcorrect.runtime.shell.source_spec as source_spec

    monkeypatch.setattr(source_spec, "_ffmpeg_available", lambda: False)
    (tmp_path / "clip.mkv").write_bytes(b"")
    with pytest.raises(InputError, match="imageio-ffmpeg.*animated GIF"):
        parse_source(str(tmp_path / "clip.mkv"))


@pytest.mark.parametrize("src, dst, rect", [
    ((64, 48), (64, 48), (0, 0, 64, 48)),      # same size: texel for texel
    ((32, 24), (64, 48), (0, 0, 64, 48)),      # same aspect, scaled
    ((100, 50), (64, 48), (0, 8, 64, 32)),     # wider: full width, centred vertically
    ((50, 100), (64, 48), (20, 0, 24, 48)),    # taller: full height, centred horizontally
    ((1, 1000), (64, 48), (31, 0, 1, 48)),     # at least one pixel
])
def test_fit_rect(src, dst, rect):
    r = fit_rect(*src, *dst)
    assert (r.x, r.y, r.width, r.height) == rect


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 5000), st.integers(1, 5000), st.integers(1, 2000), st.integers(1, 2000))
def test_fit_rect_is_inside_centred_and_keeps_the_aspect(sw, sh, dw, dh):
    r = fit_rect(sw, sh, dw, dh)
    assert r.x + r.width <= dw and r.y + r.height <= dh
    assert r.width == dw or r.height == dh
    assert abs(2 * r.x + r.width - dw) <= 1 and abs(2 * r.y + r.height - dh) <= 1
    if r.width > 2 and r.height > 2:
        assert abs(math.log((r.width / r.height) / (sw / sh))) < math.log(1 + 2.0 / min(r.width, r.height)) + 1e-9


def test_frame_index_and_frame_at():
    assert [frame_index(t, 10.0, 3) for t in (0, 0.099, 0.1, 0.25, 0.3, 0.31)] == [0, 0, 1, 2, 0, 0]
    assert frame_index(-5.0, 10.0, 3) == 0
    assert [frame_at(t, [0.1, 0.2, 0.1]) for t in (0, 0.05, 0.1, 0.29, 0.3, 0.39, 0.4, 0.45)] == \
        [0, 0, 1, 1, 2, 2, 0, 0]
    with pytest.raises(ValidationError):
        frame_index(0.0, 0.0, 3)
    with pytest.raises(ValidationError):
        frame_at(0.0, [])


def test_perspective_maps_near_and_far_planes():
    p = perspective(90.0, 2.0, 0.5, 10.0)
    for z, depth in ((-0.5, -1.0), (-10.0, 1.0)):
        clip = p @ np.array([0.0, 0.0, z, 1.0])
        assert clip[2] / clip[3] == pytest.approx(depth)
    edge = p @ np.array([2.0, 1.0, -1.0, 1.0])  # 45 degrees up, aspect 2: the top-right corner
    assert edge[:2] / edge[3] == pytest.approx([1.0, 1.0])


def test_cube_faces_point_outwards():
    mesh = cube_mesh(1.0)
    assert mesh.shape == (36, 8)
    pos, normal = mesh[:, :3], mesh[:, 3:6]
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0)
    assert np.allclose(np.abs(pos).max(axis=1), 0.5)
    assert np.all(np.einsum("ij,ij->i", pos, normal) > 0.49)
    for tri in mesh.reshape(12, 3, 8):  # counter-clockwise seen from outside
        a, b, c = tri[:, :3]
        assert np.dot(np.cross(b - a, c - a), tri[0, 3:6]) > 0


def test_eyes_see_the_scene_from_points_an_ipd_apart():
    config = SceneConfig(ipd_m=0.064)
    left, right = (scene_transforms(1.0, eye, 1.0, config) for eye in VIEW_ORDER)
    assert np.allclose(left["cube"], right["cube"])
    view_l = np.linalg.inv(perspective(config.fov_y_deg, 1.0, 0.05, 60.0)) @ left["view_projection"]
    view_r = np.linalg.inv(perspective(config.fov_y_deg, 1.0, 0.05, 60.0)) @ right["view_projection"]
    assert view_l[0, 3] - view_r[0, 3] == pytest.approx(0.064)
    assert not np.allclose(scene_transforms(0.0, "left", 1.0)["cube"], scene_transforms(2.0, "left", 1.0)["cube"])


# --------------------------------------------------------------------------
# Text (pure)
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def atlas():
    return build_font_atlas(13)


def test_font_atlas_has_every_printable_character(atlas):
    h, w = atlas.image.shape
    for c in range(32, 127):
        g = atlas.glyphs[chr(c)]
        assert 0 <= g.x and g.x + g.width <= w and 0 <= g.y and g.y + g.height <= h
        cell = atlas.image[g.y:g.y + g.height, g.x:g.x + g.width]
        assert (cell.max() > 128) == (chr(c) != " "), repr(chr(c))
        assert g.advance > 0
    sx, sy, sw, sh = atlas.solid
    assert (atlas.image[sy:sy + sh, sx:sx + sw] == 255).all()
    assert atlas.glyph("\u00e9") == atlas.glyphs["?"]


def test_layout_text(atlas):
    quads = layout_text(atlas, ["ab c", "d"], 10, 20)
    assert quads.shape == (4, 12)  # the space draws nothing
    assert quads[0, 0] == 10 + atlas.glyphs["a"].offset_x and quads[0, 1] == 20
    assert quads[1, 0] - quads[0, 0] == atlas.glyphs["a"].advance
    assert quads[3, 1] == 20 + atlas.line_height
    assert text_width(atlas, "ab c") == sum(atlas.glyphs[c].advance for c in "ab c")
    # uv: inside [0, 1], top above bottom (GL orientation)
    assert (quads[:, 4:8] >= 0).all() and (quads[:, 4:8] <= 1).all() and (quads[:, 5] > quads[:, 7]).all()
    tabbed = layout_text(atlas, ["a\tb", "long words\tc"], 0, 0, tab_stops=(100,))
    assert tabbed[1, 0] - atlas.glyphs["b"].offset_x == 100 == tabbed[-1, 0] - atlas.glyphs["c"].offset_x
    assert text_width(atlas, "a\tb\tc", tab_stops=(100,), tab_px=64) == 128 + atlas.glyphs["c"].advance


def test_panel_covers_its_text(atlas):
    quads, (x, y, w, h) = panel_instances(atlas, ["hello", "a longer line"], 5, 7, padding=4)
    assert (x, y) == (5, 7) and w == text_width(atlas, "a longer line") + 8 and h == 2 * atlas.line_height + 8
    text = quads[1:]
    assert (text[:, 0] >= x).all() and (text[:, 1] >= y).all()
    assert (text[:, 1] + text[:, 3] <= y + h).all()


# --------------------------------------------------------------------------
# Scene and sources on headless EGL
# --------------------------------------------------------------------------


def test_srgb_texture_reads_linear_light_and_write_texture_replaces_it(gl):
    from vrcorrect.specs.display import srgb_to_linear
    from vrcorrect.runtime.shaders import compile_program

    codes = np.arange(0, 256, 5, dtype=np.uint8)
    image = np.dstack([np.broadcast_to(codes, (2, codes.size))] * 3 + [np.full((2, codes.size), 255, np.uint8)])
    texture = G.upload_texture(gl, image, srgb=True)
    program = compile_program(gl, "passthrough.glsl")
    vao = G.fullscreen_triangle(gl, program)
    target, fb = G.render_target(gl, width=codes.size, height=2, dtype=np.float32)
    try:
        texture.use(0)
        G.draw_fullscreen(vao, fb)
        got = G.read_framebuffer(fb, dtype=np.float32)[0, :, 0]
        assert np.abs(got - srgb_to_linear(codes / 255.0)).max() < 2e-3
        assert (G.download_texture(texture) == image).all()
        flipped = np.ascontiguousarray(image[::-1, ::-1])
        G.write_texture(texture, flipped)
        assert (G.download_texture(texture) == flipped).all()
        with pytest.raises(ValidationError, match="image"):
            G.write_texture(texture, image[:1])
        with pytest.raises(ValidationError, match="srgb"):
            G.upload_texture(gl, image.astype(np.float32), srgb=True)
    finally:
        G.release(fb, target, vao, program, texture)


def test_mipmapped_texture_downscales_in_linear_light(gl):
    image = np.zeros((8, 8, 4), np.uint8)
    image[..., 3] = 255
    image[:, ::2, :3] = 255
    texture = G.upload_texture(gl, image, filter="mipmap", srgb=True)
    try:
        import moderngl

        assert texture.filter == (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        level1 = np.frombuffer(texture.read(level=1, alignment=1), np.uint8).reshape(4, 4, 4)
        assert np.abs(level1[..., :3].astype(int) - 188).max() <= 2  # 50 % light, not code 128
    finally:
        G.release(texture)


def test_demo_scene_moves_has_stereo_and_fine_detail(gl):
    scene = DemoScene(gl, 96, 80)
    try:
        left0, right0 = (G.download_texture(t)[..., :3].astype(int) for t in scene.render(0.0))
        left1 = G.download_texture(scene.render(1.5)[0])[..., :3].astype(int)
        assert left0.shape == (80, 96, 3)
        assert np.abs(left0 - right0).mean() > 0.5, "the eyes see from different points"
        assert np.abs(left0 - left1).mean() > 2.0, "the scene moves"
        grad = np.abs(np.diff(left0, axis=1)).mean() + np.abs(np.diff(left0, axis=0)).mean()
        assert grad > 8.0, "fine detail (charts, checkerboard, text)"
        assert left0.max() - left0.min() > 120, "contrast"
        sky = np.round(np.array(scene.sky_codes) * 255)
        assert np.abs(left0[0, 0] - sky).max() <= 1  # top corner: sky, as cleared
        assert scene.render(0.0)[0].glo == scene.render(0.1)[0].glo  # same texture every frame
    finally:
        scene.release()


def _pattern(height: int, width: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    img[:, : width // 3] = (np.arange(height)[:, None, None] * 255 // max(height - 1, 1)).astype(np.uint8)
    return img


def test_still_image_of_the_eye_size_is_shown_texel_for_texel(gl):
    image = _pattern(20, 30)
    source = StillSource(gl, 30, 20, image)
    try:
        left, right = source.render(0.0)
        assert left is right
        shown = G.download_texture(left)
        assert (shown[..., :3] == image).all() and (shown[..., 3] == 255).all()
    finally:
        source.release()


def test_other_sizes_are_fitted_on_black_in_linear_light(gl):
    image = np.zeros((16, 40, 3), np.uint8)
    image[:, ::2] = 255  # 1-pixel black/white columns: halving them gives 50 % light
    source = StillSource(gl, 20, 20, image)
    try:
        shown = G.download_texture(source.render(0.0)[0])[..., :3].astype(int)
        rect = fit_rect(40, 16, 20, 20)
        assert (rect.x, rect.y, rect.width, rect.height) == (0, 6, 20, 8)
        assert (shown[:6] == 0).all() and (shown[14:] == 0).all()
        inner = shown[7:13, 2:-2]
        # sRGB code of 50 % linear light is 188 (a code-value average would give 128)
        assert np.abs(inner - 188).max() <= 6, inner.mean()
    finally:
        source.release()


def test_folder_images_are_cycled(gl, tmp_path):
    a = _write_png(tmp_path / "1.png", np.full((8, 8, 3), 200, np.uint8))
    _write_png(tmp_path / "2.png", np.full((16, 16, 3), 50, np.uint8))  # another size: another texture
    source = open_source(gl, parse_source(str(tmp_path)), 8, 8, folder_interval_s=0.5)
    try:
        assert isinstance(source, FolderSource) and source.files[0] == a
        values = [int(G.download_texture(source.render(t)[0])[4, 4, 0]) for t in (0.0, 0.4, 0.5, 0.9, 1.0)]
        assert values == [200, 200, 50, 50, 200]
    finally:
        source.release()


def test_animated_gif_plays_at_its_frame_durations(gl, tmp_path):
    from PIL import Image

    frames = [Image.new("RGB", (8, 8), c) for c in ((255, 0, 0), (0, 255, 0), (0, 0, 255))]
    path = tmp_path / "anim.gif"
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=[100, 200, 100], loop=0)
    source = open_source(gl, parse_source(str(path)), 8, 8)
    try:
        assert isinstance(source, AnimatedImageSource)
        colours = [tuple(G.download_texture(source.render(t)[0])[4, 4, :3]) for t in (0.0, 0.15, 0.29, 0.35, 0.45)]
        assert colours == [(255, 0, 0), (0, 255, 0), (0, 255, 0), (0, 0, 255), (255, 0, 0)]
    finally:
        source.release()


def test_video_plays_in_real_time_and_loops(gl, tmp_path):
    import imageio_ffmpeg

    path = tmp_path / "clip.mp4"
    colours = [(230, 30, 30), (30, 230, 30), (30, 30, 230)]
    writer = imageio_ffmpeg.write_frames(str(path), (32, 32), fps=10, quality=9, macro_block_size=16,
                                         ffmpeg_log_level="error")
    writer.send(None)
    for c in colours:
        writer.send(np.ascontiguousarray(np.broadcast_to(np.array(c, np.uint8), (32, 32, 3))))
    writer.close()
    source = open_source(gl, parse_source(str(path)), 32, 32)
    try:
        assert isinstance(source, VideoSource) and source.frames_per_s == pytest.approx(10.0)
        seen = [G.download_texture(source.render(t)[0])[16, 16, :3].astype(int) for t in (0.0, 0.12, 0.25, 0.4)]
        for got, want in zip(seen, [colours[0], colours[1], colours[2], colours[0]]):
            assert np.abs(got - want).max() <= 16, (got, want)
    finally:
        source.release()


def test_a_broken_video_is_an_input_error(gl, tmp_path):
    path = tmp_path / "broken.mp4"
    path.write_bytes(b"not a video")
    with pytest.raises(InputError, match="broken.mp4"):
        open_source(gl, parse_source(str(path)), 8, 8)


# --------------------------------------------------------------------------
# The mirror window (Xvfb), with a still image of the eye size and the real Corrector
# --------------------------------------------------------------------------

EYE_W, EYE_H = 48, 40


@pytest.fixture(scope="module")
def mirror_image(tmp_path_factory):
    from vrcorrect.plumbing.imageio import read_image

    sample = read_image(REPO / "vrcorrect" / "data" / "sample.png")  # 512 x 512: photo, star, text, bars
    crop = np.round(sample[50:50 + EYE_H, 85:85 + EYE_W] * 255).astype(np.uint8)  # face: mid-tones, edges
    path = tmp_path_factory.mktemp("mirror") / "eye.png"
    _write_png(path, crop)
    return path, crop


SAMPLE_RX = (REPO / "vrcorrect" / "data" / "sample_rx.json").read_text()


@pytest.fixture(scope="module")
def shared_mirror(x_display, mirror_image, tmp_path_factory):
    path, _ = mirror_image
    rx = tmp_path_factory.mktemp("rx") / "rx.json"
    rx.write_text(SAMPLE_RX)
    # the plumbing tests below compare the window with the eye's Corrector run again on the same
    # picture, which needs a filter without memory: fista's frame depends on the frames before it
    # (its own tests: test_fista_*; the default is checked in test_default_filter_is_fista)
    config = MirrorConfig(rx=rx, source=str(path), eye_size=(EYE_W, EYE_H), visible=False, vsync=False, platform="x11",
                          time_step_s=0.0, panel=False, screenshot_dir=tmp_path_factory.mktemp("shots"),
                          corrector_options={"filter": "fft"})
    with Mirror(config, echo=None) as m:
        yield m


@pytest.fixture
def mirror(shared_mirror):
    """The shared mirror, back in its initial state (panel hidden), no GL error before or after."""
    m = shared_mirror
    m.state = MirrorState(show_panel=False)
    m._actions.clear()
    m.status = ""
    G.check_gl_errors(m.ctx, "before the test")
    yield m
    G.check_gl_errors(m.ctx, "after the test")


def press(m: Mirror, ch: str | int, mods: int = 0) -> None:
    """A key press (and its release) through the mirror's GLFW key callback."""
    k = ch if isinstance(ch, int) else key(ch)
    m.key_callback(m.window, k, 0, GLFW_PRESS, mods)
    m.key_callback(m.window, k, 0, GLFW_RELEASE, mods)


def settle(app) -> None:
    """What the last frame started designing (a file edit seen, a key's live change) is designed off
    the render thread: wait for the eye source, then one more frame installs it."""
    assert app.eye_source.wait(120)
    app.render()


def halves(m: Mirror) -> dict[str, np.ndarray]:
    screen = m.read_screen().astype(int)
    assert screen.shape == (EYE_H, 2 * EYE_W, 3)
    return {"left": screen[:, :EYE_W], "right": screen[:, EYE_W:]}


def reference(m: Mirror, eye: str, image: np.ndarray, view: str = "displayed") -> np.ndarray:
    """What the eye's Corrector writes for ``image`` into an offscreen framebuffer."""
    src = G.upload_texture(m.ctx, np.dstack([image, np.full(image.shape[:2], 255, np.uint8)]))
    tex, fb = G.render_target(m.ctx, width=image.shape[1], height=image.shape[0])
    try:
        c = m.correctors[eye]
        if view == "displayed":
            c.apply(src, fb)
        else:
            c.simulate(src, fb, corrected=view == "seen_corrected")
        return G.read_framebuffer(fb).astype(int)
    finally:
        G.release(fb, tex, src)


def test_window_is_two_eyes_wide_with_an_opengl_4_3_context(mirror):
    import glfw

    assert mirror.ctx.version_code >= 430
    assert glfw.get_framebuffer_size(mirror.window) == (2 * EYE_W, EYE_H) == mirror.ctx.screen.size


def test_halves_hold_each_eyes_corrected_image(mirror, mirror_image):
    _, image = mirror_image
    mirror.render()
    got = halves(mirror)
    for eye in VIEW_ORDER:
        want = reference(mirror, eye, image)
        assert np.abs(got[eye] - want).max() <= 1, eye
        assert np.abs(got[eye] - image).mean() > 2.0, f"{eye}: the correction changes the image"
    assert np.abs(got["left"] - got["right"]).mean() > 1.0, "two prescriptions, two corrections"


def test_correction_off_shows_the_source(mirror, mirror_image):
    _, image = mirror_image
    press(mirror, "c")
    assert not mirror.state.correction
    mirror.render()
    assert all(not c.enabled for c in mirror.correctors.values())
    for eye, half in halves(mirror).items():
        assert np.abs(half - image).max() <= 1, eye
    press(mirror, "c")
    mirror.render()
    assert np.abs(halves(mirror)["left"] - reference(mirror, "left", image)).max() <= 1


def test_view_switch_shows_what_each_eye_sees(mirror, mirror_image):
    _, image = mirror_image
    mirror.render()
    displayed = halves(mirror)
    pictures = {}
    for view in ("seen_uncorrected", "seen_corrected"):
        press(mirror, "v")
        assert mirror.state.view == view
        mirror.render()
        pictures[view] = got = halves(mirror)
        for eye in VIEW_ORDER:
            assert np.abs(got[eye] - reference(mirror, eye, image, view)).max() <= 1, (view, eye)
            assert np.abs(got[eye] - displayed[eye]).mean() > 2.0, (view, eye)
    for eye in VIEW_ORDER:
        assert np.abs(pictures["seen_corrected"][eye] - pictures["seen_uncorrected"][eye]).mean() > 1.0
    press(mirror, "c")  # correction off: the eye sees the uncorrected image in both seen views
    mirror.render()
    for eye in VIEW_ORDER:
        assert np.abs(halves(mirror)[eye] - pictures["seen_uncorrected"][eye]).max() <= 1
    press(mirror, "c")
    press(mirror, "v")
    assert mirror.state.view == "displayed"


def test_screenshot_writes_the_picture_as_shown(mirror):
    from vrcorrect.plumbing.imageio import read_image

    press(mirror, "v")
    press(mirror, "p")
    before = len(mirror.screenshots)
    mirror.step()  # renders, takes the screenshot from the back buffer, swaps
    assert len(mirror.screenshots) == before + 1
    path = mirror.screenshots[-1]
    assert path.parent == Path(mirror.config.screenshot_dir) and path.suffix == ".png"
    assert "screenshot" in mirror.status
    mirror.render()  # the same frame again (still image, same state)
    shot = np.round(read_image(path) * 255).astype(int)
    assert shot.shape == (EYE_H, 2 * EYE_W, 3)
    assert (shot == mirror.read_screen()).all()
    press(mirror, "p")
    mirror.step()
    assert len(mirror.screenshots) == before + 2 and mirror.screenshots[-1] != path


def test_key_map_and_panel_are_drawn_over_the_picture(mirror):
    mirror.render()
    plain = mirror.read_screen().astype(int)
    press(mirror, "h")
    assert mirror.state.show_keys
    mirror.render()
    with_keys = mirror.read_screen().astype(int)
    assert np.abs(with_keys - plain).mean() > 5.0
    press(mirror, "h")
    press(mirror, "i")
    assert mirror.state.show_panel
    mirror.render()
    with_panel = mirror.read_screen().astype(int)
    assert np.abs(with_panel[:20, :20] - plain[:20, :20]).mean() > 5.0  # the panel's corner
    press(mirror, "i")
    mirror.render()
    assert (mirror.read_screen() == plain).all()


def test_panel_text_shows_stages_state_and_both_prescriptions(mirror):
    mirror.render()
    mirror.render()  # the first frame's times are collected at the start of the second
    lines = "\n".join(mirror.panel_lines())
    for word in ("scene", "correct left", "correct right", "overlay", "displayed image", "correction ON",
                 "edits: right eye", "left\t-2.50 / -0.75 x 160", "right\t-3.00 / -1.50 x 20"):
        assert word in lines, word
    assert set(mirror.timings_ms) <= set(STAGES)
    gpu, cpu = mirror.timings_ms["correct left"]
    assert gpu is not None and gpu >= 0 and cpu >= 0
    press(mirror, "v")
    mirror.render()
    mirror.render()
    assert "simulate left" in mirror.timings_ms and "correct left" not in mirror.timings_ms


@pytest.fixture
def fista_mirror(mirror):
    """The shared mirror with projected-gradient correctors (k = 4) in place of its own, for one test."""
    from vrcorrect.runtime.corrector import Corrector

    own = dict(mirror.correctors)
    mirror.correctors = {eye: Corrector(mirror.ctx, mirror.rx_path, mirror.display, eye, filter="fista",
                                        iterations_per_frame=4) for eye in VIEW_ORDER}
    try:
        yield mirror
    finally:
        for c in mirror.correctors.values():
            c.release()
        mirror.correctors = own


def test_brackets_change_the_iterations_live_and_the_panel_shows_them(fista_mirror):
    m = fista_mirror
    size = m.config.eye_size
    press(m, KEY_RIGHT_BRACKET)
    m.render()
    assert all(c.iterations_per_frame == 8 for c in m.correctors.values())      # both eyes told
    assert m.status == "iterations per frame: 8"
    assert "fista k 8" in "\n".join(m.panel_lines())
    for _ in range(5):                                                           # 8 -> 4 -> 2 -> 1 -> 1 -> 1
        press(m, KEY_LEFT_BRACKET)
    m.render()
    assert [c.iterations_per_frame for c in m.correctors.values()] == [1, 1]
    for _ in range(8):                                                           # 1 -> ... -> 64 -> 64
        press(m, KEY_RIGHT_BRACKET)
    m.render()
    assert [c.iterations_per_frame for c in m.correctors.values()] == [64, 64]
    press(m, KEY_LEFT_BRACKET)
    press(m, KEY_LEFT_BRACKET)
    press(m, KEY_LEFT_BRACKET)
    press(m, KEY_LEFT_BRACKET)                                                   # 64 -> 4
    m.render()
    # the panel's objective is the frame before the last one's, read without touching the live sums
    right = m.correctors["right"]
    before = right.last_objective_fraction(size)
    guard = right.strategy._sized[size].blend.guard
    live = guard.result

    class NoRead:
        def read(self, *a, **k):
            raise AssertionError("the panel must not read the frame in flight")

    m.render()
    guard.result = NoRead()
    try:
        lines = "\n".join(m.panel_lines())
        assert right.previous_objective_fraction(size) == pytest.approx(before, abs=1e-7)
    finally:
        guard.result = live
    assert "fista k 4" in lines and f"right {before:.3f}" in lines and 0 < before < 1
    press(m, "c")                                                                # correction off: no figure
    m.render()
    assert "objective left - right - of uncorrected" in "\n".join(m.panel_lines())
    press(m, "c")


def test_brackets_without_fista_say_so(mirror):
    press(mirror, KEY_RIGHT_BRACKET)
    mirror.render()
    assert "only with --filter admm or fista" in mirror.status
    assert all(c.options.filter == "fft" for c in mirror.correctors.values())
    assert not any(line.startswith("fista") for line in mirror.panel_lines())


def test_releases_and_repeats_do_nothing_and_escape_quits(mirror):
    import glfw

    state = mirror.state
    for action in (GLFW_RELEASE, GLFW_REPEAT):
        mirror.key_callback(mirror.window, key("c"), 0, action, 0)
    assert mirror.state == state
    press(mirror, "e")
    assert mirror.state.edit_eye == "left"
    assert mirror.running
    press(mirror, KEY_ESCAPE)
    assert not mirror.state.running and not mirror.running
    assert glfw.window_should_close(mirror.window)
    glfw.set_window_should_close(mirror.window, False)


def test_a_refused_edit_keeps_the_prescription_and_says_why(mirror, monkeypatch):
    def refuse(eye, offset):
        raise ValidationError("right.sphere_D", -20.25, "-20 to 20 D")

    monkeypatch.setattr(mirror.eye_source, "adjust", refuse)
    before = mirror.current_rx("right")
    press(mirror, "s")
    mirror.render()
    assert mirror.current_rx("right") == before
    assert "right eye unchanged" in mirror.status and "-20 to 20 D" in mirror.status


def test_live_sphere_edit_rebuilds_only_that_eye(mirror, mirror_image):
    _, image = mirror_image
    mirror.render()
    before = halves(mirror)
    press(mirror, "S", MOD_SHIFT)  # right eye (the default), +0.25 D
    mirror.render()
    assert "right eye: designing -2.75" in mirror.status
    settle(mirror)
    after = halves(mirror)
    assert mirror.current_rx("right").sphere_D == pytest.approx(-2.75)
    assert "right eye now" in mirror.status
    assert mirror.correctors["right"].eye_rx.sphere_D == pytest.approx(-2.75)
    assert (after["left"] == before["left"]).all()
    assert np.abs(after["right"] - before["right"]).max() > 2
    assert np.abs(after["right"] - reference(mirror, "right", image)).max() <= 1
    assert "-2.75" in "\n".join(mirror.panel_lines())
    press(mirror, "s")  # back
    mirror.render()
    settle(mirror)
    assert mirror.current_rx("right").sphere_D == pytest.approx(-3.0)
    assert np.abs(halves(mirror)["right"] - before["right"]).max() <= 1


def test_an_edit_never_stalls_the_render_thread(mirror, mirror_image, monkeypatch):
    """With the eye's design held on the worker (as a slow kernel build would be), frames go on
    with the current correction, unchanged; once let go, the next frame installs the new eye."""
    import threading

    entered, release = threading.Event(), threading.Event()
    real = eye_source_module.build_eye_model

    def held(eye, display, options, **kw):
        entered.set()
        assert release.wait(120)
        return real(eye, display, options, **kw)

    monkeypatch.setattr(eye_source_module, "build_eye_model", held)
    mirror.render()
    before = halves(mirror)
    try:
        press(mirror, "S", MOD_SHIFT)                     # right eye +0.25 D: designed on the worker
        mirror.render()
        assert entered.wait(60)
        for _ in range(5):                                # the render thread is not held
            mirror.render()
            assert mirror.current_rx("right").sphere_D == pytest.approx(-3.0)
            assert np.abs(halves(mirror)["right"] - before["right"]).max() <= 1
    finally:
        release.set()
    settle(mirror)
    assert mirror.current_rx("right").sphere_D == pytest.approx(-2.75)
    press(mirror, "s")
    mirror.render()
    settle(mirror)
    assert mirror.current_rx("right").sphere_D == pytest.approx(-3.0)


def test_slow_frames_step_the_scene_clock_and_the_panel_says_so(mirror, monkeypatch):
    """Frames 2 s apart (a software renderer) advance the scene by one 90 Hz frame each, not by 2 s,
    so the warm start meets a scene that moved as it would in a headset; frames 10 ms apart follow
    the clock."""
    import dataclasses

    from vrcorrect.runtime.shell import mirror as M

    clock = iter([100.0, 102.0, 104.0, 104.010, 104.020])
    monkeypatch.setattr(M.time, "perf_counter", lambda: next(clock))
    monkeypatch.setattr(mirror, "config", dataclasses.replace(mirror.config, time_step_s=None))
    monkeypatch.setattr(mirror, "_scene_wall", None)
    monkeypatch.setattr(mirror, "_scene_s", 0.0)
    times = [mirror.scene_time() for _ in range(3)]
    assert times == pytest.approx([0.0, 1 / 90, 2 / 90]) and mirror.stepped
    mirror.state = dataclasses.replace(mirror.state, show_panel=True)
    assert any(line.startswith("slow frames: the scene steps 11.1 ms a frame") for line in mirror.panel_lines())
    assert mirror.scene_time() == pytest.approx(2 / 90 + 0.010) and not mirror.stepped
    assert not any(line.startswith("slow frames") for line in mirror.panel_lines())


def test_prescription_file_changes_show_up_and_bad_files_are_refused(mirror, mirror_image):
    import json
    import time

    _, image = mirror_image
    mirror.render()
    before = halves(mirror)
    doc = json.loads(SAMPLE_RX)
    doc["right"]["sphere_D"] = -2.0
    time.sleep(0.3)  # the correctors look at the file at most every 0.25 s
    mirror.rx_path.write_text(json.dumps(doc))
    mirror.render()
    settle(mirror)
    assert mirror.current_rx("right").sphere_D == -2.0 and mirror.current_rx("left").sphere_D == -2.5
    assert "reloaded" in mirror.status and "right\t-2.00 / -1.50 x 20" in "\n".join(mirror.panel_lines())
    got = halves(mirror)
    assert np.abs(got["right"] - before["right"]).max() > 2
    assert np.abs(got["right"] - reference(mirror, "right", image)).max() <= 1
    time.sleep(0.3)
    mirror.rx_path.write_text('{"schema": "vrcorrect.prescription/1", "right": {"sphere_D": -99}}')
    mirror.render()
    settle(mirror)
    assert "not reloaded" in mirror.status
    assert mirror.current_rx("right").sphere_D == -2.0
    assert (halves(mirror)["right"] == got["right"]).all()
    time.sleep(0.3)
    mirror.rx_path.write_text(SAMPLE_RX)
    mirror.render()
    settle(mirror)
    assert mirror.current_rx("right").sphere_D == -3.0
    assert np.abs(halves(mirror)["right"] - before["right"]).max() <= 1


CREATORS = ("texture", "texture_array", "texture3d", "texture_cube", "depth_texture", "framebuffer", "renderbuffer",
            "depth_renderbuffer", "buffer", "vertex_array", "simple_vertex_array", "program", "compute_shader",
            "query", "sampler", "scope")


def test_no_gpu_allocations_per_frame_after_warm_up(mirror, monkeypatch):
    calls = []
    for name in CREATORS:
        original = getattr(mirror.ctx, name, None)
        if original is not None:
            def counting(*args, _name=name, _original=original, **kwargs):
                calls.append(_name)
                return _original(*args, **kwargs)

            monkeypatch.setattr(mirror.ctx, name, counting)

    def cycle():
        for keys in ("", "v", "v", "v", "h", "i", "hi", "c", "c"):
            for ch in keys:
                press(mirror, ch)
            mirror.step()

    cycle()  # warm-up: every view, overlay and switch once
    calls.clear()
    cycle()
    cycle()
    assert calls == []
    G.release(mirror.ctx.buffer(reserve=16))  # the counting itself works
    assert calls == ["buffer"]


# --------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------


@pytest.mark.parametrize("args, message", [
    (["--size", "0x10"], "--size"),
    (["--size", "big"], "--size"),
    (["--frames", "0"], "--frames"),
    (["--frames", "two"], "--frames"),
    (["--source", "/no/such/picture.png"], "no such file"),
    (["--source", __file__], "unsupported file type"),
    (["--display", "no-such-display"], "no-such-display"),
    (["--rx", "/no/such/rx.json"], "rx.json"),
    (["--model", "m.onnx"], "only with --backend onnx"),
    (["--filter", "fista", "--iterations-per-frame", "65"], "--iterations-per-frame"),
    (["--filter", "separable", "--iterations-per-frame", "4"], "only with --filter admm or fista"),
])
def test_cli_bad_input_is_one_line_and_exit_2(args, message, capsys):
    from vrcorrect.apps.cli import main

    assert main(["mirror", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("vrcorrect: error:") and message in err, err


def _cli(args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli", "mirror", *args], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=600)


def test_cli_without_a_display_says_so(tmp_path, mirror_image):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = str(REPO)
    result = _cli(["--source", str(mirror_image[0]), "--frames", "1"], env, tmp_path)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and "DISPLAY" in result.stderr


def test_cli_renders_n_frames_and_exits(x_display, tmp_path, mirror_image):
    env = dict(os.environ, DISPLAY=x_display, PYTHONPATH=str(REPO))
    result = _cli(["--source", str(mirror_image[0]), "--size", "24x16", "--frames", "3",
                   "--screenshot-dir", str(tmp_path / "shots")], env, tmp_path)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    first, rest = out.split("\n", 1)            # no --rx: the sample prescription is said first, then the keys
    assert first.startswith("vrcorrect: using the sample prescription"), out
    assert rest.startswith("keys:") and "Esc / q" in rest
    assert "3 frame(s)" in out and "correct left" in out and "correct right" in out
    times = re.search(r"3 frame\(s\) in [\d.]+ s \(median ([\d.]+) ms a frame after the first, ([\d.]+) ms on "
                      r"average; set-up", out)
    assert times and float(times[1]) > 0 and float(times[2]) > 0, out       # the median of the two frames after the first


# --------------------------------------------------------------------------
# Start-up: the prescription file is read once, an edit during the builds is picked up
# --------------------------------------------------------------------------


def _edit_during_first_build(monkeypatch, rx: Path, text: str) -> None:
    """Make the first eye's build save ``text`` into ``rx``: a user editing the file during the
    10-40 s a real start-up spends building kernels."""
    from vrcorrect.runtime import corrector as C

    real = C.build_eye_model
    pending = [text]

    def build(eye, display, options=C.CorrectorOptions(), **design):
        if pending:
            rx.write_text(pending.pop())
            st = rx.stat()
            os.utime(rx, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))   # visible on coarse clocks
        return real(eye, display, options, **design)

    monkeypatch.setattr(C, "build_eye_model", build)


@pytest.mark.parametrize("edit, sphere_after, status_words", [
    (SAMPLE_RX.replace('"sphere_D": -3.0', '"sphere_D": -1.0'), -1.0, "reloaded"),
    ('{"schema": "vrcorrect.prescription/1", "right": {"sphere_D": "oops"}', -3.0, "not reloaded"),
], ids=["valid edit", "invalid edit"])
def test_an_edit_during_start_up_is_one_state_for_both_eyes_and_the_panel(x_display, mirror_image, tmp_path,
                                                                          monkeypatch, edit, sphere_after,
                                                                          status_words):
    """Both eyes are built from the one read of the file, whatever happens to it meanwhile; the
    edit then arrives through hot reload, for the corrector and the panel alike.  An invalid edit
    keeps the good prescription already loaded (no exit)."""
    path, _ = mirror_image
    rx = tmp_path / "rx.json"
    rx.write_text(SAMPLE_RX)
    _edit_during_first_build(monkeypatch, rx, edit)
    config = MirrorConfig(rx=rx, source=str(path), eye_size=(EYE_W, EYE_H), visible=False, vsync=False,
                          platform="x11", time_step_s=0.0, panel=True, corrector_options={"filter": "fft"})
    with Mirror(config, echo=None) as m:
        right = m.correctors["right"]
        assert right.eye_rx.sphere_D == -3.0                       # built from the first read,
        assert m.correctors["left"].eye_rx.sphere_D == -2.5        # both eyes,
        assert "-3.00" in "\n".join(m.panel_lines())               # and shown so
        monkeypatch.setattr(eye_source_module, "POLL_INTERVAL_S", 0.0)
        m.render()
        settle(m)
        assert right.eye_rx.sphere_D == sphere_after
        right_line = next(line for line in m.panel_lines() if line.startswith("right"))
        assert f"{sphere_after:+.2f}" in right_line, right_line     # the panel says what is corrected
        assert status_words in m.status, m.status
        assert m.correctors["left"].eye_rx.sphere_D == -2.5



def test_the_panel_shows_what_the_frame_budget_chose(x_display, mirror_image, tmp_path):
    """``vrcorrect mirror --budget-ms``: the panel's knob line gives the budget, the iterations a frame
    it chose for each eye (their mean) and the time it measured (two frames late)."""
    path, _ = mirror_image
    rx = tmp_path / "rx.json"
    rx.write_text(SAMPLE_RX)
    config = MirrorConfig(rx=rx, source=str(path), eye_size=(EYE_W, EYE_H), visible=False, vsync=False,
                          platform="x11", time_step_s=0.0, panel=True,
                          corrector_options={"filter": "admm", "budget_ms": 5000.0})
    with Mirror(config, echo=None) as m:
        for _ in range(4):
            m.render()
        line = next(line for line in m.panel_lines() if line.startswith("admm k"))
        assert "budget 5000 ms: k " in line and " ms)" in line, line
        assert all(c.budget is not None and c.budget.last_ms is not None for c in m.correctors.values())
        press(m, KEY_RIGHT_BRACKET)                              # the keys do not fight the budget
        m.render()
        assert "chosen by the frame budget (5000 ms, --budget-ms)" in m.status, m.status


def _light_entry(codes: np.ndarray) -> float:
    """The bank entry of the light-adapted pupil for a picture of these sRGB codes on quest2 (from the
    formula and the picture, not from the window)."""
    from vrcorrect.physics.pupil import pupil_from_light
    from vrcorrect.runtime.pupil_bank import nearest_bank_pupil, relative_luminance_of
    from vrcorrect.specs.display import decode, get_display

    quest2 = get_display("quest2")
    linear = decode("srgb", codes.astype(np.float32) / 255)
    return nearest_bank_pupil(pupil_from_light(relative_luminance_of(linear, quest2), quest2).diameter_mm)


def test_the_first_design_is_for_the_first_frames_light(x_display, tmp_path):
    """With ``pupil="auto"`` the window reads its source's first frame before it designs, and each
    eye's first design is for the pupil of that frame's light (a bright picture: a small pupil), not a
    mid-grey frame's that the pupil bank would leave a few frames later; the window says so."""
    from vrcorrect.runtime.eye_model import NEUTRAL_LUMINANCE

    bright = np.full((EYE_H, EYE_W, 3), 230, np.uint8)
    _write_png(tmp_path / "bright.png", bright)
    want = _light_entry(bright)
    grey = _light_entry(np.full((1, 1, 3), np.round(255 * NEUTRAL_LUMINANCE ** (1 / 2.2)), np.uint8))
    assert want < grey                                                 # the test means something
    config = MirrorConfig(source=str(tmp_path / "bright.png"), eye_size=(EYE_W, EYE_H), visible=False, vsync=False,
                          platform="x11", panel=False, corrector_options={"filter": "fft", "pupil": "auto", "robust": False})
    lines: list[str] = []
    with Mirror(config, echo=lines.append) as m:
        for eye in VIEW_ORDER:
            c = m.correctors[eye]
            assert c.model.pupil_mm == pytest.approx(want) and c._pupil.current == pytest.approx(want)
        for _ in range(5):                                             # the light measured: the same pupil
            m.step()
        assert all(m.correctors[eye]._pupil.switches == 0 for eye in VIEW_ORDER)
    assert sum(f"pupil {want:.2f} mm from the first frame's light" in line for line in lines) == 2, lines


def test_a_second_launch_takes_its_designs_from_the_cache(x_display, tmp_path, monkeypatch):
    """The window keeps each eye's first design and, with ``pupil="auto"``, the pupil bank's designs in
    vrcorrect's cache folder (``VRCORRECT_CACHE_DIR``).  A folder whose first picture is mid-grey and
    the rest bright: the first design is the grey picture's, and the pupil leaves it for the bright
    light's, designed on the bank's worker and written there.  Launched again, the window starts from
    the kept first designs (it says so) and follows the same light with the kept file: nothing is
    designed and written again, and the designs are the same."""
    from vrcorrect.runtime import eye_cache

    cache = tmp_path / "cache"
    monkeypatch.setenv("VRCORRECT_CACHE_DIR", str(cache))
    grey = np.full((EYE_H, EYE_W, 3), 128, np.uint8)
    light = np.full((EYE_H, EYE_W, 3), 230, np.uint8)
    pictures = tmp_path / "pictures"
    pictures.mkdir()
    _write_png(pictures / "a.png", grey)
    for i in range(9):                                                 # bright nine tenths of the loop
        _write_png(pictures / f"b{i}.png", light)
    (tmp_path / "rx.json").write_text(SAMPLE_RX)
    start, want = _light_entry(grey), _light_entry(light)
    assert start != want
    config = MirrorConfig(rx=tmp_path / "rx.json", source=str(pictures), eye_size=(EYE_W, EYE_H),
                          visible=False, vsync=False, platform="x11", panel=False, folder_interval_s=0.5,
                          time_step_s=0.1, corrector_options={"filter": "fft", "pupil": "auto", "robust": False})
    kept, said, first = [], [], []
    for _ in range(2):
        lines: list[str] = []
        with Mirror(config, echo=lines.append) as m:
            c = m.correctors["right"]
            first.append({eye: m.correctors[eye].model for eye in VIEW_ORDER})
            assert c._pupil.current == pytest.approx(start)           # the grey picture's design to begin with
            deadline = time.monotonic() + 240                          # the bank designs on its worker
            while c._pupil.current != pytest.approx(want) and time.monotonic() < deadline:
                m.step()
            assert c._pupil.current == pytest.approx(want) and c.model.pupil_mm == pytest.approx(want)
            name = eye_cache.design_key(c.model.eye, c.display, c.options, c.age_years, want,
                                        c.model.grid_kernel_size, c.model.reach_mm) + ".pickle"
            kept.append({p.name: p.stat().st_mtime_ns for p in (cache / "designs").glob("*.pickle")})
            assert name in kept[-1]
        said.append(lines)
    assert sum("built in" in line for line in said[0]) == 2 and not any("taken from" in line for line in said[0])
    assert sum(f"taken from {cache}" in line for line in said[1]) == 2 and not any("built in" in line for line in said[1])
    assert len(kept[0]) >= 3                                           # two first designs and the light's
    assert all(kept[1][k] == v for k, v in kept[0].items())           # nothing kept was designed again
    for eye in VIEW_ORDER:
        a, b = first[0][eye], first[1][eye]
        assert (a.eye, a.pupil_mm, a.reach_mm) == (b.eye, b.pupil_mm, b.reach_mm)
        assert np.array_equal(a.kernel.kernel, b.kernel.kernel)
