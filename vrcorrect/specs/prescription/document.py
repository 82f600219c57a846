"""Prescription documents (parsed JSON): every problem in one, found at once
(:func:`problems_in`), and the :class:`Prescription` it describes (:func:`parse_prescription`).

Field names in problems are dotted paths such as ``"right.sphere_D"``; a required field that is
absent has the value :data:`MISSING`.
"""

from __future__ import annotations

from typing import Any, Mapping

from ...plumbing.errors import FieldProblem, ValidationErrors
from ..validation import check_number, unknown_key_problem
from ..vocabulary import Eye, names
from .model import (
    AGE,
    COEFFICIENT,
    COEFFS_ALLOWED,
    EYE_FIELDS,
    HO_PUPIL,
    SCHEMA,
    EyeRx,
    HigherOrder,
    Prescription,
    accommodation_from_age,
    check_j,
    join_field,
    parse_j,
    pupil_vs_measured_allowed,
)

__all__ = ["MISSING", "problems_in", "parse_prescription"]


class _Missing:
    """Sentinel standing for a field that is not in the document."""

    _instance: "_Missing | None" = None

    def __new__(cls) -> "_Missing":
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "<missing>"

    def __reduce__(self) -> str:
        return "MISSING"


#: The ``value`` of a :class:`FieldProblem` reporting a required field that is absent.
MISSING: Any = _Missing()

_EYE_KEYS = tuple(EYE_FIELDS) + ("higher_order",)
_HO_KEYS = ("pupil_diameter_mm", "coefficients_um")
_TOP_KEYS = ("schema", "notes", "age_years") + names(Eye)

_EYE_ALLOWED = (
    "an object with sphere_D, cylinder_D, axis_deg, pupil_diameter_mm "
    "and optionally accommodation_D, accommodative_lag_D and higher_order"
)
_HO_ALLOWED = (
    "an object with pupil_diameter_mm and coefficients_um "
    "(leave higher_order out if there are no higher-order aberrations)"
)


def _eye_doc_problems(doc: Any, prefix: str, problems: list[FieldProblem]) -> None:
    if doc is MISSING:
        problems.append(FieldProblem(prefix, MISSING, _EYE_ALLOWED))
        return
    if not isinstance(doc, Mapping):
        problems.append(FieldProblem(prefix, doc, _EYE_ALLOWED))
        return
    pupil: float | None = None
    for name, (rule, required) in EYE_FIELDS.items():
        field = join_field(prefix, name)
        if name not in doc:
            if required:
                problems.append(FieldProblem(field, MISSING, rule.allowed))
            continue
        number = check_number(problems, field, doc[name], rule)
        if name == "pupil_diameter_mm":
            pupil = number
    ho_pupil: float | None = None
    if "higher_order" in doc:
        ho_pupil = _ho_doc_problems(doc["higher_order"], join_field(prefix, "higher_order"), problems)
    if pupil is not None and ho_pupil is not None and pupil > ho_pupil:
        problems.append(FieldProblem(join_field(prefix, "pupil_diameter_mm"), doc["pupil_diameter_mm"],
                                pupil_vs_measured_allowed(ho_pupil)))
    for key in doc:
        if key not in _EYE_KEYS:
            problems.append(unknown_key_problem(join_field(prefix, str(key)), key, doc[key], _EYE_KEYS))


def _ho_doc_problems(doc: Any, prefix: str, problems: list[FieldProblem]) -> float | None:
    """Check a higher_order object; return its pupil when that is valid."""
    if not isinstance(doc, Mapping):
        problems.append(FieldProblem(prefix, doc, _HO_ALLOWED))
        return None
    pupil: float | None = None
    pfield = join_field(prefix, "pupil_diameter_mm")
    if "pupil_diameter_mm" not in doc:
        problems.append(FieldProblem(pfield, MISSING, HO_PUPIL.allowed))
    else:
        pupil = check_number(problems, pfield, doc["pupil_diameter_mm"], HO_PUPIL)
    cfield = join_field(prefix, "coefficients_um")
    if "coefficients_um" not in doc:
        problems.append(FieldProblem(cfield, MISSING, COEFFS_ALLOWED))
    elif not isinstance(doc["coefficients_um"], Mapping):
        problems.append(FieldProblem(cfield, doc["coefficients_um"], COEFFS_ALLOWED))
    else:
        seen: set[int] = set()
        for key, value in doc["coefficients_um"].items():
            field = join_field(cfield, str(key))
            j = check_j(problems, field, key)
            check_number(problems, field, value, COEFFICIENT)
            if j is not None:
                if j in seen:  # only possible for programmatic dicts mixing "7" and 7
                    problems.append(FieldProblem(field, value, "each index j given once"))
                seen.add(j)
    for key in doc:
        if key not in _HO_KEYS:
            problems.append(unknown_key_problem(join_field(prefix, str(key)), key, doc[key], _HO_KEYS))
    return pupil


def problems_in(doc: object) -> list[FieldProblem]:
    """Every problem in a parsed prescription document, in document order.

    Parameters
    ----------
    doc
        The parsed JSON (normally a dict).

    Returns
    -------
    list of FieldProblem
        Empty when the document is a valid prescription. Field names are
        dotted paths such as ``"right.sphere_D"``; a missing field has the
        value :data:`MISSING`.
    """
    problems: list[FieldProblem] = []
    if not isinstance(doc, Mapping):
        problems.append(FieldProblem("(top level)", doc, "a JSON object with schema, right and left"))
        return problems
    schema = doc.get("schema", MISSING)
    if not isinstance(schema, str) or schema != SCHEMA:
        problems.append(FieldProblem("schema", schema, f"the string {SCHEMA!r}"))
    if "notes" in doc and not isinstance(doc["notes"], str):
        problems.append(FieldProblem("notes", doc["notes"], "a string (free text)"))
    if "age_years" in doc:
        check_number(problems, "age_years", doc["age_years"], AGE)
    for name in names(Eye):
        _eye_doc_problems(doc.get(name, MISSING), name, problems)
    for key in doc:
        if key not in _TOP_KEYS:
            problems.append(unknown_key_problem(str(key), key, doc[key], _TOP_KEYS))
    return problems


def _eye_from_doc(doc: Mapping[str, Any], age_years: float | None) -> EyeRx:
    """The eye of a checked eye document; without ``accommodation_D``, its amplitude from
    ``age_years`` (:func:`~.model.accommodation_from_age`) where the document gives the age, else 0."""
    ho = None
    if "higher_order" in doc:
        h = doc["higher_order"]
        ho = HigherOrder(
            pupil_diameter_mm=h["pupil_diameter_mm"],
            coefficients_um=tuple((parse_j(k), v) for k, v in h["coefficients_um"].items()),
        )
    return EyeRx(
        sphere_D=doc["sphere_D"],
        cylinder_D=doc["cylinder_D"],
        axis_deg=doc["axis_deg"],
        pupil_diameter_mm=doc["pupil_diameter_mm"],
        accommodation_D=doc["accommodation_D"] if "accommodation_D" in doc
        else (accommodation_from_age(age_years) if age_years is not None else 0.0),
        higher_order=ho,
        accommodative_lag_D=doc.get("accommodative_lag_D", 0.0),
    )


def parse_prescription(doc: object, source: str | None = None) -> Prescription:
    """Build a :class:`Prescription` from a parsed JSON document.

    Parameters
    ----------
    doc
        The parsed JSON.
    source
        Where it came from (file name), used in error messages.

    Raises
    ------
    ValidationErrors
        Listing every problem found (see :func:`problems_in`).
    """
    problems = problems_in(doc)
    if problems:
        raise ValidationErrors(problems, source)
    assert isinstance(doc, Mapping)
    try:
        age = doc.get("age_years")
        return Prescription(
            right=_eye_from_doc(doc["right"], age),
            left=_eye_from_doc(doc["left"], age),
            notes=doc.get("notes", ""),
            age_years=age,
            accommodation_unstated=tuple(e for e in names(Eye) if "accommodation_D" not in doc[e]),
        )
    except ValidationErrors as exc:  # pragma: no cover - problems_in is stricter
        raise ValidationErrors(exc.problems, source) from None
