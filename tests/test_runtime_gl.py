"""The real-time GL plumbing on a real headless context (EGL; Mesa llvmpipe in CI): textures
and orientation, the sRGB shader library against vrcorrect.specs.display, the bundled programs,
compile errors mapped to files. The ``gl`` fixture (conftest.py) fails a test that leaves or
finds a GL error flag set."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vrcorrect.specs import display
from vrcorrect.plumbing.errors import GLError, GLUnavailableError, ShaderCompileError, ShaderError, ValidationError
from vrcorrect.runtime import gl as G
from vrcorrect.runtime import shaders as S

# Tolerances of the GLSL sRGB curves (float32, the driver's pow) against vrcorrect.specs.display in
# float64. Measured on Mesa 22.3 llvmpipe: at most 6.1e-7 relative (about 10 float32 ulp) for
# both; the bounds leave room for GPU drivers' pow, which is exp2(y * log2(x)) with
# approximate exp2/log2.
TOLERANCE = {
    "decode": dict(rtol=4e-6, atol=1e-7),   # sRGB codes -> linear light
    "encode": dict(rtol=4e-6, atol=1e-7),   # linear light -> sRGB codes
}


def all_codes_image() -> np.ndarray:
    """16 x 16 x 3 uint8 holding every code 0-255 in every channel, in different places."""
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16)
    return np.stack([codes, codes[::-1, ::-1], codes.T], axis=-1)


def marked_image(height: int, width: int, seed: int) -> np.ndarray:
    """Random RGB uint8 with a pure red top row and a pure blue bottom row."""
    img = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    img[0] = (255, 0, 0)
    img[-1] = (0, 0, 255)
    return img


def run_program(ctx, program_name: str, source: np.ndarray, *, out_dtype=np.uint8, defines=None,
                root=None, uniforms=None) -> np.ndarray:
    """Draw ``program_name`` over a target the size of ``source`` and read it back (RGBA)."""
    program = S.compile_program(ctx, program_name, defines=defines, root=root)
    vao = G.fullscreen_triangle(ctx, program)
    texture = G.upload_texture(ctx, source)
    target, fbo = G.render_target(ctx, width=source.shape[1], height=source.shape[0], dtype=out_dtype)
    try:
        G.bind_textures(program, {"u_source": texture})
        for name, value in (uniforms or {}).items():
            program[name].value = value
        G.draw_fullscreen(vao, fbo)
        return G.read_framebuffer(fbo, components=4, dtype=out_dtype)
    finally:
        G.release(fbo, target, texture, vao, program)


# --------------------------------------------------------------------------
# Context and errors
# --------------------------------------------------------------------------


def test_headless_context_is_core_330_or_newer(gl):
    assert gl.version_code >= 330
    assert gl.info["GL_RENDERER"]


def test_missing_egl_library_gives_a_typed_error_naming_the_packages(monkeypatch):
    monkeypatch.setenv("GLCONTEXT_LINUX_LIBEGL", "/nonexistent/libEGL.so.1")
    with pytest.raises(GLUnavailableError) as info:
        G.headless_context()
    message = str(info.value)
    assert "EGL" in message and "libegl1" in message and "libgl1-mesa-dri" in message


def test_headless_context_validates_the_version():
    with pytest.raises(ValidationError, match="require"):
        G.headless_context(require=33)


def test_check_gl_errors_names_where_and_clears_the_flags(gl):
    G.check_gl_errors(gl, "clean")  # no error: no exception
    gl.enable_direct(0xFFFF)  # glEnable(an invalid enum) -> GL_INVALID_ENUM
    with pytest.raises(GLError, match="after the bad enable: OpenGL reported GL_INVALID_ENUM"):
        G.check_gl_errors(gl, "after the bad enable")
    G.check_gl_errors(gl, "cleared")


def test_release_unbinds_a_bound_framebuffer_first(gl):
    """moderngl rebinds the last-used framebuffer when it creates the next one; a deleted one
    would be GL_INVALID_OPERATION (the fixture checks there is none)."""
    texture, fbo = G.render_target(gl, width=4, height=4)
    fbo.use()
    G.release(fbo, texture, None)
    texture, fbo = G.render_target(gl, width=4, height=4)
    G.check_gl_errors(gl, "creating a framebuffer after releasing the bound one")
    G.release(fbo, texture)


# --------------------------------------------------------------------------
# Textures and orientation
# --------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_upload_download_round_trip_is_exact(gl, dtype, channels):
    rng = np.random.default_rng(channels)
    shape = (5, 7, channels)  # odd width: rows are not 4-byte aligned
    image = (rng.integers(0, 256, shape).astype(dtype) if dtype == np.uint8
             else rng.standard_normal(shape).astype(np.float32))
    texture = G.upload_texture(gl, image)
    try:
        assert texture.size == (7, 5) and texture.components == channels
        back = G.download_texture(texture)
    finally:
        G.release(texture)
    assert back.dtype == image.dtype and back.shape == image.shape
    np.testing.assert_array_equal(back, image)


@pytest.mark.parametrize("image, match", [
    (np.zeros((4, 4, 3), np.float64), "image.dtype"),
    (np.zeros((4, 4), np.uint8), "image"),
    (np.zeros((4, 4, 5), np.uint8), "image"),
    (np.zeros((0, 4, 3), np.uint8), "size"),
])
def test_upload_rejects_what_it_cannot_hold(gl, image, match):
    with pytest.raises(ValidationError, match=match):
        G.upload_texture(gl, image)


def test_upload_rejects_an_unknown_filter(gl):
    with pytest.raises(ValidationError, match="filter"):
        G.upload_texture(gl, np.zeros((2, 2, 3), np.uint8), filter="cubic")


def test_gl_side_is_gl_natural_the_image_top_is_the_highest_y(gl, tmp_path):
    """What the module docstring promises: gl_FragCoord.y grows towards the image's top row,
    and texelFetch at GL row y reads image row H-1-y."""
    (tmp_path / "probe.glsl").write_text(
        '#version 330 core\n#include "fullscreen.glsl"\n'
        "#if defined VERTEX_SHADER\nvoid main() { gl_Position = fullscreen_position(fullscreen_uv(gl_VertexID)); }\n#endif\n"
        "#if defined FRAGMENT_SHADER\nuniform sampler2D u_source;\nout vec4 f;\n"
        "void main() { f = vec4(gl_FragCoord.y, texelFetch(u_source, ivec2(gl_FragCoord.xy), 0).r, 0.0, 1.0); }\n"
        "#endif\n")
    (tmp_path / "fullscreen.glsl").write_text((S.shaders_dir() / "fullscreen.glsl").read_text())
    height, width = 6, 3
    image = np.zeros((height, width, 1), np.float32)
    image[:, :, 0] = np.arange(height)[:, None]  # image row index
    out = run_program(gl, "probe.glsl", image, out_dtype=np.float32, root=tmp_path)
    np.testing.assert_array_equal(out[:, 0, 0], np.arange(height)[::-1] + 0.5)  # top row: highest y
    np.testing.assert_array_equal(out[:, :, 1], image[:, :, 0])  # and it holds the image's top row


def test_rect_conversions_are_top_left_based():
    assert G.gl_viewport(G.Rect(0, 0, 4, 2), 10, 8) == (0, 6, 4, 2)  # the top strip
    assert G.gl_viewport(G.Rect(6, 6, 4, 2), 10, 8) == (6, 0, 4, 2)  # the bottom-right corner
    assert G.uv_rect(G.Rect(0, 0, 5, 4), 10, 8) == (0.0, 0.5, 0.5, 0.5)  # top-left quadrant
    with pytest.raises(ValidationError, match="inside the 10x8 target"):
        G.gl_viewport(G.Rect(8, 0, 4, 2), 10, 8)
    with pytest.raises(ValidationError, match="rect.x"):
        G.Rect(-1, 0, 1, 1)
    with pytest.raises(ValidationError, match="width and height >= 1"):
        G.Rect(0, 0, 0, 1)


def test_bind_textures_names_an_unknown_sampler(gl):
    program = S.compile_program(gl, "passthrough.glsl")
    texture = G.upload_texture(gl, np.zeros((2, 2, 3), np.uint8))
    try:
        with pytest.raises(ValidationError, match="textures.u_missing"):
            G.bind_textures(program, {"u_missing": texture})
    finally:
        G.release(texture, program)


# --------------------------------------------------------------------------
# sRGB in GLSL against vrcorrect.specs.display
# --------------------------------------------------------------------------


def test_srgb_round_trip_of_8bit_codes_is_exact(gl):
    image = all_codes_image()
    out = run_program(gl, "passthrough.glsl", image, defines={"DECODE_SRGB": None, "ENCODE_SRGB": None})
    np.testing.assert_array_equal(out[..., :3], image)
    assert (out[..., 3] == 255).all()


def test_srgb_decode_matches_display_on_all_256_codes(gl):
    image = all_codes_image()
    out = run_program(gl, "passthrough.glsl", image, out_dtype=np.float32, defines={"DECODE_SRGB": None})
    expected = display.decode("srgb", image.astype(np.float64) / 255.0)
    np.testing.assert_allclose(out[..., :3], expected, **TOLERANCE["decode"])
    assert (out[..., 3] == 1.0).all()  # alpha passes through


def test_srgb_encode_matches_display_on_a_dense_ramp(gl):
    # 4096 linear values, and the ones either side of the 0.0031308 knee
    ramp = np.linspace(0.0, 1.0, 64 * 64, dtype=np.float32)
    knee = np.float32(0.0031308)
    ramp[:4] = [np.nextafter(knee, np.float32(0)), knee, np.nextafter(knee, np.float32(1)), 1e-6]
    image = np.repeat(ramp.reshape(64, 64, 1), 3, axis=2)
    out = run_program(gl, "passthrough.glsl", image, out_dtype=np.float32, defines={"ENCODE_SRGB": None})
    expected = display.encode("srgb", image.astype(np.float64))
    np.testing.assert_allclose(out[..., :3], expected, **TOLERANCE["encode"])


def test_srgb_decode_near_its_knee_and_out_of_range_clamps_like_display(gl):
    knee = np.float32(0.04045)
    values = np.array([np.nextafter(knee, np.float32(0)), knee, np.nextafter(knee, np.float32(1)),
                       -0.5, 1.5, 0.0, 1.0, 0.5], np.float32)
    image = np.repeat(values.reshape(1, -1, 1), 3, axis=2)
    out = run_program(gl, "passthrough.glsl", image, out_dtype=np.float32, defines={"DECODE_SRGB": None})
    expected = display.decode("srgb", image.astype(np.float64))
    np.testing.assert_allclose(out[..., :3], expected, **TOLERANCE["decode"])
    assert out[0, 3, 0] == 0.0 and out[0, 4, 0] == 1.0


def test_passthrough_without_defines_copies_floats_exactly(gl):
    image = np.random.default_rng(3).random((9, 11, 4), dtype=np.float32) * 4 - 2  # outside [0, 1] too
    out = run_program(gl, "passthrough.glsl", image, out_dtype=np.float32)
    np.testing.assert_array_equal(out, image)


# --------------------------------------------------------------------------
# Composite: sources into rectangles of the output
# --------------------------------------------------------------------------


def composite_into(ctx, sources_and_rects, width, height, *, defines=None, dtype=np.uint8, source_rects=None):
    program = S.compile_program(ctx, "composite.glsl", defines=defines)
    vao = G.fullscreen_triangle(ctx, program)
    target, fbo = G.render_target(ctx, width=width, height=height, dtype=dtype)
    textures = []
    try:
        fbo.use()
        ctx.viewport = (0, 0, width, height)
        fbo.clear(0.0, 0.0, 0.0, 1.0)
        for i, (image, rect) in enumerate(sources_and_rects):
            texture = G.upload_texture(ctx, image)
            textures.append(texture)
            G.bind_textures(program, {"u_source": texture})
            crop = (source_rects or {}).get(i)
            program["u_source_rect"].value = ((0.0, 0.0, 1.0, 1.0) if crop is None
                                              else G.uv_rect(crop, image.shape[1], image.shape[0]))
            G.draw_fullscreen(vao, fbo, rect=rect)
        return G.read_framebuffer(fbo, components=3, dtype=dtype)
    finally:
        G.release(*textures, fbo, target, vao, program)


def test_composite_two_eyes_side_by_side(gl):
    h, w = 6, 5
    left, right = marked_image(h, w, 1), marked_image(h, w, 2)
    out = composite_into(gl, [(left, G.Rect(0, 0, w, h)), (right, G.Rect(w, 0, w, h))], 2 * w, h)
    np.testing.assert_array_equal(out[:, :w], left)
    np.testing.assert_array_equal(out[:, w:], right)
    assert (out[0] == (255, 0, 0)).all() and (out[-1] == (0, 0, 255)).all()  # top row stays on top


def test_composite_stacked_puts_the_first_rect_on_top(gl):
    h, w = 4, 7
    top, bottom = marked_image(h, w, 3), marked_image(h, w, 4)
    out = composite_into(gl, [(top, G.Rect(0, 0, w, h)), (bottom, G.Rect(0, h, w, h))], w, 2 * h + 1)
    np.testing.assert_array_equal(out[:h], top)
    np.testing.assert_array_equal(out[h:2 * h], bottom)
    assert (out[2 * h] == 0).all()  # the row below both rectangles is untouched (cleared to black)


def test_composite_crops_the_source_with_a_top_left_rect(gl):
    image = marked_image(8, 10, 5)
    crop = G.Rect(2, 0, 4, 3)  # 4 x 3 from the top, starting at column 2
    out = composite_into(gl, [(image, G.Rect(0, 0, 4, 3))], 4, 3, source_rects={0: crop})
    np.testing.assert_array_equal(out, image[0:3, 2:6])


def test_composite_scales_and_encodes(gl):
    linear = np.full((2, 2, 3), 0.214041, np.float32)  # sRGB code 0.5 (display.encode gives 0.5000)
    out = composite_into(gl, [(linear, G.Rect(1, 1, 6, 4))], 8, 6, defines={"ENCODE_SRGB": None},
                         dtype=np.float32)
    np.testing.assert_allclose(out[1:5, 1:7], display.encode("srgb", linear[0, 0].astype(np.float64))
                               * np.ones((4, 6, 3)), **TOLERANCE["encode"])
    assert (out[0] == 0).all() and (out[:, 0] == 0).all() and (out[5] == 0).all() and (out[:, 7] == 0).all()


# --------------------------------------------------------------------------
# Compiling: every bundled program, and errors mapped back to files
# --------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["passthrough.glsl", "composite.glsl"])
@pytest.mark.parametrize("defines", [{}, {"DECODE_SRGB": None}, {"ENCODE_SRGB": None},
                                     {"DECODE_SRGB": None, "ENCODE_SRGB": None}])
def test_bundled_programs_compile(gl, name, defines):
    S.compile_program(gl, name, defines=defines).release()


BROKEN_LIB = "// lib\nfloat helper(float x) {\n    return x * undeclared_in_lib;\n}\n"


def broken_tree(root: Path, fragment_body: str = "color = vec4(helper(1.0));") -> Path:
    (root / "lib.glsl").write_text(BROKEN_LIB)
    (root / "ok.glsl").write_text("float helper(float x) { return x; }\n")
    (root / "p.glsl").write_text(
        '#version 330 core\n#include "{lib}"\n#if defined VERTEX_SHADER\n'
        "void main() { gl_Position = vec4(0.0, 0.0, 0.0, 1.0); }\n#endif\n"
        "#if defined FRAGMENT_SHADER\nout vec4 color;\nvoid main() {\n"
        f"    {fragment_body}\n}}\n#endif\n")
    return root


def test_compile_error_in_an_included_file_names_that_file_and_line(gl, tmp_path):
    root = broken_tree(tmp_path)
    (root / "p.glsl").write_text((root / "p.glsl").read_text().replace("{lib}", "lib.glsl"))
    with pytest.raises(ShaderCompileError) as info:
        S.compile_program(gl, "p.glsl", root=root)
    message = str(info.value)
    assert "shader program p.glsl failed to build" in message
    assert "vertex stage:" in message  # the include is in both stages; the vertex stage fails first
    assert "lib.glsl:3(" in message and "undeclared_in_lib" in message
    assert ":10003" not in message  # the encoded line number is translated
    assert info.value.raw_log != info.value.log


def test_compile_error_in_the_program_file_names_its_line(gl, tmp_path):
    root = broken_tree(tmp_path, fragment_body="color = vec4(helper(1.0)) + not_declared;")
    (root / "p.glsl").write_text((root / "p.glsl").read_text().replace("{lib}", "ok.glsl"))
    with pytest.raises(ShaderCompileError) as info:
        S.compile_program(gl, "p.glsl", root=root)
    assert "fragment stage:" in str(info.value)
    assert "p.glsl:9(" in str(info.value) and "not_declared" in str(info.value)


def test_compile_error_from_a_define_value_points_at_its_use(gl, tmp_path):
    root = broken_tree(tmp_path, fragment_body="color = vec4(GAIN);")
    (root / "p.glsl").write_text((root / "p.glsl").read_text().replace("{lib}", "ok.glsl"))
    with pytest.raises(ShaderCompileError, match=r"p\.glsl:9\(\d+\).*oops_symbol"):
        S.compile_program(gl, "p.glsl", defines={"GAIN": "oops_symbol"}, root=root)


def test_link_error_is_reported(gl, tmp_path):
    (tmp_path / "p.glsl").write_text(
        "#version 330 core\nfloat missing(float x);\n#if defined VERTEX_SHADER\n"
        "void main() { gl_Position = vec4(missing(1.0)); }\n#endif\n"
        "#if defined FRAGMENT_SHADER\nout vec4 c;\nvoid main() { c = vec4(1.0); }\n#endif\n")
    with pytest.raises(ShaderCompileError, match="link:"):
        S.compile_program(gl, "p.glsl", root=tmp_path)


def test_compute_programs(gl, tmp_path):
    (tmp_path / "c.glsl").write_text(
        "#version 430\n#if defined COMPUTE_SHADER\nlayout(local_size_x = 1) in;\n"
        "layout(std430, binding = 0) buffer Out { float values[]; };\n"
        "void main() { values[gl_GlobalInvocationID.x] = float(gl_GlobalInvocationID.x) * SCALE; }\n#endif\n")
    compute = S.compile_compute(gl, "c.glsl", defines={"SCALE": 0.5}, root=tmp_path)
    buffer = gl.buffer(reserve=4 * 4)
    try:
        buffer.bind_to_storage_buffer(0)
        compute.run(group_x=4)
        np.testing.assert_array_equal(np.frombuffer(buffer.read(), np.float32), [0.0, 0.5, 1.0, 1.5])
    finally:
        G.release(buffer, compute)
    with pytest.raises(ShaderError, match="no vertex or fragment stage.*compile_compute"):
        S.compile_program(gl, "c.glsl", defines={"SCALE": 0.5}, root=tmp_path)
    with pytest.raises(ShaderError, match="no '#if defined COMPUTE_SHADER'"):
        S.compile_compute(gl, "passthrough.glsl")
    (tmp_path / "bad.glsl").write_text((tmp_path / "c.glsl").read_text().replace("SCALE", "NO_SUCH"))
    with pytest.raises(ShaderCompileError, match=r"compute stage:\n.*bad\.glsl:5\("):
        S.compile_compute(gl, "bad.glsl", root=tmp_path)


def test_a_released_headless_context_gives_the_thread_back_its_previous_context(gl):
    """A second headless context made and released inside a test (as ``vrcorrect render`` run in the
    process does): the test's context is current again, its objects are there and new ones are made
    in it.  (glcontext leaves a released context current: the GL calls that followed went to a
    destroyed context; unbinding it alone left none current, and moderngl could not make a program.)"""
    picture = np.arange(8 * 6 * 4, dtype=np.uint8).reshape(6, 8, 4)
    before = G.upload_texture(gl, picture)
    other = G.headless_context(require=430)
    other.release()
    program = S.compile_program(gl, "passthrough.glsl")           # made in the test's context
    try:
        assert np.array_equal(G.download_texture(before), picture)  # the test's texture, read in its context
    finally:
        G.release(program, before)
