"""The GLSL loader without OpenGL: includes, defines, stages, cycle and missing-file errors,
and the #line mapping of compiler locations back to files.

The mapping is checked by property: a small model of GLSL's ``#line`` rule (after
``#line N S`` the next line is line N) is run over the assembled text, and every line must
decode (``ShaderSource.locate``) to a file and line holding exactly that text."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrcorrect.plumbing.errors import InputError, ShaderError, ValidationError
from vrcorrect.runtime import shaders as S

REPO = Path(__file__).resolve().parents[1]

PROGRAM = """#version 330 core
// a program
#include "lib.glsl"
#if defined VERTEX_SHADER
void main() { gl_Position = vec4(helper(1.0)); }
#endif
#if defined FRAGMENT_SHADER
out vec4 color;
void main() { color = vec4(helper(0.5)); }
#endif
"""

LIB = """// a library
#ifndef LIB_GLSL
#define LIB_GLSL
#include "sub/deep.glsl"
float helper(float x) { return deep(x) * 2.0; }
#endif
"""

DEEP = """float deep(float x) {
    return x + 1.0;
}
"""


def write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    return write(tmp_path, {"prog.glsl": PROGRAM, "lib.glsl": LIB, "sub/deep.glsl": DEEP})


def simulate_line_numbers(text: str) -> list[tuple[int, int, str]]:
    """(source number, line number, text) of every line GLSL compiles, by the GLSL >= 3.30
    rule: after ``#line N S`` the following line is line N of source S."""
    out = []
    source, line = 0, 1
    for raw in text.splitlines():
        m = re.fullmatch(r"#line (\d+) (\d+)", raw)
        if m:
            line, source = int(m[1]), int(m[2])
            continue
        out.append((source, line, raw))
        line += 1
    return out


def assert_mapping_exact(src: S.ShaderSource, root: Path, defines_text: list[str]) -> None:
    files = {name: (root / name).read_text().splitlines() for name in src.files if name != S.DEFINES_FILE}
    files[S.DEFINES_FILE] = defines_text
    for source, line, text in simulate_line_numbers(src.text):
        where = src.locate(line, source)
        assert where is not None, f"line {source}:{line} {text!r} does not decode"
        assert src.locate(line, 0) == where  # Mesa reports source 0 for every file
        name, n = where
        expected = files[name][n - 1]
        assert text == expected.replace("#include ", "# include ") or text == expected, (name, n, text, expected)
    # the origins table says the same for every line that is not a #line directive
    physical = [o for o in src.origins if o is not None]
    assert physical == [src.locate(line, source) for source, line, _ in simulate_line_numbers(src.text)]


# --------------------------------------------------------------------------
# Assembly
# --------------------------------------------------------------------------


def test_version_first_then_stage_and_caller_defines(tree):
    src = S.load_stage("prog.glsl", "vertex", defines={"A": None, "B": 3, "C": 0.25, "D": "vec3(1.0)"}, root=tree)
    lines = src.text.splitlines()
    assert lines[0] == "#version 330 core"
    assert lines[1].startswith("#line ")
    assert lines[2:7] == ["#define VERTEX_SHADER", "#define A", "#define B 3", "#define C 0.25", "#define D vec3(1.0)"]
    assert lines[7] == "#line 2 0"  # back to the program's own line 2
    assert src.files[0] == "prog.glsl" and src.files[-1] == S.DEFINES_FILE


def test_each_stage_defines_only_its_own_macro(tree):
    program = S.load_program("prog.glsl", root=tree)
    assert program.stage_names == ("vertex", "fragment")
    assert "#define FRAGMENT_SHADER" in program["fragment"].text
    assert "VERTEX_SHADER\n" not in program["fragment"].text.split("#line 2 0")[0]
    with pytest.raises(KeyError, match="no compute stage"):
        program["compute"]


def test_includes_are_expanded_recursively_relative_to_the_root(tree):
    src = S.load_stage("prog.glsl", "fragment", root=tree)
    assert src.files[:3] == ("prog.glsl", "lib.glsl", "sub/deep.glsl")
    assert "return x + 1.0;" in src.text and "float helper(float x)" in src.text
    assert not re.search(r"#\s*include\s*\"", src.text)
    assert_mapping_exact(src, tree, ["#define FRAGMENT_SHADER"])


def test_include_path_is_relative_to_shaders_not_to_the_including_file(tmp_path):
    write(tmp_path, {"p.glsl": '#version 330 core\n#include "sub/a.glsl"\n#if defined VERTEX_SHADER\n#endif\n',
                     "sub/a.glsl": '#include "b.glsl"\n', "b.glsl": "// top-level b\n",
                     "sub/b.glsl": "// sub b (must not be used)\n"})
    text = S.load_stage("p.glsl", "vertex", root=tmp_path).text
    assert "// top-level b" in text and "sub b" not in text


def test_an_include_is_expanded_every_time_it_appears(tmp_path):
    """Like C: the loader does not skip repeats (stage blocks may each include a file);
    libraries guard themselves with #ifndef."""
    write(tmp_path, {"p.glsl": '#version 330 core\n#if defined VERTEX_SHADER\n#include "x.glsl"\n#endif\n'
                               '#if defined FRAGMENT_SHADER\n#include "x.glsl"\n#endif\n',
                     "x.glsl": "float x_function() { return 1.0; }\n"})
    src = S.load_stage("p.glsl", "fragment", root=tmp_path)
    assert src.text.count("float x_function()") == 2
    assert src.files == ("p.glsl", "x.glsl", S.DEFINES_FILE)
    assert_mapping_exact(src, tmp_path, ["#define FRAGMENT_SHADER"])


def test_includes_in_comments_are_not_expanded_and_not_left_for_moderngl(tmp_path):
    write(tmp_path, {"p.glsl": '#version 330 core\n// #include "missing.glsl"\n/* start\n#include "missing.glsl"\n'
                               'end */\n#if defined VERTEX_SHADER\n#endif\n'})
    src = S.load_stage("p.glsl", "vertex", root=tmp_path)
    assert src.files == ("p.glsl", S.DEFINES_FILE)
    # moderngl rewrites '#include "x"' anywhere in the text, comments included
    assert not re.search(r'#include\s+"', src.text)
    assert_mapping_exact(src, tmp_path, ["#define VERTEX_SHADER"])


def test_include_with_trailing_comment_and_spaces(tmp_path):
    write(tmp_path, {"p.glsl": '#version 330 core\n  #  include   "a.glsl"  // the library\n'
                               "#if defined VERTEX_SHADER\n#endif\n",
                     "a.glsl": "float a() { return 1.0; }\n"})
    assert "float a()" in S.load_stage("p.glsl", "vertex", root=tmp_path).text


def test_a_one_line_program(tmp_path):
    write(tmp_path, {"p.glsl": "#version 330 core\n"})
    with pytest.raises(ShaderError, match="no stage blocks"):
        S.load_program("p.glsl", root=tmp_path)
    src = S.load_stage("p.glsl", "vertex", root=tmp_path)
    assert src.text.splitlines()[0] == "#version 330 core"


# --------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------


def test_include_cycle_names_the_chain(tmp_path):
    write(tmp_path, {"p.glsl": '#version 330 core\n#include "a.glsl"\n',
                     "a.glsl": '// a\n#include "b.glsl"\n', "b.glsl": '#include "a.glsl"\n'})
    with pytest.raises(ShaderError) as info:
        S.load_stage("p.glsl", "vertex", root=tmp_path)
    message = str(info.value)
    assert "p.glsl:2 -> a.glsl:2 -> b.glsl:1 includes a.glsl" in message
    assert "cycle" in message and "a.glsl -> b.glsl -> a.glsl" in message


def test_self_include_is_a_cycle(tmp_path):
    write(tmp_path, {"p.glsl": '#version 330 core\n#include "p.glsl"\n'})
    with pytest.raises(ShaderError, match=r"p\.glsl:2 includes p\.glsl: include cycle"):
        S.load_stage("p.glsl", "vertex", root=tmp_path)


def test_missing_include_names_the_chain(tmp_path):
    write(tmp_path, {"p.glsl": '#version 330 core\n\n#include "a.glsl"\n', "a.glsl": '\n\n\n#include "gone.glsl"\n'})
    with pytest.raises(InputError, match=r"p\.glsl:3 -> a\.glsl:4 includes gone\.glsl: no such file"):
        S.load_stage("p.glsl", "vertex", root=tmp_path)


def test_missing_program_file(tmp_path):
    with pytest.raises(InputError, match=r"nothere\.glsl: no such file"):
        S.load_program("nothere.glsl", root=tmp_path)


@pytest.mark.parametrize("text", ["", "\n#version 330 core\n", "// comment\n#version 330 core\n",
                                  "void main() {}\n", "  #version 330 core\n"])
def test_version_must_be_the_first_line(tmp_path, text):
    write(tmp_path, {"p.glsl": text})
    with pytest.raises(ShaderError, match=r"p\.glsl:1: the first line must be '#version"):
        S.load_stage("p.glsl", "vertex", root=tmp_path)


def test_version_in_an_included_file_or_later_is_an_error(tmp_path):
    write(tmp_path, {"p.glsl": '#version 330 core\n#include "lib.glsl"\n', "lib.glsl": "#version 330 core\n",
                     "q.glsl": "#version 330 core\n\n#version 330 core\n"})
    with pytest.raises(ShaderError, match=r"p\.glsl:2 -> lib\.glsl:1: #version belongs on the first line"):
        S.load_stage("p.glsl", "vertex", root=tmp_path)
    with pytest.raises(ShaderError, match=r"q\.glsl:3: #version"):
        S.load_stage("q.glsl", "vertex", root=tmp_path)


def test_line_directives_in_files_are_refused(tmp_path):
    write(tmp_path, {"p.glsl": "#version 330 core\n#line 40\n"})
    with pytest.raises(ShaderError, match=r"p\.glsl:2: #line is reserved"):
        S.load_stage("p.glsl", "vertex", root=tmp_path)


@pytest.mark.parametrize("directive", ["#include <a.glsl>", "#include a.glsl", '#include "../a.glsl"',
                                       '#include "/etc/a.glsl"', '#include "a.txt"', '#include "a.glsl" x'])
def test_malformed_or_escaping_includes(tmp_path, directive):
    write(tmp_path, {"p.glsl": f"#version 330 core\n{directive}\n", "a.glsl": "\n"})
    with pytest.raises(ShaderError, match=r"p\.glsl:2"):
        S.load_stage("p.glsl", "vertex", root=tmp_path)


@pytest.mark.parametrize("name", ["../x.glsl", "/abs/x.glsl", "x.txt", "a//b.glsl", "a\\b.glsl", 3])
def test_program_name_is_validated(name):
    with pytest.raises(ValidationError, match="shader"):
        S.load_stage(name, "vertex")


def test_stage_is_validated(tree):
    with pytest.raises(ValidationError, match="stage = 'tesselation'"):
        S.load_stage("prog.glsl", "tesselation", root=tree)


@pytest.mark.parametrize("name, value", [("1A", None), ("GL_X", None), ("A__B", None), ("A-B", 1),
                                         ("VERTEX_SHADER", None), ("A", True), ("A", float("nan")),
                                         ("A", float("inf")), ("A", "two\nlines"), ("A", [1, 2])])
def test_bad_defines(tree, name, value):
    with pytest.raises(ValidationError, match="defines"):
        S.load_stage("prog.glsl", "vertex", defines={name: value}, root=tree)


def test_too_long_a_file(tmp_path):
    write(tmp_path, {"p.glsl": "#version 330 core\n" + "\n" * S.LINE_STRIDE})
    with pytest.raises(ShaderError, match="at most 9999"):
        S.load_stage("p.glsl", "vertex", root=tmp_path)


def test_program_stages_reads_directives_only(tmp_path):
    write(tmp_path, {"c.glsl": "#version 430\n// VERTEX_SHADER in a comment\n#ifdef COMPUTE_SHADER\n#endif\n",
                     "g.glsl": "#version 330 core\n#if defined(VERTEX_SHADER)\n#elif defined FRAGMENT_SHADER\n"
                               "#endif\n#if defined GEOMETRY_SHADER\n#endif\n"})
    assert S.program_stages("c.glsl", root=tmp_path) == ("compute",)
    assert S.program_stages("g.glsl", root=tmp_path) == ("vertex", "geometry", "fragment")


# --------------------------------------------------------------------------
# Mapping compiler messages back
# --------------------------------------------------------------------------


def test_translate_mesa_nvidia_and_amd_logs(tree):
    src = S.load_stage("prog.glsl", "fragment", root=tree)
    k_lib = src.files.index("lib.glsl")
    k_deep = src.files.index("sub/deep.glsl")
    lib5 = k_lib * S.LINE_STRIDE + 5
    deep2 = k_deep * S.LINE_STRIDE + 2
    log = (f"0:{lib5}(12): error: `x' undeclared\n"
           f"{k_deep}:{deep2}(3): warning: unused\n"
           f"0({deep2}) : error C1008: undefined variable\n"
           f"ERROR: 0:{lib5}: 'helper' : no matching overload\n"
           "0:9(7): error: in the program itself\n"
           "error: unresolved reference (no location)\n"
           "0:99999(1): error: not one of ours\n")
    assert src.translate_log(log).splitlines() == [
        "lib.glsl:5(12): error: `x' undeclared",
        "sub/deep.glsl:2(3): warning: unused",
        "sub/deep.glsl:2 : error C1008: undefined variable",
        "ERROR: lib.glsl:5: 'helper' : no matching overload",
        "prog.glsl:9(7): error: in the program itself",
        "error: unresolved reference (no location)",
        "0:99999(1): error: not one of ours",
    ]


def test_locate_rejects_a_contradicting_source_number(tree):
    src = S.load_stage("prog.glsl", "fragment", root=tree)
    k = src.files.index("lib.glsl")
    assert src.locate(k * S.LINE_STRIDE + 2, k) == ("lib.glsl", 2)
    assert src.locate(k * S.LINE_STRIDE + 2, 0) == ("lib.glsl", 2)
    assert src.locate(k * S.LINE_STRIDE + 2, k + 1) is None
    assert src.locate(k * S.LINE_STRIDE, k) is None  # line 0 does not exist


def test_define_lines_map_to_the_defines_pseudo_file(tree):
    src = S.load_stage("prog.glsl", "vertex", defines={"GAIN": 2}, root=tree)
    d = src.files.index(S.DEFINES_FILE)
    assert src.locate(d * S.LINE_STRIDE + 2) == (S.DEFINES_FILE, 2)
    assert_mapping_exact(src, tree, ["#define VERTEX_SHADER", "#define GAIN 2"])


@st.composite
def include_trees(draw):
    """1-5 files; file i may include files j > i only (no cycles), anywhere among its lines."""
    n = draw(st.integers(1, 5))
    code = st.sampled_from(["float a;", "", "// note", "/* block", "end */", "  vec3 b = vec3(1.0);",
                            "#if defined VERTEX_SHADER", "#endif", "#define X 1"])
    files = {}
    for i in range(n):
        lines = draw(st.lists(code, max_size=8))
        targets = draw(st.lists(st.integers(i + 1, n - 1), max_size=3)) if i < n - 1 else []
        for t in targets:
            lines.insert(draw(st.integers(0, len(lines))), f'#include "f{t}.glsl"')
        # keep block comments closed so the includes stay live
        text = "\n".join(line for line in lines if "/*" not in line and "*/" not in line)
        files[f"f{i}.glsl"] = text + "\n"
    files["f0.glsl"] = "#version 330 core\n" + files["f0.glsl"]
    return files


@settings(max_examples=60, deadline=None)
@given(include_trees(), st.sampled_from(S.STAGES))
def test_every_assembled_line_maps_back_to_its_file_and_line(files, stage):
    with tempfile.TemporaryDirectory() as tmp:
        root = write(Path(tmp), files)
        src = S.load_stage("f0.glsl", stage, defines={"K": 1}, root=root)
        assert_mapping_exact(src, root, [f"#define {S.stage_macro(stage)}", "#define K 1"])


# --------------------------------------------------------------------------
# The bundled shaders
# --------------------------------------------------------------------------


def test_shaders_dir_is_the_top_level_folder_and_ships_in_the_package():
    assert S.shaders_dir().resolve() == (REPO / "shaders").resolve()
    # vrcorrect/shaders links to ../shaders so that package data ("shaders/*.glsl") puts the
    # files into wheels; pyproject.toml must list them.
    assert (REPO / "vrcorrect" / "shaders").resolve() == (REPO / "shaders").resolve()
    assert '"shaders/*.glsl"' in (REPO / "pyproject.toml").read_text()


BUNDLED = sorted(p.name for p in (REPO / "shaders").glob("*.glsl"))


@pytest.mark.parametrize("name", BUNDLED)
def test_bundled_files_follow_the_conventions(name):
    lines = (REPO / "shaders" / name).read_text().splitlines()
    if lines[0].startswith("#version"):  # a program
        program = S.load_program(name, defines={"DECODE_SRGB": None, "ENCODE_SRGB": None})
        assert program.stage_names in (("vertex", "fragment"), ("compute",))
        for src in program.stages:
            defines = [f"#define {S.stage_macro(src.stage)}", "#define DECODE_SRGB", "#define ENCODE_SRGB"]
            assert_mapping_exact(src, S.shaders_dir(), defines)
    else:  # a library: guarded (or a template, included once per set of parameters, that refuses to
        # build without them), no stages
        assert lines[0].startswith("//"), "a library starts with a comment saying what it is"
        text = "\n".join(lines)
        template = re.search(r"^#if !defined\((\w+)\).*\n#error .*template", text, re.M)
        assert template or re.search(r"^#ifndef (\w+)\n#define \1$", text, re.M), "a library has an include guard"
        assert not S._STAGE_REF.search(text)


def test_srgb_library_uses_the_standard_thresholds():
    text = (REPO / "shaders" / "srgb.glsl").read_text()
    for constant in ("0.04045", "12.92", "0.055", "1.055", "2.4", "0.0031308"):
        assert constant in text
