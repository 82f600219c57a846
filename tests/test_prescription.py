"""Tests for vrcorrect.specs.prescription: power vectors, cylinder forms, validation, files."""

from __future__ import annotations

import copy
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrcorrect.plumbing.errors import InputError, FieldProblem, ValidationError, ValidationErrors
from vrcorrect.specs.prescription import (
    MISSING,
    SCHEMA,
    EyeRx,
    HigherOrder,
    PowerVector,
    Prescription,
    bundled_sample_path,
    load_prescription,
    parse_prescription,
    problems_in,
    template_text,
    to_json_text,
    validate_file,
    write_template,
)
from vrcorrect.specs.vocabulary import Eye


def valid_doc() -> dict:
    return {
        "schema": SCHEMA,
        "notes": "test",
        "right": {
            "sphere_D": -2.5,
            "cylinder_D": -1.0,
            "axis_deg": 20,
            "pupil_diameter_mm": 4.0,
            "accommodation_D": 0.0,
            "higher_order": {"pupil_diameter_mm": 6.0, "coefficients_um": {"7": 0.10, "12": -0.05}},
        },
        "left": {"sphere_D": -2.0, "cylinder_D": 0.5, "axis_deg": 180, "pupil_diameter_mm": 3.0},
    }


def eye(S: float = 0.0, C: float = 0.0, axis: float = 0.0, pupil: float = 4.0, **kw) -> EyeRx:
    return EyeRx(sphere_D=S, cylinder_D=C, axis_deg=axis, pupil_diameter_mm=pupil, **kw)


def fields_of(problems: list[FieldProblem]) -> list[str]:
    return [p.field for p in problems]


def set_path(doc: dict, path: str, value) -> dict:
    """Set (or with value MISSING, delete) a dotted path in a copy of doc."""
    doc = copy.deepcopy(doc)
    *parents, last = path.split(".")
    node = doc
    for key in parents:
        node = node[key]
    if value is MISSING:
        del node[last]
    else:
        node[last] = value
    return doc


# ---------------------------------------------------------------------------
# Power vector (Thibos 1997), worked by hand
# ---------------------------------------------------------------------------

def assert_pv(pv: PowerVector, M: float, J0: float, J45: float, tol: float = 1e-12) -> None:
    assert pv.M_D == pytest.approx(M, abs=tol)
    assert pv.J0_D == pytest.approx(J0, abs=tol)
    assert pv.J45_D == pytest.approx(J45, abs=tol)


def test_power_vector_cylinder_axis_180():
    # plano / -2.00 x 180: M = -1, J0 = -(-1) cos 360° = +1, J45 = 0
    assert_pv(eye(0.0, -2.0, 180).power_vector(), -1.0, 1.0, 0.0)
    assert_pv(eye(0.0, -2.0, 0).power_vector(), -1.0, 1.0, 0.0)


def test_power_vector_cylinder_axis_45_and_90_and_135():
    assert_pv(eye(0.0, -2.0, 45).power_vector(), -1.0, 0.0, 1.0)
    assert_pv(eye(0.0, -2.0, 90).power_vector(), -1.0, -1.0, 0.0)
    assert_pv(eye(0.0, -2.0, 135).power_vector(), -1.0, 0.0, -1.0)


def test_power_vector_sphere_only():
    assert_pv(eye(-3.25).power_vector(), -3.25, 0.0, 0.0)
    assert_pv(eye(+4.0, 0.0, 73).power_vector(), 4.0, 0.0, 0.0)


def test_power_vector_axis_is_in_degrees_not_radians():
    # -3.00 / -1.00 x 20: M = -3.5, J0 = 0.5 cos 40°, J45 = 0.5 sin 40° (hand values)
    pv = eye(-3.0, -1.0, 20).power_vector()
    assert_pv(pv, -3.5, 0.38302222155948906, 0.32139380484326968, tol=1e-12)
    # axis treated as radians would give 0.5 cos 40 rad = -0.333...
    assert pv.J0_D > 0


def test_power_vector_plus_cylinder_form_same_eye():
    # -3.00 / +2.00 x 90 is -1.00 / -2.00 x 180
    assert_pv(eye(-3.0, 2.0, 90).power_vector(), -2.0, 1.0, 0.0)
    assert_pv(eye(-1.0, -2.0, 180).power_vector(), -2.0, 1.0, 0.0)


# ---------------------------------------------------------------------------
# Cylinder forms
# ---------------------------------------------------------------------------

spheres = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False)
cylinders = st.floats(min_value=-10.0, max_value=10.0, allow_nan=False)
axes = st.floats(min_value=0.0, max_value=180.0, allow_nan=False)


def axis_distance(a: float, b: float) -> float:
    """Distance between two axes in degrees, with 0 ≡ 180."""
    d = abs(a - b) % 180.0
    return min(d, 180.0 - d)


@given(spheres, cylinders, axes)
def test_transposed_has_same_power_vector(S, C, axis):
    e = eye(S, C, axis)
    t = e.transposed()
    assert t.sphere_D == pytest.approx(S + C, abs=1e-12)
    assert t.cylinder_D == -C
    assert 0.0 <= t.axis_deg < 180.0
    assert axis_distance(t.axis_deg, axis) == pytest.approx(90.0, abs=1e-9)
    a, b = e.power_vector(), t.power_vector()
    assert abs(a.M_D - b.M_D) <= 1e-12
    assert abs(a.J0_D - b.J0_D) <= 1e-12
    assert abs(a.J45_D - b.J45_D) <= 1e-12


@given(spheres, cylinders, axes)
def test_transposing_twice_returns_the_same_eye(S, C, axis):
    e = eye(S, C, axis, accommodation_D=2.0)
    tt = e.transposed().transposed()
    assert tt.sphere_D == pytest.approx(S, abs=1e-12)
    assert tt.cylinder_D == C
    assert axis_distance(tt.axis_deg, axis) <= 1e-9
    assert tt.pupil_diameter_mm == e.pupil_diameter_mm
    assert tt.accommodation_D == e.accommodation_D


@given(spheres, cylinders, axes)
def test_minus_cylinder_form(S, C, axis):
    e = eye(S, C, axis)
    m = e.minus_cylinder()
    assert m.cylinder_D <= 0.0
    assert 0.0 <= m.axis_deg < 180.0
    a, b = e.power_vector(), m.power_vector()
    assert abs(a.M_D - b.M_D) <= 1e-12
    assert abs(a.J0_D - b.J0_D) <= 1e-12
    assert abs(a.J45_D - b.J45_D) <= 1e-12


def test_minus_cylinder_examples():
    m = eye(-3.0, 2.0, 90).minus_cylinder()
    assert (m.sphere_D, m.cylinder_D, m.axis_deg) == (-1.0, -2.0, 0.0)
    m = eye(-1.0, -2.0, 180).minus_cylinder()  # already minus form: axis 180 -> 0
    assert (m.sphere_D, m.cylinder_D, m.axis_deg) == (-1.0, -2.0, 0.0)
    m = eye(1.0, 0.5, 10).minus_cylinder()
    assert (m.sphere_D, m.cylinder_D, m.axis_deg) == (1.5, -0.5, 100.0)


def test_transposed_sphere_out_of_range_raises():
    # +18.00 / +4.00 x 90 is +22.00 / -4.00 x 180: beyond the ±20 D sphere range
    with pytest.raises(ValidationErrors) as info:
        eye(18.0, 4.0, 90).minus_cylinder()
    assert "sphere_D" in str(info.value)


def test_axis_180_accepted_on_input():
    assert eye(0.0, -1.0, 180).axis_deg == 180.0


# ---------------------------------------------------------------------------
# Power vector -> EyeRx -> power vector
# ---------------------------------------------------------------------------

@given(
    st.floats(min_value=-15.0, max_value=15.0, allow_nan=False),
    st.floats(min_value=-3.5, max_value=3.5, allow_nan=False),
    st.floats(min_value=-3.5, max_value=3.5, allow_nan=False),
)
def test_power_vector_round_trip(M, J0, J45):
    pv = PowerVector(M, J0, J45)
    e = EyeRx.from_power_vector(pv, pupil_diameter_mm=5.0)
    assert e.cylinder_D <= 0.0
    assert 0.0 <= e.axis_deg < 180.0
    assert e.pupil_diameter_mm == 5.0
    back = e.power_vector()
    assert back.M_D == pytest.approx(M, abs=1e-12)
    assert back.J0_D == pytest.approx(J0, abs=1e-12)
    assert back.J45_D == pytest.approx(J45, abs=1e-12)


@given(spheres, cylinders, axes)
def test_eye_to_power_vector_and_back_is_minus_cylinder_form(S, C, axis):
    e = eye(S, C, axis)
    back = EyeRx.from_power_vector(e.power_vector(), e.pupil_diameter_mm)
    m = e.minus_cylinder()
    assert back.sphere_D == pytest.approx(m.sphere_D, abs=1e-9)
    assert back.cylinder_D == pytest.approx(m.cylinder_D, abs=1e-9)
    if abs(C) > 1e-3:  # the axis is meaningless without cylinder
        assert axis_distance(back.axis_deg, m.axis_deg) < 1e-6


def test_from_power_vector_examples():
    e = EyeRx.from_power_vector(PowerVector(-1.0, 1.0, 0.0), 4.0)
    assert (e.sphere_D, e.cylinder_D, e.axis_deg) == (0.0, -2.0, 0.0)
    e = EyeRx.from_power_vector(PowerVector(-1.0, 0.0, 1.0), 4.0)
    assert (e.sphere_D, e.cylinder_D) == (0.0, -2.0)
    assert e.axis_deg == pytest.approx(45.0, abs=1e-12)
    e = EyeRx.from_power_vector(PowerVector(-1.0, 0.0, -1.0), 4.0)
    assert e.axis_deg == pytest.approx(135.0, abs=1e-12)
    e = EyeRx.from_power_vector(PowerVector(2.0, 0.0, 0.0), 3.0, accommodation_D=1.5)
    assert (e.sphere_D, e.cylinder_D, e.axis_deg, e.accommodation_D) == (2.0, 0.0, 0.0, 1.5)
    # tiny negative J45 must not give axis 180
    e = EyeRx.from_power_vector(PowerVector(0.0, 1.0, -1e-300), 4.0)
    assert 0.0 <= e.axis_deg < 180.0


def test_from_power_vector_limit_cases_survive_round_off():
    for S, C, axis in [(0.0, 10.0, 10.0), (20.0, -10.0, 33.0), (-20.0, 10.0, 77.0), (10.0, 10.0, 1.0)]:
        back = EyeRx.from_power_vector(eye(S, C, axis).power_vector(), 4.0)
        assert back.cylinder_D == pytest.approx(-abs(C), abs=1e-12)
        assert -20.0 <= back.sphere_D <= 20.0


def test_from_power_vector_rejects_bad_input():
    with pytest.raises(ValidationErrors) as info:
        EyeRx.from_power_vector(PowerVector(math.nan, 0.0, 0.0), 4.0)
    assert "M_D" in str(info.value)
    with pytest.raises(ValidationErrors) as info:  # C = -2*6 = -12 is out of range
        EyeRx.from_power_vector(PowerVector(0.0, 6.0, 0.0), 4.0)
    assert "cylinder_D" in fields_of(info.value.problems)


# ---------------------------------------------------------------------------
# Programmatic construction validates
# ---------------------------------------------------------------------------

def test_eyerx_rejects_bad_values_all_at_once():
    with pytest.raises(ValidationErrors) as info:
        EyeRx(sphere_D=-25.0, cylinder_D=True, axis_deg=200, pupil_diameter_mm=math.nan, accommodation_D=-1)
    assert fields_of(info.value.problems) == [
        "sphere_D", "cylinder_D", "axis_deg", "pupil_diameter_mm", "accommodation_D"]


def test_eyerx_stores_floats():
    e = eye(-2, -1, 20, 4)
    assert all(type(v) is float for v in (e.sphere_D, e.cylinder_D, e.axis_deg, e.pupil_diameter_mm))


def test_with_changes_revalidates():
    e = eye(-2.0, -1.0, 20)
    assert e.with_changes(sphere_D=-3.0).sphere_D == -3.0
    assert e.with_changes(sphere_D=-3.0).cylinder_D == -1.0
    with pytest.raises(ValidationErrors) as info:
        e.with_changes(sphere_D=30.0)
    assert "sphere_D" in str(info.value)
    with pytest.raises(ValidationErrors) as info:
        e.with_changes(sphere=-3.0)
    assert "sphere_D" in str(info.value)  # suggests the right name


def test_eye_pupil_larger_than_measured_pupil_rejected():
    ho = HigherOrder(pupil_diameter_mm=5.0, coefficients_um=((7, 0.1),))
    assert eye(pupil=5.0, higher_order=ho).higher_order == ho
    with pytest.raises(ValidationErrors) as info:
        eye(pupil=6.0, higher_order=ho)
    assert "extrapolate" in str(info.value)


def test_higher_order_sorted_and_validated():
    ho = HigherOrder(6.0, {12: -0.05, 7: 0.1})
    assert ho.coefficients_um == ((7, 0.1), (12, -0.05))
    assert HigherOrder(6.0, ((12, -0.05), (7, 0.1))) == ho
    with pytest.raises(ValidationErrors) as info:
        HigherOrder(6.0, ((7, 0.1), (7, 0.2)))
    assert "once" in str(info.value)
    with pytest.raises(ValidationErrors) as info:
        HigherOrder(0.5, ((4, 0.1), (8, 11.0)))
    assert fields_of(info.value.problems) == [
        "pupil_diameter_mm", "coefficients_um.4", "coefficients_um.8"]


def test_prescription_eye():
    rx = parse_prescription(valid_doc())
    assert rx.eye("right") is rx.right
    assert rx.eye("left") is rx.left
    with pytest.raises(ValidationError) as info:
        rx.eye("OD")
    assert info.value.field == "eye"


def test_prescription_rejects_non_eyes():
    with pytest.raises(ValidationErrors):
        Prescription(right=eye(), left={"sphere_D": 0})  # type: ignore[arg-type]


# ---------------------------------------------------------------------------
# Document validation
# ---------------------------------------------------------------------------

def test_valid_doc_parses():
    doc = valid_doc()
    assert problems_in(doc) == []
    rx = parse_prescription(doc)
    assert rx.notes == "test"
    assert rx.right.sphere_D == -2.5
    assert rx.right.higher_order == HigherOrder(6.0, ((7, 0.10), (12, -0.05)))
    assert rx.left.axis_deg == 180.0
    assert rx.left.accommodation_D == 0.0
    assert rx.left.higher_order is None


BOUNDARIES_OK = [
    ("right.sphere_D", -20), ("right.sphere_D", 20.0), ("right.cylinder_D", -10),
    ("right.cylinder_D", 10), ("right.axis_deg", 0), ("right.axis_deg", 180),
    ("left.pupil_diameter_mm", 1), ("left.pupil_diameter_mm", 9),
    ("right.accommodation_D", 15), ("right.higher_order.coefficients_um.65", 10.0),
    ("right.higher_order.coefficients_um.6", -10), ("right.pupil_diameter_mm", 6.0),
]


@pytest.mark.parametrize("path,value", BOUNDARIES_OK)
def test_boundary_values_accepted(path, value):
    assert problems_in(set_path(valid_doc(), path, value)) == []


# (path to change, new value, field reported, words the allowed text must contain)
BAD = [
    ("schema", "vrcorrect.prescription/2", "schema", SCHEMA),
    ("schema", MISSING, "schema", SCHEMA),
    ("notes", 5, "notes", "string"),
    ("right", MISSING, "right", "sphere_D"),
    ("left", [1, 2], "left", "object"),
    ("right.sphere_D", MISSING, "right.sphere_D", "-20 to 20 (dioptres)"),
    ("right.cylinder_D", MISSING, "right.cylinder_D", "-10 to 10"),
    ("left.axis_deg", MISSING, "left.axis_deg", "0 to 180"),
    ("left.pupil_diameter_mm", MISSING, "left.pupil_diameter_mm", "1 to 9"),
    ("right.sphere_D", -20.25, "right.sphere_D", "-20 to 20 (dioptres)"),
    ("right.sphere_D", 21, "right.sphere_D", "-20 to 20"),
    ("right.sphere_D", 10 ** 400, "right.sphere_D", "-20 to 20"),
    ("right.sphere_D", "-2.5", "right.sphere_D", "number"),
    ("right.sphere_D", True, "right.sphere_D", "number"),
    ("right.sphere_D", None, "right.sphere_D", "number"),
    ("right.sphere_D", math.nan, "right.sphere_D", "finite"),
    ("right.sphere_D", math.inf, "right.sphere_D", "finite"),
    ("left.cylinder_D", -10.5, "left.cylinder_D", "-10 to 10 (dioptres"),
    ("left.cylinder_D", False, "left.cylinder_D", "number"),
    ("left.axis_deg", -1, "left.axis_deg", "0 to 180 (degrees"),
    ("left.axis_deg", 180.5, "left.axis_deg", "0 to 180"),
    ("left.axis_deg", -math.inf, "left.axis_deg", "0 to 180"),
    ("right.pupil_diameter_mm", 0.5, "right.pupil_diameter_mm", "1 to 9 (millimetres)"),
    ("left.pupil_diameter_mm", 9.5, "left.pupil_diameter_mm", "1 to 9"),
    ("right.accommodation_D", -0.5, "right.accommodation_D", "0 to 15"),
    ("right.accommodation_D", 16, "right.accommodation_D", "0 to 15"),
    ("right.accommodation_D", None, "right.accommodation_D", "0 to 15"),
    ("right.sphre_D", 1.0, "right.sphre_D", "sphere_D"),
    ("extra", 1, "extra", "no such field"),
    ("Right", {}, "Right", "right"),
    ("right.higher_order.order", 3, "right.higher_order.order", "no such field"),
    ("right.higher_order", None, "right.higher_order", "pupil_diameter_mm"),
    ("right.higher_order", [0.1], "right.higher_order", "coefficients_um"),
    ("right.higher_order.pupil_diameter_mm", MISSING, "right.higher_order.pupil_diameter_mm", "1 to 9"),
    ("right.higher_order.pupil_diameter_mm", 9.5, "right.higher_order.pupil_diameter_mm", "1 to 9"),
    ("right.higher_order.coefficients_um", MISSING, "right.higher_order.coefficients_um", "micrometres"),
    ("right.higher_order.coefficients_um", [0.1], "right.higher_order.coefficients_um", "micrometres"),
    ("right.higher_order.coefficients_um.3", 0.1, "right.higher_order.coefficients_um.3", "sphere_D"),
    ("right.higher_order.coefficients_um.5", 0.1, "right.higher_order.coefficients_um.5", "6 to 65"),
    ("right.higher_order.coefficients_um.66", 0.1, "right.higher_order.coefficients_um.66", "6 to 65"),
    ("right.higher_order.coefficients_um.7.0", 0.1, "right.higher_order.coefficients_um.7.0", "6 to 65"),
    ("right.higher_order.coefficients_um.coma", 0.1, "right.higher_order.coefficients_um.coma", "OSA/ANSI"),
    ("right.higher_order.coefficients_um.07", 0.1, "right.higher_order.coefficients_um.07", "OSA/ANSI"),
    ("right.higher_order.coefficients_um.7", 10.5, "right.higher_order.coefficients_um.7", "-10 to 10 (micrometres)"),
    ("right.higher_order.coefficients_um.7", math.nan, "right.higher_order.coefficients_um.7", "finite"),
    ("right.higher_order.coefficients_um.7", "0.1", "right.higher_order.coefficients_um.7", "number"),
    ("right.pupil_diameter_mm", 6.5, "right.pupil_diameter_mm", "extrapolate"),
]


def _set_bad(doc: dict, path: str, value) -> dict:
    # keys containing dots (like "7.0") are written under coefficients_um directly
    prefix = "right.higher_order.coefficients_um."
    if path.startswith(prefix) and path != prefix + "7":
        doc = copy.deepcopy(doc)
        doc["right"]["higher_order"]["coefficients_um"][path[len(prefix):]] = value
        return doc
    return set_path(doc, path, value)


@pytest.mark.parametrize("path,value,field,words", BAD, ids=[f"{b[0]}={b[1]!r}"[:60] for b in BAD])
def test_each_rule_rejects_with_field_name(path, value, field, words):
    doc = _set_bad(valid_doc(), path, value)
    problems = problems_in(doc)
    assert field in fields_of(problems)
    problem = next(p for p in problems if p.field == field)
    assert words in problem.allowed
    with pytest.raises(ValidationErrors) as info:
        parse_prescription(doc, source="rx.json")
    message = str(info.value)
    assert field in message
    assert message.startswith("rx.json: ")
    # every problem in the document is an error; nothing is silently dropped
    assert info.value.problems == problems


def test_missing_required_value_reported_as_missing():
    problems = problems_in(set_path(valid_doc(), "right.sphere_D", MISSING))
    assert problems == [FieldProblem("right.sphere_D", MISSING, problems[0].allowed)]
    assert "<missing>" in str(problems[0])


def test_all_problems_reported_together():
    doc = valid_doc()
    doc["right"]["sphere_D"] = -30
    doc["left"]["axis_deg"] = True
    doc["left"]["colour"] = "blue"
    problems = problems_in(doc)
    assert fields_of(problems) == ["right.sphere_D", "left.axis_deg", "left.colour"]
    with pytest.raises(ValidationErrors) as info:
        parse_prescription(doc)
    assert len(info.value.problems) == 3
    assert str(info.value).startswith("3 problems:")


def test_many_problems_in_one_eye():
    doc = valid_doc()
    doc["right"] = {"sphere_D": "x", "cylinder_D": None, "bogus": 1}
    fields = fields_of(problems_in(doc))
    assert set(fields) == {"right.sphere_D", "right.cylinder_D", "right.axis_deg",
                           "right.pupil_diameter_mm", "right.bogus"}


def test_top_level_not_object():
    problems = problems_in([1, 2])
    assert len(problems) == 1
    with pytest.raises(ValidationErrors):
        parse_prescription("hello")


def test_both_eyes_missing():
    fields = fields_of(problems_in({"schema": SCHEMA}))
    assert fields == ["right", "left"]


# ---------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------

def write(tmp_path, text: str, name: str = "rx.json"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_load_valid_file(tmp_path):
    path = write(tmp_path, json.dumps(valid_doc()))
    assert load_prescription(path) == parse_prescription(valid_doc())
    assert load_prescription(str(path)) == parse_prescription(valid_doc())
    assert validate_file(path) == []


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_nan_and_infinity_tokens_rejected(tmp_path, token):
    text = json.dumps(valid_doc()).replace('"sphere_D": -2.5', f'"sphere_D": {token}')
    assert token in text
    path = write(tmp_path, text)
    with pytest.raises(ValidationErrors) as info:
        load_prescription(path)
    assert fields_of(info.value.problems) == ["right.sphere_D"]
    assert str(path) in str(info.value)
    assert fields_of(validate_file(path)) == ["right.sphere_D"]


def test_bool_in_file_rejected(tmp_path):
    text = json.dumps(valid_doc()).replace('"pupil_diameter_mm": 3.0', '"pupil_diameter_mm": true')
    with pytest.raises(ValidationErrors) as info:
        load_prescription(write(tmp_path, text))
    assert fields_of(info.value.problems) == ["left.pupil_diameter_mm"]


def test_comment_lines_are_ignored(tmp_path):
    text = "// a comment\n   // indented comment\n" + json.dumps(valid_doc(), indent=2).replace(
        '  "left"', '\t// comment between keys, with "quotes" and { braces\n  "left"')
    rx = load_prescription(write(tmp_path, text))
    assert rx == parse_prescription(valid_doc())


def test_comment_with_crlf_line_endings(tmp_path):
    text = "// comment\r\n" + json.dumps(valid_doc(), indent=2).replace("\n", "\r\n")
    path = tmp_path / "rx.json"
    path.write_bytes(text.encode("utf-8"))
    assert load_prescription(path) == parse_prescription(valid_doc())


def test_utf8_bom_accepted(tmp_path):
    path = tmp_path / "rx.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps(valid_doc()).encode("utf-8"))
    assert load_prescription(path) == parse_prescription(valid_doc())


def test_syntax_error_line_number_after_comments(tmp_path):
    lines = [
        "// line 1",
        "// line 2",
        "{",
        '  "schema": "vrcorrect.prescription/1",',
        "  // line 5",
        '  "right": {"sphere_D": -1, "cylinder_D": 0, "axis_deg": 0, "pupil_diameter_mm": 4},',
        '  "left": {"sphere_D": -1 "cylinder_D": 0, "axis_deg": 0, "pupil_diameter_mm": 4}',  # line 7
        "}",
    ]
    with pytest.raises(InputError) as info:
        load_prescription(write(tmp_path, "\n".join(lines)))
    message = str(info.value)
    assert "line 7" in message
    assert "column 27" in message  # the '"' after -1
    assert "\n" not in message


def test_trailing_comment_is_a_syntax_error_with_hint(tmp_path):
    text = json.dumps(valid_doc(), indent=2).replace('"notes": "test",', '"notes": "test", // why')
    with pytest.raises(InputError) as info:
        load_prescription(write(tmp_path, text))
    assert "line 3" in str(info.value)
    assert "whole-line" in str(info.value)


def test_comment_marker_inside_string_is_kept(tmp_path):
    doc = valid_doc()
    doc["notes"] = "see https://example.org // not a comment"
    assert load_prescription(write(tmp_path, json.dumps(doc))).notes == doc["notes"]


def test_missing_file(tmp_path):
    with pytest.raises(InputError) as info:
        load_prescription(tmp_path / "nope.json")
    assert "nope.json" in str(info.value)
    assert "not found" in str(info.value)
    with pytest.raises(InputError):
        validate_file(tmp_path / "nope.json")


def test_directory_is_not_a_file(tmp_path):
    with pytest.raises(InputError) as info:
        load_prescription(tmp_path)
    assert "directory" in str(info.value)


def test_not_utf8(tmp_path):
    path = tmp_path / "rx.json"
    path.write_bytes(json.dumps(valid_doc()).replace("test", "caf\u00e9").encode("latin-1"))
    with pytest.raises(InputError) as info:
        load_prescription(path)
    assert "UTF-8" in str(info.value)


@pytest.mark.parametrize("text,words", [
    ("[1, 2]", "array"), ('"hello"', "string"), ("3", "number"), ("null", "null"),
])
def test_top_level_not_object_in_file(tmp_path, text, words):
    path = write(tmp_path, "// comment\n" + text)
    with pytest.raises(InputError) as info:
        load_prescription(path)
    assert words in str(info.value)
    assert "object" in str(info.value)
    with pytest.raises(InputError):
        validate_file(path)


def test_empty_file(tmp_path):
    with pytest.raises(InputError) as info:
        load_prescription(write(tmp_path, "// only a comment\n\n"))
    assert "empty" in str(info.value) or "line" in str(info.value)


def test_duplicate_key_rejected(tmp_path):
    text = json.dumps(valid_doc()).replace('"sphere_D": -2.5', '"sphere_D": -2.5, "sphere_D": -5')
    with pytest.raises(InputError) as info:
        load_prescription(write(tmp_path, text))
    assert "sphere_D" in str(info.value)


def test_validate_file_lists_problems(tmp_path):
    doc = valid_doc()
    doc["schema"] = "other"
    doc["left"]["sphere_D"] = 99
    assert fields_of(validate_file(write(tmp_path, json.dumps(doc)))) == ["schema", "left.sphere_D"]


# ---------------------------------------------------------------------------
# Canonical JSON
# ---------------------------------------------------------------------------

finite = dict(allow_nan=False, allow_infinity=False)
eyes_strategy = st.builds(
    lambda S, C, a, p, acc, ho: EyeRx(S, C, a, p, acc, ho),
    st.floats(-20, 20, **finite), st.floats(-10, 10, **finite), st.floats(0, 180, **finite),
    st.floats(1, 6, **finite), st.floats(0, 15, **finite),
    st.one_of(st.none(), st.builds(
        HigherOrder, st.floats(6, 9, **finite),
        st.dictionaries(st.integers(6, 65), st.floats(-10, 10, **finite), max_size=8))),
)


@settings(max_examples=50)
@given(eyes_strategy, eyes_strategy, st.text(max_size=40))
def test_to_json_text_loads_back_equal(tmp_path_factory, right, left, notes):
    rx = Prescription(right=right, left=left, notes=notes)
    text = to_json_text(rx)
    assert parse_prescription(json.loads(text)) == rx
    path = tmp_path_factory.mktemp("rx") / "rx.json"
    path.write_text(text, encoding="utf-8")
    assert load_prescription(path) == rx


def test_to_json_text_shape():
    rx = parse_prescription(valid_doc())
    doc = json.loads(to_json_text(rx))
    assert list(doc) == ["schema", "notes", "right", "left"]
    assert doc["schema"] == SCHEMA
    assert doc["right"]["higher_order"]["coefficients_um"] == {"7": 0.1, "12": -0.05}
    assert "higher_order" not in doc["left"]


# ---------------------------------------------------------------------------
# Accommodation from age (Hofstetter 1950, mean amplitude 18.5 - 0.3 x age)
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("age, amplitude", [(40, 6.5), (50, 3.5), (25, 11.0), (60, 0.5),
                                            (10, 15.0),      # 15.5 held at the field's 15 D
                                            (90, 0.0), (1, 15.0), (120, 0.0), (61.6, 0.02)])
def test_an_eye_without_accommodation_gets_hofstetters_mean_for_the_files_age(age, amplitude):
    doc = set_path(set_path(valid_doc(), "right.accommodation_D", MISSING), "age_years", age)
    rx = parse_prescription(doc)
    assert rx.right.accommodation_D == pytest.approx(amplitude, abs=1e-9)     # by hand from the formula
    assert rx.left.accommodation_D == pytest.approx(amplitude, abs=1e-9)      # the left eye never gave one
    assert rx.accommodation_from_age == ("right", "left")


def test_a_stated_accommodation_and_a_file_without_age_keep_their_amplitude():
    doc = set_path(set_path(valid_doc(), "right.accommodation_D", 2.0), "age_years", 30)
    rx = parse_prescription(doc)
    assert rx.right.accommodation_D == 2.0 and rx.left.accommodation_D == pytest.approx(9.5)
    assert rx.accommodation_from_age == ("left",)
    stated_zero = parse_prescription(set_path(valid_doc(), "age_years", 30))      # right states 0: a presbyope
    assert stated_zero.right.accommodation_D == 0.0
    no_age = parse_prescription(valid_doc())
    assert no_age.left.accommodation_D == 0.0 and no_age.accommodation_from_age == ()


def test_an_amplitude_from_age_is_left_out_when_written_and_comes_back_from_the_age(tmp_path):
    rx = parse_prescription(set_path(valid_doc(), "age_years", 40))
    doc = json.loads(to_json_text(rx))
    assert "accommodation_D" not in doc["left"] and doc["right"]["accommodation_D"] == 0.0
    again = parse_prescription(doc)
    assert again == rx and again.accommodation_from_age == ("left",) and again.left.accommodation_D == 6.5
    older = parse_prescription({**doc, "age_years": 55})               # the age edited: the amplitude follows
    assert older.left.accommodation_D == pytest.approx(2.0)


def test_accommodation_from_age_refuses_what_is_not_an_age_and_unstated_eyes_that_are_not_eyes():
    from vrcorrect.specs.prescription import accommodation_from_age

    for bad in (float("nan"), "40", True, None):
        with pytest.raises(ValidationError, match="age_years"):
            accommodation_from_age(bad)
    with pytest.raises(ValidationErrors, match="accommodation_unstated"):
        Prescription(right=eye(), left=eye(), age_years=30, accommodation_unstated=("both",))
    with pytest.raises(ValidationErrors, match="accommodation_unstated"):
        Prescription(right=eye(), left=eye(), accommodation_unstated="right")      # a string, not a tuple of eyes
    # without an age an unstated eye's amplitude is 0, and none is said to come from an age
    assert Prescription(right=eye(), left=eye(), accommodation_unstated=("right",)).accommodation_from_age == ()


def test_with_age_gives_unstated_eyes_the_ages_amplitude_and_keeps_stated_ones():
    no_age = parse_prescription(valid_doc())             # the right eye states 0, the left none; no age
    assert no_age.accommodation_unstated == ("left",) and no_age.left.accommodation_D == 0.0
    aged = no_age.with_age(40)
    assert aged.age_years == 40 and aged.left.accommodation_D == pytest.approx(6.5)      # 18.5 - 0.3 x 40
    assert aged.right.accommodation_D == 0.0                                             # stated: a presbyope's
    assert aged.accommodation_from_age == ("left",)
    assert aged.left.sphere_D == no_age.left.sphere_D and aged.notes == no_age.notes
    assert aged.with_age(90).left.accommodation_D == 0.0                                  # follows a later age
    written = json.loads(to_json_text(aged))                                              # still unstated in a file
    assert "accommodation_D" not in written["left"] and written["age_years"] == 40
    for bad in (0, 121, float("nan"), "40"):
        with pytest.raises((ValidationError, ValidationErrors), match="age_years"):
            no_age.with_age(bad)


# ---------------------------------------------------------------------------
# Template and sample
# ---------------------------------------------------------------------------

def test_template_loads_back_valid(tmp_path):
    text = template_text()
    path = write(tmp_path, text)
    rx = load_prescription(path)
    assert isinstance(rx, Prescription)
    assert validate_file(path) == []
    comments = "\n".join(line for line in text.splitlines() if line.lstrip().startswith("//"))
    for word in ("sphere_D", "cylinder_D", "axis_deg", "pupil_diameter_mm", "accommodation_D",
                 "higher_order", "coefficients_um", "notes", "dioptres", "degrees",
                 "millimetres", "micrometres", "TABO", "ISO 8429", "minus-cylinder",
                 "plus-cylinder", "-20 to 20", "-10 to 10", "0 to 180", "1 to 9", "0 to 15",
                 "6 to 65"):
        assert word.lower() in comments.lower(), word


def test_write_template_refuses_to_overwrite(tmp_path):
    path = tmp_path / "rx.json"
    original = b"my precious prescription \x00\xff"
    path.write_bytes(original)
    with pytest.raises(InputError) as info:
        write_template(path)
    assert "--force" in str(info.value)
    assert path.read_bytes() == original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rx.json"]  # no temporary left behind
    write_template(path, force=True)
    assert path.read_text(encoding="utf-8") == template_text()
    assert isinstance(load_prescription(path), Prescription)


def test_write_template_new_file(tmp_path):
    path = tmp_path / "new.json"
    write_template(str(path))
    assert path.read_text(encoding="utf-8") == template_text()
    with pytest.raises(InputError):
        write_template(tmp_path / "no_such_folder" / "rx.json")


def test_bundled_sample_loads():
    path = bundled_sample_path()
    assert path.is_file()
    assert path.name == "sample_rx.json"
    rx = load_prescription(path)
    assert (rx.right.sphere_D, rx.right.cylinder_D, rx.right.axis_deg) == (-3.0, -1.5, 20.0)
    assert (rx.left.sphere_D, rx.left.cylinder_D, rx.left.axis_deg) == (-2.5, -0.75, 160.0)
    for name in Eye:
        e = rx.eye(name)
        assert e.pupil_diameter_mm == 4.0
        assert e.accommodation_D == 0.0
        assert e.higher_order is None
    assert rx.notes
    # mirror-symmetric astigmatism axes: J45 has opposite signs
    assert rx.right.power_vector().J45_D > 0 > rx.left.power_vector().J45_D


# ---------------------------------------------------------------- a spectacle prescription's line (rx new --right)

@pytest.mark.parametrize("text, eye", [
    ("-2.00 -1.00 x 120", (-2.0, -1.0, 120.0)),
    ("-2.00/-1.00x120", (-2.0, -1.0, 120.0)),
    ("+1.25 -0.50 × 180", (1.25, -0.5, 180.0)),
    ("−2.00 −1.00 x 120", (-2.0, -1.0, 120.0)),             # typeset minus signs, as copied from a document
    ("-2.00D -1.00DC x 120", (-2.0, -1.0, 120.0)),
    ("-2.00 -1.00 @ 120", (-2.0, -1.0, 120.0)),
    ("-2.00 +1.00 axis 30", (-2.0, 1.0, 30.0)),              # plus-cylinder form, kept as written
    ("plano -0.75 x 90", (0.0, -0.75, 90.0)),
    ("-1.50", (-1.5, 0.0, 0.0)),
    ("-1.50 DS", (-1.5, 0.0, 0.0)),
    ("+0.75 sph", (0.75, 0.0, 0.0)),
    ("PL", (0.0, 0.0, 0.0)),
    ("0", (0.0, 0.0, 0.0)),
])
def test_a_spectacle_prescription_line_reads_as_sphere_cylinder_axis(text, eye):
    from vrcorrect.specs.prescription.notation import parse_spectacle_rx

    assert parse_spectacle_rx(text, "--right") == eye


@pytest.mark.parametrize("lens, vertex, eye", [
    ((-6.0, 0.0, 0.0), 12.0, (-5.597, 0.0, 0.0)),             # -6 / 1.072, by hand
    ((6.0, 0.0, 0.0), 12.0, (6.466, 0.0, 0.0)),               # 6 / 0.928
    ((-2.0, -1.0, 120.0), 12.0, (-1.953, -0.943, 120.0)),     # meridians -2 / 1.024 and -3 / 1.036
    ((-4.0, 2.0, 45.0), 14.0, (-3.788, 1.842, 45.0)),         # plus-cylinder form: -4 / 1.056, -2 / 1.028 = -1.946
    ((-2.0, -1.0, 120.0), 0.0, (-2.0, -1.0, 120.0)),          # 0: the powers are at the eye already
    ((-20.0, 0.0, 0.0), 25.0, (-13.333, 0.0, 0.0)),           # the extremes: -20 / 1.5
    ((20.0, 0.0, 0.0), 25.0, (40.0, 0.0, 0.0)),               # 20 / 0.5 (then refused by the eye's range)
    ((40.0, 0.0, 0.0), 25.0, (40.0, 0.0, 0.0)),               # 1 - d F = 0: left as written, no division
    ((45.0, -10.0, 90.0), 25.0, (45.0, -10.0, 90.0)),         # 1 - d F < 0.25 for both: as written
])
def test_a_spectacle_line_moves_to_the_eye_meridian_by_meridian(lens, vertex, eye):
    from vrcorrect.specs.prescription.notation import at_eye

    assert at_eye(*lens, vertex) == pytest.approx(eye, abs=5e-4)


@pytest.mark.parametrize("vertex", [-1.0, 25.5, float("nan"), float("inf"), True, "12"])
def test_a_vertex_distance_out_of_range_is_refused_naming_the_option(vertex):
    from vrcorrect.specs.prescription.notation import at_eye

    with pytest.raises(ValidationError) as err:
        at_eye(-6.0, 0.0, 0.0, vertex)
    assert err.value.field == "--vertex" and "0 to 25 mm" in str(err.value)


@pytest.mark.parametrize("text, field, says", [
    ("-2.00 -1.00", "--right", "axis"),                       # a cylinder without its axis
    ("-2.00 x 120", "--right", "SPHERE CYLINDER x AXIS"),
    ("-2.00 -1.00 x 181", "--right axis", "0 to 180"),
    ("", "--right", "SPHERE"),
    ("-2.00 -1.00 x 120 x 3", "--right", "SPHERE"),
])
def test_a_line_that_is_not_a_prescription_is_refused_naming_the_forms(text, field, says):
    from vrcorrect.specs.prescription.notation import parse_spectacle_rx

    with pytest.raises(ValidationError) as err:
        parse_spectacle_rx(text, "--right")
    assert err.value.field == field and says in str(err.value)


@pytest.mark.parametrize("text, line, add", [
    ("-2.00 -1.00 x 120 ADD +2.00", "-2.00 -1.00 x 120", 2.0),
    ("-2.00 -1.00 x 120, add 2.25", "-2.00 -1.00 x 120", 2.25),
    ("+1.00 DS Add: +2.50D", "+1.00 DS", 2.5),
    ("-2.00 -1.00 x 120", "-2.00 -1.00 x 120", None),
])
def test_a_reading_addition_is_split_off_the_distance_prescription(text, line, add):
    from vrcorrect.specs.prescription.notation import parse_spectacle_rx, split_add

    got_line, got_add = split_add(text)
    assert got_add == add and got_line.strip() == line
    assert parse_spectacle_rx(got_line, "--right") == parse_spectacle_rx(line, "--right")


def test_an_accommodative_lag_is_read_written_back_and_refused_out_of_its_range(tmp_path):
    rx = parse_prescription(set_path(valid_doc(), "right.accommodative_lag_D", 0.5))
    assert rx.right.accommodative_lag_D == 0.5 and rx.left.accommodative_lag_D == 0.0       # left out: 0
    doc = json.loads(to_json_text(rx))
    assert doc["right"]["accommodative_lag_D"] == 0.5 and "accommodative_lag_D" not in doc["left"]
    assert parse_prescription(doc) == rx
    for bad in (-0.25, 2.5, float("nan"), "0.5", True):
        problems = problems_in(set_path(valid_doc(), "left.accommodative_lag_D", bad))
        assert [p.field for p in problems] == ["left.accommodative_lag_D"]
        assert "0 to 2" in problems[0].allowed and "MEM" in problems[0].allowed
    for edge in (0.0, 2.0):
        assert parse_prescription(set_path(valid_doc(), "left.accommodative_lag_D", edge)).left.accommodative_lag_D == edge
    with pytest.raises(ValidationErrors, match="accommodative_lag_D"):
        eye().with_changes(accommodative_lag_D=3.0)


def test_the_template_explains_the_lag_and_writes_it_when_given():
    assert "accommodative_lag_D" in template_text() and "MEM retinoscopy" in template_text()
    body = "\n".join(line for line in template_text().splitlines() if not line.lstrip().startswith("//"))
    assert "accommodative_lag_D" not in body                       # explained, but not in the file's values
    filled = parse_prescription(json.loads("\n".join(
        line for line in template_text(right=(-1.0, 0.0, 0.0), lag_D=0.75).splitlines() if not line.lstrip().startswith("//"))))
    assert filled.right.accommodative_lag_D == 0.75 and filled.left.accommodative_lag_D == 0.75
