"""The one vocabulary (``vrcorrect.specs.vocabulary``): each enum holds exactly the names that the
prescription files, the command line and the library accept, in the order they are shown; the
iterations-per-frame range is one constant that the CLI's error and the windows' keys both state;
and no module writes these vocabularies out again as literals."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pytest

from vrcorrect.apps.cli import build_parser
from vrcorrect.apps.cli_docs import commands
from vrcorrect.apps.realtime_options import parse_iterations_per_frame
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.runtime.eye_model import DEFAULT_ITERATIONS, CorrectorOptions
from vrcorrect.runtime.strategies import STRATEGIES
from vrcorrect.runtime.shell.keys import ITERATION_KEYS, next_iterations
from vrcorrect.runtime.layer.config import eye_of_view
from vrcorrect.solvers import LEARNED, METHODS
from vrcorrect.solvers.realtime import AdmmFrames
from vrcorrect.specs.prescription import problems_in, template_text
from vrcorrect.specs.vocabulary import (
    ITERATIONS_PER_FRAME,
    ITERATIVE_FILTERS,
    MAX_ITERATIONS_PER_FRAME,
    VIEW_ORDER,
    Backend,
    Eye,
    Filter,
    Method,
    Precision,
    either,
    names,
    one_of,
)

PACKAGE = Path(__file__).resolve().parents[1] / "vrcorrect"


def _choices(words: tuple[str, ...], option: str) -> tuple[str, ...] | None:
    parser = next(c.parser for c in commands() if c.words == words)
    for action in parser._actions:
        if option in action.option_strings:
            return tuple(action.choices) if action.choices is not None else None
    raise AssertionError(f"vrcorrect {' '.join(words)} has no {option}")


# ------------------------------------------------------------ the names

def test_eyes_are_the_prescription_files_keys_in_their_order():
    assert names(Eye) == ("right", "left")
    assert tuple(re.findall(r'^  "(right|left)": \{', template_text(), re.M)) == names(Eye)
    missing = [p.field for p in problems_in({"schema": "vrcorrect.prescription/1"})]
    assert [f for f in missing if f in names(Eye)] == list(names(Eye))


def test_the_display_order_is_left_then_right_and_is_openxrs_view_order():
    assert names(VIEW_ORDER) == ("left", "right") and set(VIEW_ORDER) == set(Eye)
    assert [eye_of_view(v) for v in (0, 1)] == list(VIEW_ORDER)


def test_backends_filters_precisions_are_what_the_options_accept():
    for backend in Backend:
        assert CorrectorOptions(backend=backend.value).backend == backend
    for f in Filter:
        assert CorrectorOptions(filter=f.value).filter == f
    for p in Precision:
        assert CorrectorOptions(precision=p.value).precision == p
    assert set(STRATEGIES) == set(Filter) and list(DEFAULT_ITERATIONS) == list(ITERATIVE_FILTERS)
    for field, kind in (("backend", Backend), ("filter", Filter), ("precision", Precision)):
        with pytest.raises(ValidationError) as e:
            CorrectorOptions(**{field: "nope"})
        assert (e.value.field, e.value.value, e.value.allowed) == (field, "nope", one_of(kind))
    assert one_of(Backend) == "one of glsl, onnx"
    with pytest.raises(ValidationError, match=re.escape(one_of(Precision))):     # checked before anything else
        AdmmFrames.__init__(object.__new__(AdmmFrames), None, None, (8, 8), precision="double")


def test_methods_are_the_solvers_names():
    assert names(Method) == (*METHODS, LEARNED)
    assert all(type(n) is str for n in names(Method))


def test_the_command_line_offers_the_vocabulary_in_its_order():
    for words in (("correct",), ("simulate",), ("overlay",)):
        assert _choices(words, "--eye") == names(Eye)
    for words in (("render",), ("mirror",), ("overlay",), ("xr",)):
        assert _choices(words, "--backend") == names(Backend)
        assert _choices(words, "--filter") == names(Filter)
    assert set(_choices(("correct",), "--method")) <= set(Method)
    assert set(_choices(("evaluate",), "--methods")) <= set(Method) - {Method.NONE, Method.LEARNED}
    for words, option in ((("render",), "--backend"), (("correct",), "--eye"), (("render",), "--filter")):
        assert all(type(c) is str for c in _choices(words, option))   # argparse shows each choice's repr


def test_a_bad_choice_is_refused_with_the_plain_names(capsys):
    parser = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["render", "in.png", "-o", "out.png", "--backend", "vulkan"])
    assert "(choose from 'glsl', 'onnx')" in capsys.readouterr().err


def test_either_and_one_of_read_as_the_errors_always_did():
    assert either(Eye) == "'right' or 'left'"
    assert either(VIEW_ORDER) == "'left' or 'right'"
    assert either(Backend, quote=False) == "glsl or onnx"
    assert either(ITERATIVE_FILTERS) == "'admm' or 'fista'"
    assert one_of(Filter) == "one of admm, fista, fft, separable"


# ------------------------------------------------------------ the iteration range

def test_the_iteration_range_is_one_constant_the_cli_and_the_keys_state():
    low, high = ITERATIONS_PER_FRAME
    assert (low, high) == (1, 64) and 0 < low < high <= MAX_ITERATIONS_PER_FRAME
    assert parse_iterations_per_frame(str(low)) == low and parse_iterations_per_frame(str(high)) == high
    for bad in (low - 1, high + 1):
        with pytest.raises(ValidationError) as e:
            parse_iterations_per_frame(str(bad))
        assert e.value.allowed == f"a whole number of iterations from {low} to {high}"
    [(_, what)] = ITERATION_KEYS
    assert f"({low}-{high};" in what
    assert next_iterations(high, True) == high and next_iterations(low, False) == low
    help_text = next(c.parser for c in commands() if c.words == ("render",)).format_help()
    assert f"{low} to {high}" in " ".join(help_text.split())
    with pytest.raises(ValidationError) as e:
        CorrectorOptions(iterations_per_frame=MAX_ITERATIONS_PER_FRAME + 1)
    assert e.value.allowed == f"a whole number from 0 to {MAX_ITERATIONS_PER_FRAME}"


# ------------------------------------------------------------ no second copy

_LITERAL_COPIES = [
    (re.compile(r"""\(\s*["'](right|left)["']\s*,\s*["'](right|left)["']\s*\)"""), "an eye tuple: Eye or VIEW_ORDER"),
    (re.compile(r"""\(\s*["']glsl["']\s*,\s*["']onnx["']\s*\)"""), "a backend tuple: Backend"),
    (re.compile(r"""[=!]=\s*["'](glsl|onnx)["']|["'](glsl|onnx)["']\s*[=!]="""), "a backend compared: Backend"),
    (re.compile(r"""\(\s*["']admm["']\s*,\s*["']fista["']"""), "a filter tuple: Filter, ITERATIVE_FILTERS"),
    (re.compile(r"""\(\s*["']half["']\s*,\s*["']single["']\s*\)"""), "a precision tuple: Precision"),
    (re.compile(r"""\(\s*1\s*,\s*64\s*\)"""), "the iteration range: ITERATIONS_PER_FRAME"),
    (re.compile(r"""^\s*(EYES|BACKENDS|FILTERS|ITERATIVE_FILTERS|PRECISIONS|ITERATIONS_RANGE)\s*=""", re.M),
     "a vocabulary constant of its own"),
]


@pytest.mark.parametrize("pattern,what", _LITERAL_COPIES, ids=[w.split(":")[0] for _, w in _LITERAL_COPIES])
def test_no_module_writes_the_vocabulary_again(pattern, what):
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "vocabulary.py" and path.parent.name == "specs":
            continue
        for m in pattern.finditer(path.read_text(encoding="utf-8")):
            line = path.read_text(encoding="utf-8").count("\n", 0, m.start()) + 1
            found.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {m.group(0).strip()}")
    assert not found, f"{what} belongs to vrcorrect.specs.vocabulary:\n" + "\n".join(found)


def test_members_stand_in_for_their_text():
    options = {Eye.LEFT: 1}
    assert options["left"] == 1 and f"{Eye.LEFT}" == "left" and json.dumps({Eye.RIGHT: Backend.GLSL}) == \
        '{"right": "glsl"}'
    assert isinstance(argparse.Namespace(eye=Eye.RIGHT).eye, str)
