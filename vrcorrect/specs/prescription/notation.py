"""A spectacle prescription as an optician writes it, read into sphere, cylinder and axis.

``vrcorrect rx new --right "-2.00 -1.00 x 120" --left "-1.50 DS"`` writes a prescription file from the
lines on a spectacle prescription, so that nobody has to edit JSON to start.  Accepted, case and
spaces aside:

- ``SPHERE`` alone: ``-1.50``, ``+0.75``, ``-1.50 DS`` (dioptre sphere), ``-1.50 sph``, ``plano``
  (also ``pl``, ``0``): no cylinder;
- ``SPHERE CYLINDER x AXIS``: ``-2.00 -1.00 x 120``, ``-2.00/-1.00x120``, ``+1.25 -0.50 × 180``,
  ``plano -0.75 x 90``, ``-2.00 -1.00 @ 120``; the cylinder in either form (minus, as optometrists
  write it, or plus), the axis in whole degrees 0 to 180 (TABO), a ``D`` or ``DC`` after a power
  allowed (``-2.00D -1.00DC x 120``);
- either of them followed by a reading addition, ``ADD +2.00`` (:func:`split_add` takes it off; the
  distance prescription is what vrcorrect models).

Anything else is refused with the text, the field it came from and the forms above; the values'
ranges are :class:`~vrcorrect.specs.prescription.model.EyeRx`'s, checked where the eye is made.

A spectacle lens sits in front of the eye (the vertex distance, about 12 mm), where a power ``F``
corrects an eye whose own refraction, at the cornea, is ``F / (1 - d F)`` (``d`` in metres): a
-6.00 D lens is a -5.60 D eye, a +6.00 D lens a +6.45 D eye.  A prescription file holds the eye's
own refraction (docs/architecture.md, 'Physics conventions'), so :func:`at_eye` moves a line's two
principal meridians there.

Layer 1: the standard library.
"""

from __future__ import annotations

import math
import re

from ...plumbing.errors import ValidationError

__all__ = ["FORMS", "DEFAULT_VERTEX_MM", "VERTEX_ALLOWED", "at_eye", "parse_spectacle_rx", "split_add"]

#: The lenses' distance from the eye a spectacle prescription is taken at when none is given, mm (the
#: usual fitting; a prescription of 4 D or more often states its own, as BVD).
DEFAULT_VERTEX_MM = 12.0

#: The vertex distances :func:`at_eye` takes, in words.
VERTEX_ALLOWED = "a finite distance from 0 to 25 mm (the lenses from the cornea; 0: the powers are at the eye already)"

#: What the refusal lists as the accepted forms.
FORMS = ("a spectacle prescription: SPHERE, or SPHERE CYLINDER x AXIS, e.g. '-1.50', '-1.50 DS', 'plano', "
         "'-2.00 -1.00 x 120', '-2.00/-1.00x120', 'plano -0.75 x 90'")

_POWER = r"(?:[+-]?(?:\d+(?:\.\d*)?|\.\d+)|plano|pl)"
_SPHERE_ONLY = re.compile(rf"^\s*(?P<s>{_POWER})\s*(?:d|ds|dsph|sph|sphere)?\s*$", re.IGNORECASE)
_FULL = re.compile(rf"^\s*(?P<s>{_POWER})\s*(?:d|ds|dsph|sph)?\s*[/\s]\s*(?P<c>[+-]?(?:\d+(?:\.\d*)?|\.\d+))\s*"
                   r"(?:d|dc|dcyl|cyl)?\s*(?:x|×|@|\*|ax|axis)\s*(?P<a>\d+(?:\.\d*)?)\s*°?\s*$", re.IGNORECASE)

_NO_AXIS = re.compile(rf"^\s*{_POWER}\s*(?:d|ds|dsph|sph)?\s*[/\s]\s*[+-]?(?:\d+(?:\.\d*)?|\.\d+)\s*(?:d|dc|dcyl|cyl)?\s*$",
                      re.IGNORECASE)


_ADD = re.compile(r"\s*(?:,|;)?\s*\badd\b\s*:?\s*(?P<add>[+-]?(?:\d+(?:\.\d*)?|\.\d+))\s*(?:d\b)?\s*$", re.IGNORECASE)


def split_add(text: str) -> tuple[str, float | None]:
    """A line and its reading addition (``... ADD +2.00``, the near add of a presbyope's prescription), if
    it ends with one: ``(the line without it, the add in dioptres or None)``. vrcorrect models the
    distance prescription at the display's distance, and the eye's own focus from its age or
    ``accommodation_D``; the add is read so that a line copied whole is not refused, and said to be
    unused by the caller."""
    if not isinstance(text, str):
        return text, None
    m = _ADD.search(text.replace("−", "-"))
    if m is None:
        return text, None
    return text.replace("−", "-")[:m.start()], float(m["add"])


def _power(text: str) -> float:
    return 0.0 if text.lower() in ("plano", "pl") else float(text)


def parse_spectacle_rx(text: str, field: str) -> tuple[float, float, float]:
    """``(sphere_D, cylinder_D, axis_deg)`` of one eye's line of a spectacle prescription (the forms in
    this module's docstring); a :class:`ValidationError` naming ``field`` (e.g. ``--right``), the text
    and the accepted forms for anything else."""
    if not isinstance(text, str):
        raise ValidationError(field, text, FORMS)
    cleaned = text.replace("−", "-").replace("–", "-").strip()   # a typeset minus or dash, as copied from a document
    m = _SPHERE_ONLY.match(cleaned)
    if m:
        return _power(m["s"]), 0.0, 0.0
    m = _FULL.match(cleaned)
    if m:
        axis = float(m["a"])
        if not 0.0 <= axis <= 180.0:
            raise ValidationError(f"{field} axis", m["a"], "0 to 180 degrees (TABO: 0 and 180 are horizontal)")
        return _power(m["s"]), float(m["c"]), axis
    if _NO_AXIS.match(cleaned):
        raise ValidationError(field, text, "the cylinder's axis after it, 'x AXIS' in degrees 0 to 180 (e.g. "
                                           "'-2.00 -1.00 x 120'): a cylinder without its axis is not an eye")
    raise ValidationError(field, text, FORMS)


def at_eye(sphere_D: float, cylinder_D: float, axis_deg: float, vertex_mm: float,
           field: str = "--vertex") -> tuple[float, float, float]:
    """A spectacle line ``(sphere_D, cylinder_D, axis_deg)`` worn ``vertex_mm`` in front of the eye, as
    the eye's own refraction: each principal meridian's power ``F`` becomes ``F / (1 - d F)``, the
    axis stays (rounded to a thousandth of a dioptre). A :class:`ValidationError` naming ``field`` for
    a distance out of :data:`VERTEX_ALLOWED`; a meridian of ``1 / d`` dioptres or more (beyond any
    prescription's range: +40 D at 25 mm) is left as written, never divided by zero."""
    if isinstance(vertex_mm, bool) or not isinstance(vertex_mm, (int, float)) or not math.isfinite(vertex_mm) \
            or not 0.0 <= vertex_mm <= 25.0:
        raise ValidationError(field, vertex_mm, VERTEX_ALLOWED)
    d = vertex_mm / 1000.0

    def moved(power: float) -> float:
        # 1 - d F >= 0.5 for |F| <= 20 D (a prescription's range) and d <= 25 mm; a power so strong that
        # the lens would focus at or behind the eye is left as written, for the eye's range to refuse
        return power / (1.0 - d * power) if 1.0 - d * power >= 0.25 else power

    first, second = moved(sphere_D), moved(sphere_D + cylinder_D)
    return round(first, 3) + 0.0, round(second - first, 3) + 0.0, axis_deg
