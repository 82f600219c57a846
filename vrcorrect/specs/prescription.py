"""Spectacle prescriptions: the per-eye refractive error, loaded and validated.

A prescription file is JSON (full-line ``//`` comments allowed) with a schema
version and one object per eye::

    {
      "schema": "vrcorrect.prescription/1",
      "notes": "optional free text",
      "right": {"sphere_D": -2.5, "cylinder_D": -1.0, "axis_deg": 20,
                "pupil_diameter_mm": 4.0,
                "accommodation_D": 0.0,
                "higher_order": {"pupil_diameter_mm": 6.0,
                                 "coefficients_um": {"7": 0.10, "12": -0.05}}},
      "left": {...}
    }

Conventions (see ``DESIGN.md``):

- sphere S and cylinder C in dioptres (D), cylinder axis α in degrees, 0-180,
  TABO / ISO 8429 notation. Minus- and plus-cylinder forms describe the same
  eye and are both accepted.
- Power vector (Thibos, Wheeler & Horner 1997):
  M = S + C/2, J0 = -(C/2)·cos 2α, J45 = -(C/2)·sin 2α.
- Higher-order Zernike coefficients are in micrometres, OSA/ANSI single index
  j (6..65, radial orders 3..10), for the stated pupil diameter. Terms j <= 5
  (piston, tilt, defocus, astigmatism) come from S, C and α.

Validation collects every problem in a document before raising
:class:`~vrcorrect.plumbing.errors.ValidationErrors`; file problems (missing,
unreadable, not UTF-8, not JSON) raise :class:`~vrcorrect.plumbing.errors.InputError`.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import re
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ..plumbing.errors import InputError, Problem, ValidationError, ValidationErrors, json_error_location
from ..plumbing.fileio import package_data, write_text_atomic

__all__ = [
    "SCHEMA",
    "EYES",
    "MISSING",
    "PowerVector",
    "HigherOrder",
    "EyeRx",
    "Prescription",
    "parse_prescription",
    "problems_in",
    "load_prescription",
    "validate_file",
    "to_json_text",
    "template_text",
    "write_template",
    "bundled_sample_path",
]

SCHEMA = "vrcorrect.prescription/1"
EYES = ("right", "left")

#: Range of the OSA/ANSI single index accepted for higher-order terms
#: (j = 6 is Z(3,-3); j = 65 is Z(10,10)).
J_MIN = 6
J_MAX = 65


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


#: The ``value`` of a :class:`Problem` reporting a required field that is absent.
MISSING: Any = _Missing()


# --------------------------------------------------------------------------
# Field rules (one table used by files and by programmatic construction)
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class _Range:
    lo: float
    hi: float
    allowed: str


_SPHERE = _Range(-20.0, 20.0, "a finite number from -20 to 20 (dioptres)")
_CYLINDER = _Range(-10.0, 10.0, "a finite number from -10 to 10 (dioptres; minus- or plus-cylinder form)")
_AXIS = _Range(0.0, 180.0, "a finite number from 0 to 180 (degrees, TABO / ISO 8429)")
_PUPIL = _Range(1.0, 9.0, "a finite number from 1 to 9 (millimetres)")
_ACCOMMODATION = _Range(0.0, 15.0, "a finite number from 0 to 15 (dioptres of accommodation amplitude)")
_HO_PUPIL = _Range(1.0, 9.0, "a finite number from 1 to 9 (millimetres; the pupil the coefficients were measured at)")
_COEFFICIENT = _Range(-10.0, 10.0, "a finite number from -10 to 10 (micrometres)")

_J_ALLOWED = (
    f"an integer OSA/ANSI single index j from {J_MIN} to {J_MAX} (radial orders 3 to 10), "
    "written as a string key such as \"7\"; j 0-5 (piston, tilt, defocus, astigmatism) "
    "come from sphere_D, cylinder_D and axis_deg and must not be given here"
)

# Eye fields: name -> (rule, required)
_EYE_FIELDS: dict[str, tuple[_Range, bool]] = {
    "sphere_D": (_SPHERE, True),
    "cylinder_D": (_CYLINDER, True),
    "axis_deg": (_AXIS, True),
    "pupil_diameter_mm": (_PUPIL, True),
    "accommodation_D": (_ACCOMMODATION, False),
}
_EYE_KEYS = tuple(_EYE_FIELDS) + ("higher_order",)
_HO_KEYS = ("pupil_diameter_mm", "coefficients_um")
_TOP_KEYS = ("schema", "notes") + EYES

_EYE_ALLOWED = (
    "an object with sphere_D, cylinder_D, axis_deg, pupil_diameter_mm "
    "and optionally accommodation_D and higher_order"
)
_HO_ALLOWED = (
    "an object with pupil_diameter_mm and coefficients_um "
    "(leave higher_order out if there are no higher-order aberrations)"
)
_COEFFS_ALLOWED = (
    "an object mapping OSA/ANSI index j (a string key, 6 to 65) to a coefficient in micrometres"
)


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def _is_number(value: Any) -> bool:
    """True for int/float (and numpy scalars of those kinds), never for bool."""
    if isinstance(value, (bool, np.bool_)):
        return False
    return isinstance(value, (int, float, np.integer, np.floating))


def _check_number(problems: list[Problem], field: str, value: Any, rule: _Range) -> float | None:
    """Validate one finite number in ``[rule.lo, rule.hi]``.

    Appends a :class:`Problem` and returns ``None`` when the value is bad;
    returns the value as a float otherwise.
    """
    if not _is_number(value):
        problems.append(Problem(field, value, rule.allowed))
        return None
    if isinstance(value, (int, np.integer)):
        # Compare before converting: a huge JSON integer would overflow float().
        if not (rule.lo <= int(value) <= rule.hi):
            problems.append(Problem(field, value, rule.allowed))
            return None
        return float(value)
    number = float(value)
    if not math.isfinite(number) or not (rule.lo <= number <= rule.hi):
        problems.append(Problem(field, value, rule.allowed))
        return None
    return number


def _unknown_key_problem(field: str, key: Any, value: Any, known: Iterable[str]) -> Problem:
    known = tuple(known)
    hint = ""
    if isinstance(key, str):
        close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
        if not close:
            lowered = {k.lower(): k for k in known}
            if key.lower() in lowered:
                close = [lowered[key.lower()]]
        if close:
            hint = f" (did you mean {close[0]!r}?)"
    return Problem(field, value, f"no such field{hint}; known fields here: {', '.join(known)}")


def _parse_j(key: Any) -> int | None:
    """OSA/ANSI index from a coefficient key: a canonical decimal string or an int."""
    if isinstance(key, (bool, np.bool_)):
        return None
    if isinstance(key, (int, np.integer)):
        return int(key)
    if isinstance(key, str) and re.fullmatch(r"0|[1-9][0-9]{0,5}", key):
        return int(key)
    return None


def _check_j(problems: list[Problem], field: str, key: Any) -> int | None:
    j = _parse_j(key)
    if j is None or not (J_MIN <= j <= J_MAX):
        problems.append(Problem(field, key, _J_ALLOWED))
        return None
    return j


def _pupil_vs_measured_allowed(ho_pupil_mm: float) -> str:
    return (
        f"at most {ho_pupil_mm:g} mm, the higher_order.pupil_diameter_mm the "
        "coefficients were measured at (a wavefront cannot be extrapolated beyond "
        "the measured pupil)"
    )


# --------------------------------------------------------------------------
# Data classes
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class PowerVector:
    """Refractive error as a power vector (Thibos, Wheeler & Horner 1997).

    Parameters
    ----------
    M_D
        Spherical equivalent M = S + C/2, dioptres.
    J0_D
        Jackson cross-cylinder at axis 0°/90°, J0 = -(C/2)·cos 2α, dioptres.
    J45_D
        Jackson cross-cylinder at axis 45°/135°, J45 = -(C/2)·sin 2α, dioptres.
    """

    M_D: float
    J0_D: float
    J45_D: float


def _check_ho_fields(pupil_diameter_mm: Any, coefficients: Any, prefix: str,
                     problems: list[Problem]) -> tuple[float | None, tuple[tuple[int, float], ...] | None]:
    """Validate programmatic HigherOrder fields (coefficients: mapping or pairs)."""
    pupil = _check_number(problems, _join(prefix, "pupil_diameter_mm"), pupil_diameter_mm, _HO_PUPIL)
    cfield = _join(prefix, "coefficients_um")
    if isinstance(coefficients, Mapping):
        pairs: list[Any] = list(coefficients.items())
    elif isinstance(coefficients, (str, bytes)) or not isinstance(coefficients, Iterable):
        problems.append(Problem(cfield, coefficients, _COEFFS_ALLOWED + " (or a sequence of (j, coefficient) pairs)"))
        return pupil, None
    else:
        pairs = list(coefficients)
    out: dict[int, float] = {}
    ok = True
    for pair in pairs:
        if not (isinstance(pair, tuple) or isinstance(pair, list)) or len(pair) != 2:
            problems.append(Problem(cfield, pair, "(j, coefficient_um) pairs"))
            ok = False
            continue
        key, value = pair
        j = _check_j(problems, _join(cfield, str(key)), key)
        c = _check_number(problems, _join(cfield, str(key)), value, _COEFFICIENT)
        if j is None or c is None:
            ok = False
            continue
        if j in out:
            problems.append(Problem(_join(cfield, str(j)), value, "each index j given once"))
            ok = False
            continue
        out[j] = c
    return pupil, (tuple(sorted(out.items())) if ok else None)


@dataclass(frozen=True)
class HigherOrder:
    """Higher-order aberrations measured by an aberrometer.

    Parameters
    ----------
    pupil_diameter_mm
        Pupil diameter the coefficients refer to, millimetres, 1 to 9.
    coefficients_um
        ``(j, c)`` pairs sorted by j: OSA/ANSI single index j (6 to 65, radial
        orders 3 to 10) and the Zernike coefficient c in micrometres (RMS
        normalised, -10 to 10). A mapping ``{j: c}`` is also accepted and is
        stored as sorted pairs.

    Raises
    ------
    ValidationErrors
        Listing every bad field.
    """

    pupil_diameter_mm: float
    coefficients_um: tuple[tuple[int, float], ...] = ()

    def __post_init__(self) -> None:
        problems: list[Problem] = []
        pupil, coeffs = _check_ho_fields(self.pupil_diameter_mm, self.coefficients_um, "", problems)
        if problems:
            raise ValidationErrors(problems)
        object.__setattr__(self, "pupil_diameter_mm", pupil)
        object.__setattr__(self, "coefficients_um", coeffs)

    def as_dict(self) -> dict[int, float]:
        """Coefficients as ``{j: c_um}``."""
        return dict(self.coefficients_um)


def _cos_sin_deg(angle_deg: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact at multiples of 90°."""
    reduced = math.fmod(angle_deg, 360.0)
    if reduced < 0.0:
        reduced += 360.0
    exact = {0.0: (1.0, 0.0), 90.0: (0.0, 1.0), 180.0: (-1.0, 0.0), 270.0: (0.0, -1.0), 360.0: (1.0, 0.0)}
    if reduced in exact:
        return exact[reduced]
    radians = math.radians(reduced)
    return math.cos(radians), math.sin(radians)


def _snap_to_limits(value: float, rule: _Range, tolerance: float = 1e-9) -> float:
    """``value`` moved onto the nearer limit of ``rule`` if it is outside by at most ``tolerance``."""
    if rule.hi < value <= rule.hi + tolerance:
        return rule.hi
    if rule.lo - tolerance <= value < rule.lo:
        return rule.lo
    return value


def _axis_in_range(axis_deg: float) -> float:
    """Map an axis in degrees to [0, 180)."""
    axis = math.fmod(axis_deg, 180.0)
    if axis < 0.0:
        axis += 180.0
    if axis >= 180.0:  # fmod of a tiny negative number plus 180 rounds to 180
        axis -= 180.0
    return axis + 0.0  # no -0.0


@dataclass(frozen=True)
class EyeRx:
    """One eye's refraction.

    Parameters
    ----------
    sphere_D
        Sphere S, dioptres, -20 to 20 (negative: myopia).
    cylinder_D
        Cylinder C, dioptres, -10 to 10, minus- or plus-cylinder form.
    axis_deg
        Cylinder axis α, degrees, 0 to 180 inclusive (TABO / ISO 8429;
        0 and 180 are the same meridian).
    pupil_diameter_mm
        Pupil diameter while viewing the display, millimetres, 1 to 9.
    accommodation_D
        Accommodation amplitude, dioptres, 0 to 15 (default 0: none).
    higher_order
        Optional higher-order aberrations; their measured pupil must be at
        least ``pupil_diameter_mm``.

    Raises
    ------
    ValidationErrors
        Listing every bad field (field names without an eye prefix).
    """

    sphere_D: float
    cylinder_D: float
    axis_deg: float
    pupil_diameter_mm: float
    accommodation_D: float = 0.0
    higher_order: HigherOrder | None = None

    def __post_init__(self) -> None:
        problems: list[Problem] = []
        values: dict[str, float] = {}
        for name, (rule, _required) in _EYE_FIELDS.items():
            number = _check_number(problems, name, getattr(self, name), rule)
            if number is not None:
                values[name] = number
        ho = self.higher_order
        if ho is not None and not isinstance(ho, HigherOrder):
            problems.append(Problem("higher_order", ho, "a HigherOrder or None"))
        elif ho is not None and "pupil_diameter_mm" in values and values["pupil_diameter_mm"] > ho.pupil_diameter_mm:
            problems.append(Problem("pupil_diameter_mm", self.pupil_diameter_mm,
                                    _pupil_vs_measured_allowed(ho.pupil_diameter_mm)))
        if problems:
            raise ValidationErrors(problems)
        for name, number in values.items():
            object.__setattr__(self, name, number + 0.0)

    # -- optics ------------------------------------------------------------

    def power_vector(self) -> PowerVector:
        """Power vector (M, J0, J45) in dioptres.

        M = S + C/2, J0 = -(C/2)·cos 2α, J45 = -(C/2)·sin 2α with α in degrees
        (Thibos et al. 1997). Identical for the plus- and minus-cylinder forms.
        """
        half_c = self.cylinder_D / 2.0
        cos2a, sin2a = _cos_sin_deg(2.0 * self.axis_deg)
        return PowerVector(
            M_D=self.sphere_D + half_c,
            J0_D=-half_c * cos2a + 0.0,
            J45_D=-half_c * sin2a + 0.0,
        )

    def transposed(self) -> "EyeRx":
        """The same eye written in the other cylinder form.

        S' = S + C, C' = -C, α' = α + 90° taken into [0, 180).

        Raises
        ------
        ValidationErrors
            If S + C lies outside -20 to 20 D (the other form's sphere is out
            of range; only possible when |S| + |C| > 20 D).
        """
        return dataclasses.replace(
            self,
            sphere_D=self.sphere_D + self.cylinder_D,
            cylinder_D=-self.cylinder_D + 0.0,
            axis_deg=_axis_in_range(self.axis_deg + 90.0),
        )

    def minus_cylinder(self) -> "EyeRx":
        """The same eye in minus-cylinder form (C <= 0), axis in [0, 180).

        Raises
        ------
        ValidationErrors
            If the eye is in plus-cylinder form and S + C lies outside
            -20 to 20 D.
        """
        if self.cylinder_D > 0.0:
            return self.transposed()
        return dataclasses.replace(self, axis_deg=_axis_in_range(self.axis_deg))

    def with_changes(self, **changes: Any) -> "EyeRx":
        """A copy with some fields replaced, validated again.

        Raises
        ------
        ValidationErrors
            If a value is out of range or a name is not a field of EyeRx.
        """
        names = [f.name for f in dataclasses.fields(self)]
        unknown = [k for k in changes if k not in names]
        if unknown:
            raise ValidationErrors(_unknown_key_problem(k, k, changes[k], names) for k in unknown)
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_power_vector(cls, pv: PowerVector, pupil_diameter_mm: float, **kw: Any) -> "EyeRx":
        """Eye with the given power vector, in minus-cylinder form.

        C = -2·sqrt(J0² + J45²), S = M - C/2, α = ½·atan2(J45, J0) in degrees,
        taken into [0, 180) (α = 0 when there is no cylinder).

        Parameters
        ----------
        pv
            Power vector, dioptres.
        pupil_diameter_mm
            Pupil diameter, millimetres, 1 to 9.
        **kw
            ``accommodation_D`` and ``higher_order``.

        Raises
        ------
        ValidationErrors
            If the resulting sphere/cylinder or any other field is out of range.
        """
        if not isinstance(pv, PowerVector):
            raise ValidationError("pv", pv, "a PowerVector")
        problems: list[Problem] = []
        m = _check_number(problems, "M_D", pv.M_D, _Range(-math.inf, math.inf, "a finite number (dioptres)"))
        j0 = _check_number(problems, "J0_D", pv.J0_D, _Range(-math.inf, math.inf, "a finite number (dioptres)"))
        j45 = _check_number(problems, "J45_D", pv.J45_D, _Range(-math.inf, math.inf, "a finite number (dioptres)"))
        if problems:
            raise ValidationErrors(problems)
        assert m is not None and j0 is not None and j45 is not None
        radius = math.hypot(j0, j45)
        # Round-off (e.g. a -10 D cylinder coming back as -10.000000000000002)
        # must not make a limit case invalid: snap values within 1e-9 D of a limit.
        cylinder = _snap_to_limits(-2.0 * radius + 0.0, _CYLINDER)
        sphere = _snap_to_limits(m - cylinder / 2.0, _SPHERE)
        axis = _axis_in_range(0.5 * math.degrees(math.atan2(j45, j0))) if radius > 0.0 else 0.0
        return cls(sphere_D=sphere, cylinder_D=cylinder, axis_deg=axis,
                   pupil_diameter_mm=pupil_diameter_mm, **kw)


@dataclass(frozen=True)
class Prescription:
    """Both eyes' refraction.

    Parameters
    ----------
    right, left
        Each eye's :class:`EyeRx`.
    notes
        Free text.
    """

    right: EyeRx
    left: EyeRx
    notes: str = ""

    def __post_init__(self) -> None:
        problems: list[Problem] = []
        for name in EYES:
            if not isinstance(getattr(self, name), EyeRx):
                problems.append(Problem(name, getattr(self, name), "an EyeRx"))
        if not isinstance(self.notes, str):
            problems.append(Problem("notes", self.notes, "a string"))
        if problems:
            raise ValidationErrors(problems)

    def eye(self, name: str) -> EyeRx:
        """The eye called ``"right"`` or ``"left"``.

        Raises
        ------
        ValidationError
            For any other name.
        """
        if name not in EYES:
            raise ValidationError("eye", name, "'right' or 'left'")
        return getattr(self, name)


# --------------------------------------------------------------------------
# Documents (parsed JSON)
# --------------------------------------------------------------------------

def _eye_doc_problems(doc: Any, prefix: str, problems: list[Problem]) -> None:
    if doc is MISSING:
        problems.append(Problem(prefix, MISSING, _EYE_ALLOWED))
        return
    if not isinstance(doc, Mapping):
        problems.append(Problem(prefix, doc, _EYE_ALLOWED))
        return
    pupil: float | None = None
    for name, (rule, required) in _EYE_FIELDS.items():
        field = _join(prefix, name)
        if name not in doc:
            if required:
                problems.append(Problem(field, MISSING, rule.allowed))
            continue
        number = _check_number(problems, field, doc[name], rule)
        if name == "pupil_diameter_mm":
            pupil = number
    ho_pupil: float | None = None
    if "higher_order" in doc:
        ho_pupil = _ho_doc_problems(doc["higher_order"], _join(prefix, "higher_order"), problems)
    if pupil is not None and ho_pupil is not None and pupil > ho_pupil:
        problems.append(Problem(_join(prefix, "pupil_diameter_mm"), doc["pupil_diameter_mm"],
                                _pupil_vs_measured_allowed(ho_pupil)))
    for key in doc:
        if key not in _EYE_KEYS:
            problems.append(_unknown_key_problem(_join(prefix, str(key)), key, doc[key], _EYE_KEYS))


def _ho_doc_problems(doc: Any, prefix: str, problems: list[Problem]) -> float | None:
    """Check a higher_order object; return its pupil when that is valid."""
    if not isinstance(doc, Mapping):
        problems.append(Problem(prefix, doc, _HO_ALLOWED))
        return None
    pupil: float | None = None
    pfield = _join(prefix, "pupil_diameter_mm")
    if "pupil_diameter_mm" not in doc:
        problems.append(Problem(pfield, MISSING, _HO_PUPIL.allowed))
    else:
        pupil = _check_number(problems, pfield, doc["pupil_diameter_mm"], _HO_PUPIL)
    cfield = _join(prefix, "coefficients_um")
    if "coefficients_um" not in doc:
        problems.append(Problem(cfield, MISSING, _COEFFS_ALLOWED))
    elif not isinstance(doc["coefficients_um"], Mapping):
        problems.append(Problem(cfield, doc["coefficients_um"], _COEFFS_ALLOWED))
    else:
        seen: set[int] = set()
        for key, value in doc["coefficients_um"].items():
            field = _join(cfield, str(key))
            j = _check_j(problems, field, key)
            _check_number(problems, field, value, _COEFFICIENT)
            if j is not None:
                if j in seen:  # only possible for programmatic dicts mixing "7" and 7
                    problems.append(Problem(field, value, "each index j given once"))
                seen.add(j)
    for key in doc:
        if key not in _HO_KEYS:
            problems.append(_unknown_key_problem(_join(prefix, str(key)), key, doc[key], _HO_KEYS))
    return pupil


def problems_in(doc: object) -> list[Problem]:
    """Every problem in a parsed prescription document, in document order.

    Parameters
    ----------
    doc
        The parsed JSON (normally a dict).

    Returns
    -------
    list of Problem
        Empty when the document is a valid prescription. Field names are
        dotted paths such as ``"right.sphere_D"``; a missing field has the
        value :data:`MISSING`.
    """
    problems: list[Problem] = []
    if not isinstance(doc, Mapping):
        problems.append(Problem("(top level)", doc, "a JSON object with schema, right and left"))
        return problems
    schema = doc.get("schema", MISSING)
    if not isinstance(schema, str) or schema != SCHEMA:
        problems.append(Problem("schema", schema, f"the string {SCHEMA!r}"))
    if "notes" in doc and not isinstance(doc["notes"], str):
        problems.append(Problem("notes", doc["notes"], "a string (free text)"))
    for name in EYES:
        _eye_doc_problems(doc.get(name, MISSING), name, problems)
    for key in doc:
        if key not in _TOP_KEYS:
            problems.append(_unknown_key_problem(str(key), key, doc[key], _TOP_KEYS))
    return problems


def _eye_from_doc(doc: Mapping[str, Any]) -> EyeRx:
    ho = None
    if "higher_order" in doc:
        h = doc["higher_order"]
        ho = HigherOrder(
            pupil_diameter_mm=h["pupil_diameter_mm"],
            coefficients_um=tuple((_parse_j(k), v) for k, v in h["coefficients_um"].items()),
        )
    return EyeRx(
        sphere_D=doc["sphere_D"],
        cylinder_D=doc["cylinder_D"],
        axis_deg=doc["axis_deg"],
        pupil_diameter_mm=doc["pupil_diameter_mm"],
        accommodation_D=doc.get("accommodation_D", 0.0),
        higher_order=ho,
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
        return Prescription(
            right=_eye_from_doc(doc["right"]),
            left=_eye_from_doc(doc["left"]),
            notes=doc.get("notes", ""),
        )
    except ValidationErrors as exc:  # pragma: no cover - problems_in is stricter
        raise ValidationErrors(exc.problems, source) from None


# --------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------

_COMMENT_LINE = re.compile(r"^[ \t]*//[^\n]*", re.MULTILINE)


def _strip_comments(text: str) -> str:
    """Blank full-line ``//`` comments, keeping line numbers unchanged.

    JSON strings cannot span lines, so a line starting with ``//`` is never
    inside a string.
    """
    return _COMMENT_LINE.sub("", text)


class _DuplicateKey(ValueError):
    pass


def _object_no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """JSON object hook: a repeated key is an error, not a silent overwrite."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def _read_document(path: str | PathLike[str]) -> tuple[Path, Any]:
    """Read, decode and parse a prescription file; InputError on any file problem."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: prescription file not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a prescription JSON file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read prescription file ({exc.strerror or exc})") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
            "save the prescription as UTF-8 JSON"
        ) from None
    if not text.strip():
        raise InputError(f"{path}: file is empty; expected a prescription JSON object")
    try:
        doc = json.loads(_strip_comments(text), object_pairs_hook=_object_no_duplicates)
    except json.JSONDecodeError as exc:
        line = exc.doc.splitlines()[exc.lineno - 1] if exc.lineno - 1 < len(exc.doc.splitlines()) else ""
        hint = " (only whole-line // comments are allowed)" if "//" in line else ""
        raise InputError(
            f"{path}: invalid JSON at {json_error_location(exc)}{hint}"
        ) from None
    except _DuplicateKey as exc:
        raise InputError(f"{path}: key {exc.args[0]!r} appears twice in one JSON object") from None
    except (ValueError, RecursionError) as exc:  # e.g. integer too long, nesting too deep
        raise InputError(f"{path}: cannot parse JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise InputError(
            f"{path}: top level is a JSON {_json_kind(doc)}, expected an object with schema, right and left"
        )
    return path, doc


def _json_kind(value: Any) -> str:
    if isinstance(value, list):
        return "array"
    if isinstance(value, str):
        return "string"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    return "number"


def load_prescription(path: str | PathLike[str]) -> Prescription:
    """Load and validate a prescription file.

    Raises
    ------
    InputError
        If the file is missing, unreadable, not UTF-8, not JSON, or its top
        level is not an object.
    ValidationErrors
        Listing every problem in its content.
    """
    path, doc = _read_document(path)
    return parse_prescription(doc, source=str(path))


def validate_file(path: str | PathLike[str]) -> list[Problem]:
    """Problems in a prescription file's content; ``[]`` when it is valid.

    Raises
    ------
    InputError
        If the file cannot be read or parsed as a JSON object.
    """
    _, doc = _read_document(path)
    return problems_in(doc)


def _eye_to_dict(eye: EyeRx) -> dict[str, Any]:
    out: dict[str, Any] = {
        "sphere_D": eye.sphere_D,
        "cylinder_D": eye.cylinder_D,
        "axis_deg": eye.axis_deg,
        "pupil_diameter_mm": eye.pupil_diameter_mm,
        "accommodation_D": eye.accommodation_D,
    }
    if eye.higher_order is not None:
        out["higher_order"] = {
            "pupil_diameter_mm": eye.higher_order.pupil_diameter_mm,
            "coefficients_um": {str(j): c for j, c in eye.higher_order.coefficients_um},
        }
    return out


def to_json_text(rx: Prescription) -> str:
    """Canonical JSON text of a prescription (loads back equal).

    Keys in a fixed order, floats written exactly (shortest round-trip form),
    two-space indent, trailing newline.
    """
    doc = {"schema": SCHEMA, "notes": rx.notes, "right": _eye_to_dict(rx.right), "left": _eye_to_dict(rx.left)}
    return json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n"


_TEMPLATE = """\
// vrcorrect prescription file (schema vrcorrect.prescription/1).
//
// Lines whose first non-blank characters are // are comments. Everything else
// is standard JSON: double-quoted keys, no trailing commas, no comment after a
// value on the same line. Replace the numbers below with your own; all four
// numbers per eye are on a spectacle (not contact-lens) prescription.
//
// "right" is the right eye (OD), "left" the left eye (OS). Per eye:
//
//   sphere_D           sphere S in dioptres, -20 to 20. Negative (minus) for
//                      short sight (myopia), positive (plus) for long sight.
//   cylinder_D         cylinder C in dioptres, -10 to 10; 0 if there is no
//                      astigmatism. Minus-cylinder form (C < 0, as optometrists
//                      write it) and plus-cylinder form (C > 0, as many
//                      ophthalmologists write it) are both accepted and mean
//                      the same eye: S, -C, axis +/- 90 is the other form.
//   axis_deg           cylinder axis in degrees, 0 to 180 (TABO / ISO 8429:
//                      0 and 180 are both horizontal, 90 is vertical, angles
//                      counter-clockwise as seen by someone facing the wearer).
//                      Any value is fine when cylinder_D is 0.
//   pupil_diameter_mm  pupil diameter in millimetres while looking at the
//                      display, 1 to 9 (about 3-4 for a bright monitor, 5-6 in
//                      a dim headset).
//   accommodation_D    optional: how many dioptres the eye can still focus by
//                      itself (accommodation amplitude), 0 to 15; default 0,
//                      which assumes none (the safe choice for presbyopes).
//   higher_order       optional: higher-order aberrations from an aberrometer,
//                      for example
//                        "higher_order": {"pupil_diameter_mm": 6.0,
//                                         "coefficients_um": {"7": 0.10, "12": -0.05}}
//     pupil_diameter_mm  the pupil (1 to 9 mm) the coefficients were measured
//                        at; it must be at least the eye's pupil_diameter_mm,
//                        because a wavefront cannot be extrapolated beyond the
//                        measured pupil.
//     coefficients_um    Zernike coefficients in micrometres (-10 to 10), keyed
//                        by the OSA/ANSI single index j as a string, 6 to 65
//                        (radial orders 3 to 10). j 0-5 (piston, tilt, defocus,
//                        astigmatism) come from sphere, cylinder and axis and
//                        must not be given here.
//
// "notes" is optional free text.
{
  "schema": "vrcorrect.prescription/1",
  "notes": "Template: replace the numbers with your own prescription.",
  "right": {
    "sphere_D": 0.0,
    "cylinder_D": 0.0,
    "axis_deg": 0,
    "pupil_diameter_mm": 4.0,
    "accommodation_D": 0.0
  },
  "left": {
    "sphere_D": 0.0,
    "cylinder_D": 0.0,
    "axis_deg": 0,
    "pupil_diameter_mm": 4.0,
    "accommodation_D": 0.0
  }
}
"""


def template_text() -> str:
    """A commented prescription template that loads as a valid Prescription."""
    return _TEMPLATE


def write_template(path: str | PathLike[str], force: bool = False) -> None:
    """Write :func:`template_text` to ``path`` atomically.

    Raises
    ------
    InputError
        If ``path`` exists and ``force`` is false (the message names
        ``--force``), or the folder is missing or not writable.
    """
    write_text_atomic(Path(path), template_text(), force=force)


def bundled_sample_path() -> Path:
    """Path of the bundled sample prescription ``vrcorrect/data/sample_rx.json``."""
    return package_data("sample_rx.json")
