"""Prescription files: reading one (JSON with whole-line ``//`` comments), writing one
(:func:`to_json_text`), the commented template, and the bundled sample.

File problems (missing, unreadable, not UTF-8, not JSON) raise
:class:`~vrcorrect.plumbing.errors.InputError`; problems in the content raise
:class:`~vrcorrect.plumbing.errors.ValidationErrors` listing every one.
"""

from __future__ import annotations

import json
import re
from os import PathLike
from pathlib import Path
from typing import Any

from ...plumbing.errors import FieldProblem, InputError, ValidationErrors, json_error_location
from ...plumbing.fileio import package_data, write_text_atomic
from ..validation import FileWording, read_utf8_text
from ..vocabulary import Eye, names
from .document import parse_prescription, problems_in
from .model import SCHEMA, EyeRx, Prescription

__all__ = [
    "load_prescription",
    "validate_file",
    "to_json_text",
    "template_text",
    "write_template",
    "bundled_sample_path",
]

#: How a prescription file's reading problems are told.
_PRESCRIPTION_FILE = FileWording(
    not_found="{path}: prescription file not found",
    is_directory="{path}: is a directory, expected a prescription JSON file",
    unreadable="{path}: cannot read prescription file ({reason})",
    not_utf8="{path}: not UTF-8 text (byte 0x{byte:02x} at offset {offset}); save the prescription as UTF-8 JSON",
)

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
    text = read_utf8_text(path, _PRESCRIPTION_FILE)
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


def validate_file(path: str | PathLike[str]) -> list[FieldProblem]:
    """Problems in a prescription file's content; ``[]`` when it is valid.

    Raises
    ------
    InputError
        If the file cannot be read or parsed as a JSON object.
    """
    _, doc = _read_document(path)
    return problems_in(doc)


def _eye_to_dict(eye: EyeRx, unstated: bool = False) -> dict[str, Any]:
    """An eye's document; ``unstated``: its file stated no amplitude (it came from the age, or is 0
    without one), so it is left out and comes from the age again when read back."""
    out: dict[str, Any] = {
        "sphere_D": eye.sphere_D,
        "cylinder_D": eye.cylinder_D,
        "axis_deg": eye.axis_deg,
        "pupil_diameter_mm": eye.pupil_diameter_mm,
    }
    if not unstated:
        out["accommodation_D"] = eye.accommodation_D
    if eye.accommodative_lag_D:
        out["accommodative_lag_D"] = eye.accommodative_lag_D
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
    doc = {"schema": SCHEMA, "notes": rx.notes, **{e: _eye_to_dict(rx.eye(e), e in rx.accommodation_unstated)
                                                     for e in names(Eye)}}
    if rx.age_years is not None:
        doc = {"schema": SCHEMA, "notes": rx.notes, "age_years": rx.age_years, "right": doc["right"],
               "left": doc["left"]}
    return json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n"


_TEMPLATE = """\
// vrcorrect prescription file (schema vrcorrect.prescription/1).
//
// Lines whose first non-blank characters are // are comments. Everything else
// is standard JSON: double-quoted keys, no trailing commas, no comment after a
// value on the same line. Replace the numbers below with your own: the first
// three per eye are the eye's own refraction, at the cornea. A contact-lens
// prescription gives them as they are; a spectacle lens sits about 12 mm in
// front of the eye, where a power F corrects an eye of F / (1 - 0.012 F): a
// -6.00 lens is a -5.60 eye (under 4 D the two differ by less than 0.2 D).
// 'vrcorrect rx new PATH --right "-2.00 -1.00 x 120" --left ...' writes this
// file from a spectacle prescription's lines and moves them to the eye.
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
//   pupil_diameter_mm  a pupil diameter in millimetres, 1 to 9: the one this
//                      prescription is modelled through with --pupil rx. By
//                      default (--pupil auto) vrcorrect takes the pupil you
//                      view through from the display's light instead (about 3
//                      mm for a bright monitor or a headset, more when dim).
//   accommodation_D    optional: how many dioptres the eye can still focus by
//                      itself (accommodation amplitude), 0 to 15. Left out, it
//                      is the amplitude expected at age_years (Hofstetter's
//                      mean, 18.5 - 0.3 x age: 6.5 D at 40, 0 from about 62)
//                      when the file gives an age, else 0 (none, as a
//                      presbyope). An eye that focuses on the display by
//                      itself sees it sharp, and a correction designed for
//                      blur it does not see makes its view worse: give your
//                      age, or your measured amplitude.
//   accommodative_lag_D
//                      optional: how far behind a near card at 40 cm the eye
//                      focuses, in dioptres, 0 to 2, as MEM retinoscopy
//                      measures it (0.25 to 0.75 is usual; left out, 0: the
//                      eye focuses exactly). The lag is taken to grow with
//                      how far the eye must focus (2.5 D at 40 cm), so it
//                      counts for less at a monitor, less still in a headset.
//   higher_order       optional: higher-order aberrations from an aberrometer,
//                      for example
//                        "higher_order": {"pupil_diameter_mm": 6.0,
//                                         "coefficients_um": {"7": 0.10, "12": -0.05}}
//     pupil_diameter_mm  the pupil (1 to 9 mm) the coefficients were measured
//                        at; it must be at least the eye's pupil_diameter_mm,
//                        and a viewing pupil from the light is held at it,
//                        because a wavefront cannot be extrapolated beyond the
//                        measured pupil.
//     coefficients_um    Zernike coefficients in micrometres (-10 to 10), keyed
//                        by the OSA/ANSI single index j as a string, 6 to 65
//                        (radial orders 3 to 10). j 0-5 (piston, tilt, defocus,
//                        astigmatism) come from sphere, cylinder and axis and
//                        must not be given here.
//
// "notes" is optional free text. "age_years" is optional too: the wearer's age
// (1 to 120), which the viewing pupil's formula uses (older eyes have smaller
// pupils), and the accommodation of an eye that states none; leave it out to
// use the formula's reference age and no accommodation.
"""


#: The notes of a template with no eye given.
TEMPLATE_NOTES = "Template: replace the numbers with your own prescription."

#: The pupil a template's eyes are modelled through with ``--pupil rx`` (mm).
TEMPLATE_PUPIL_MM = 4.0


def _eye_block(name: str, eye: tuple[float, float, float] | None, lag_D: float | None = None) -> str:
    s, c, a = eye if eye is not None else (0.0, 0.0, 0.0)
    lag = "" if lag_D is None else f',\n    "accommodative_lag_D": {float(lag_D)!r}'
    return (f'  "{name}": {{\n    "sphere_D": {float(s)!r},\n    "cylinder_D": {float(c)!r},\n'
            f'    "axis_deg": {a:g},\n    "pupil_diameter_mm": {TEMPLATE_PUPIL_MM!r}{lag}\n  }}')


def template_text(right: tuple[float, float, float] | None = None, left: tuple[float, float, float] | None = None,
                  age_years: float | None = None, notes: str = TEMPLATE_NOTES, lag_D: float | None = None) -> str:
    """A commented prescription template that loads as a valid Prescription: each eye that is given as
    ``(sphere_D, cylinder_D, axis_deg)`` filled in (else zeros to replace), ``age_years`` if given,
    and both eyes' ``accommodative_lag_D`` if ``lag_D`` is given.  The values are checked where the
    file is loaded, not here."""
    head = [f'  "schema": "{SCHEMA}"', f'  "notes": {json.dumps(notes, ensure_ascii=False)}']
    if age_years is not None:
        head.append(f'  "age_years": {float(age_years):g}')
    body = ",\n".join(head + [_eye_block("right", right, lag_D), _eye_block("left", left, lag_D)])
    return _TEMPLATE + "{\n" + body + "\n}\n"


def template_problems(text: str) -> list[FieldProblem]:
    """Every problem in a template's text (:func:`template_text` filled with values out of range, say)."""
    return problems_in(json.loads(_strip_comments(text), object_pairs_hook=_object_no_duplicates))


def write_template(path: str | PathLike[str], force: bool = False, **filled: Any) -> None:
    """Write :func:`template_text` (``filled``: its eyes, age and notes) to ``path`` atomically.

    Raises
    ------
    InputError
        If ``path`` exists and ``force`` is false (the message names
        ``--force``), or the folder is missing or not writable.
    ValidationErrors
        Every value given that a prescription does not allow (nothing is written).
    """
    text = template_text(**filled)
    problems = template_problems(text)
    if problems:
        raise ValidationErrors(problems)
    write_text_atomic(Path(path), text, force=force)


def bundled_sample_path() -> Path:
    """Path of the bundled sample prescription ``vrcorrect/data/sample_rx.json``."""
    return package_data("sample_rx.json")
