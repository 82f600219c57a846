"""Spectacle prescriptions: the per-eye refractive error, loaded and validated.

A prescription file is JSON (full-line ``//`` comments allowed) with a schema
version and one object per eye::

    {
      "schema": "vrcorrect.prescription/1",
      "notes": "optional free text",
      "right": {"sphere_D": -2.5, "cylinder_D": -1.0, "axis_deg": 20,
                "pupil_diameter_mm": 4.0,
                "accommodation_D": 0.0,
                "accommodative_lag_D": 0.5,
                "higher_order": {"pupil_diameter_mm": 6.0,
                                 "coefficients_um": {"7": 0.10, "12": -0.05}}},
      "left": {...}
    }

Conventions (see ``docs/architecture.md``, 'Physics conventions'):

- sphere S and cylinder C in dioptres (D), cylinder axis α in degrees, 0-180,
  TABO / ISO 8429 notation. Minus- and plus-cylinder forms describe the same
  eye and are both accepted.
- Power vector (Thibos, Wheeler & Horner 1997):
  M = S + C/2, J0 = -(C/2)·cos 2α, J45 = -(C/2)·sin 2α.
- Higher-order Zernike coefficients are in micrometres, OSA/ANSI single index
  j (6..65, radial orders 3..10), for the stated pupil diameter. Terms j <= 5
  (piston, tilt, defocus, astigmatism) come from S, C and α.

The package: :mod:`.model` (the data classes and their field rules), :mod:`.document`
(every problem in a parsed document, and the prescription it describes) and :mod:`.files`
(reading, writing, the template, the bundled sample); every name is importable from here.

Validation collects every problem in a document before raising
:class:`~vrcorrect.plumbing.errors.ValidationErrors`; file problems (missing,
unreadable, not UTF-8, not JSON) raise :class:`~vrcorrect.plumbing.errors.InputError`.
"""

from __future__ import annotations

from .document import MISSING, parse_prescription, problems_in
from .files import bundled_sample_path, load_prescription, template_text, to_json_text, validate_file, write_template
from .model import LAG_MEASURED_AT_D, accommodation_from_age
from .model import J_MAX, J_MIN, SCHEMA, EyeRx, HigherOrder, PowerVector, Prescription  # noqa: F401  (importable from here, as before, though not in __all__)

__all__ = [
    "SCHEMA",
    "MISSING",
    "PowerVector",
    "HigherOrder",
    "EyeRx",
    "Prescription",
    "accommodation_from_age",
    "LAG_MEASURED_AT_D",
    "parse_prescription",
    "problems_in",
    "load_prescription",
    "validate_file",
    "to_json_text",
    "template_text",
    "write_template",
    "bundled_sample_path",
]
