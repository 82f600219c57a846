"""The viewing pupil from the light: Watson & Yellott's unified formula, and the pupil's dynamics.

The pupil an eye views a display through follows the light it adapts to, not the prescription.
Watson & Yellott (J. Vision 12(10):12, 2012) unify seven published formulas; their core is Stanley &
Davies (1995), a function of the corneal flux density ``F = L a`` (luminance ``L`` in cd/m^2 times the
adapting field's area ``a`` in deg^2)::

    D_SD(F) = 7.75 - 5.75 (F / 846)^0.41 / ((F / 846)^0.41 + 2)        (mm)

One eye adapted instead of two counts as a tenth of the flux (``M(1) = 0.1``, ``M(2) = 1``), and age
``y`` moves the diameter by ``(y - 28.58) (0.02132 - 0.009562 D_SD)``: the older eye's pupil is
smaller, more so in the dark.  The age term was fitted to observers of 20 to 83 years; outside that
range the age is held at the nearer end, with a note (:data:`FORMULA_AGE_RANGE`).

A full headset field (about 6000 to 8000 deg^2) at 10 / 50 / 100 cd/m^2 gives about 3.4 / 2.9 /
2.7 mm; a 27-inch monitor at 60 cm (about 1800 deg^2) at 100 cd/m^2, about 3.3 mm.

What the field is, here (:func:`field_area_deg2`): a headset's whole per-eye view (its angular width
times height, times pi/4 for the lens's round field of view); a monitor's screen (the panel's angular
size), lit at the image's mean luminance, as if the image filled it.  The room around a monitor is
left out (the formula takes one uniform field).

The pupil moves: it constricts within about 0.3 to 0.5 s when the light rises and dilates over
seconds when it falls (:class:`PupilDynamics`, a first-order follower with a time constant for each
direction).

Every pupil vrcorrect designs for lies in :data:`PUPIL_RANGE_MM`; an estimate outside it is clamped,
with a note.  Layer 2: plain numbers, no arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..plumbing.errors import ValidationError
from ..specs.display import DisplayProfile

__all__ = ["PUPIL_RANGE_MM", "FORMULA_AGE_RANGE", "REFERENCE_AGE_YEARS", "PupilEstimate", "stanley_davies_mm",
           "unified_pupil_mm", "field_area_deg2", "pupil_from_light", "PupilDynamics", "CONSTRICT_S", "DILATE_S",
           "check_pupil_mm"]

#: The viewing pupils vrcorrect designs for (mm): a light-adapted pupil lies in it from a few cd/m^2
#: (about 7 mm) to far brighter than any display (about 2 mm).
PUPIL_RANGE_MM = (2.0, 7.5)
#: The ages Watson & Yellott's age term was fitted to (Winn et al. 1994's observers), years.
FORMULA_AGE_RANGE = (20.0, 83.0)
#: The age at which the age term is zero (Watson & Yellott 2012), years.
REFERENCE_AGE_YEARS = 28.58
#: Time constants of :class:`PupilDynamics` (s): constriction (95 % of a step in about 0.4 s) and
#: dilation (95 % in about 5 s).
CONSTRICT_S = 0.13
DILATE_S = 1.6


def check_pupil_mm(value: Any, field: str = "--pupil") -> float:
    """A fixed viewing pupil, checked: a finite number in :data:`PUPIL_RANGE_MM` (mm)."""
    lo, hi = PUPIL_RANGE_MM
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if isinstance(value, bool) or not (math.isfinite(number) and lo <= number <= hi):
        raise ValidationError(field, value, f"'auto', 'rx' or a pupil diameter from {lo:g} to {hi:g} mm "
                                            "(the light-adapted range vrcorrect designs for)")
    return number


def stanley_davies_mm(flux_cd_deg2: float) -> float:
    """Stanley & Davies (1995): the pupil (mm) for a corneal flux density ``F = L a`` (cd/m^2 deg^2)."""
    f = (max(float(flux_cd_deg2), 0.0) / 846.0) ** 0.41
    return 7.75 - 5.75 * f / (f + 2.0)


@dataclass(frozen=True)
class PupilEstimate:
    """A viewing pupil worked out from the light, and how.

    Attributes
    ----------
    diameter_mm
        The pupil designed for: :attr:`formula_mm` clamped to :data:`PUPIL_RANGE_MM` (and to an upper
        bound the caller gives, such as the pupil higher-order terms were measured at).
    formula_mm
        What the unified formula gives.
    luminance_cd_m2, area_deg2, age_years, eyes
        Its inputs (``age_years`` None: the formula's reference age, no age term).
    notes
        What was clamped, and why, in words.
    """

    diameter_mm: float
    formula_mm: float
    luminance_cd_m2: float
    area_deg2: float
    age_years: float | None
    eyes: int
    notes: tuple[str, ...] = ()

    def describe(self) -> str:
        age = "age not given" if self.age_years is None else f"age {self.age_years:g}"
        return (f"pupil {self.diameter_mm:.2f} mm from the light (Watson & Yellott 2012: "
                f"{self.luminance_cd_m2:.3g} cd/m^2 over {self.area_deg2:.0f} deg^2, {age}, "
                f"{'both eyes' if self.eyes == 2 else 'one eye'})")


def unified_pupil_mm(luminance_cd_m2: float, area_deg2: float, age_years: float | None = None,
                     eyes: int = 2) -> tuple[float, tuple[str, ...]]:
    """Watson & Yellott's unified formula: the light-adapted pupil (mm) and notes.

    Parameters
    ----------
    luminance_cd_m2
        The adapting field's mean luminance, cd/m^2 (>= 0; 0 is darkness).
    area_deg2
        The field's area, deg^2 (> 0).
    age_years
        The observer's age (1 to 120); None: the formula's reference age (no age term).  Ages
        outside :data:`FORMULA_AGE_RANGE` are held at its nearer end, with a note.
    eyes
        1 or 2 eyes adapted.
    """
    notes: list[str] = []
    if not (math.isfinite(luminance_cd_m2) and luminance_cd_m2 >= 0.0):
        raise ValidationError("luminance_cd_m2", luminance_cd_m2, "a finite luminance >= 0 cd/m^2")
    if not (math.isfinite(area_deg2) and area_deg2 > 0.0):
        raise ValidationError("area_deg2", area_deg2, "a finite field area > 0 deg^2")
    if eyes not in (1, 2):
        raise ValidationError("eyes", eyes, "1 or 2")
    d = stanley_davies_mm(luminance_cd_m2 * area_deg2 * (1.0 if eyes == 2 else 0.1))
    if age_years is not None:
        if not (math.isfinite(age_years) and 1.0 <= age_years <= 120.0):
            raise ValidationError("age_years", age_years, "a number of years from 1 to 120")
        lo, hi = FORMULA_AGE_RANGE
        y = min(max(float(age_years), lo), hi)
        if y != age_years:
            notes.append(f"age {age_years:g} is outside the {lo:g}-{hi:g} years the pupil formula's age term was "
                         f"fitted to: taken as {y:g}")
        d += (y - REFERENCE_AGE_YEARS) * (0.02132 - 0.009562 * d)
    return d, tuple(notes)


def field_area_deg2(display: DisplayProfile, image_size: tuple[int, int] | None = None) -> float:
    """The adapting field's area (deg^2): a headset's per-eye view (width x height in degrees, times
    pi/4 for the round field its lenses show), a monitor's screen; from the display's resolution and
    pixels per degree, or ``image_size`` ``(width, height)`` where the display states no resolution."""
    size = display.resolution_px or image_size
    if size is None:
        raise ValidationError("display.resolution_px", None, "a resolution, or an image size to take the field from")
    w_deg = size[0] / display.pixels_per_degree
    h_deg = size[1] / display.pixels_per_degree
    return w_deg * h_deg * (math.pi / 4.0 if display.kind == "headset" else 1.0)


def pupil_from_light(mean_relative_luminance: float, display: DisplayProfile, age_years: float | None = None,
                     image_size: tuple[int, int] | None = None, eyes: int = 2,
                     upper_mm: float | None = None, upper_why: str = "") -> PupilEstimate:
    """The viewing pupil for a displayed image whose mean relative luminance (white = 1; linear light
    weighted by :func:`vrcorrect.physics.perception.luminance_weights`) is ``mean_relative_luminance``
    on ``display`` (its peak luminance and field, :func:`field_area_deg2`), clamped to
    :data:`PUPIL_RANGE_MM` and to ``upper_mm`` (``upper_why`` says what that is), with notes."""
    if not math.isfinite(mean_relative_luminance) or mean_relative_luminance < 0.0:
        raise ValidationError("mean_relative_luminance", mean_relative_luminance, "a finite number >= 0")
    luminance = float(mean_relative_luminance) * display.photometry.peak_luminance_cd_m2
    area = field_area_deg2(display, image_size)
    d, notes_ = unified_pupil_mm(luminance, area, age_years, eyes)
    notes = list(notes_)
    lo, hi = PUPIL_RANGE_MM
    used = min(max(d, lo), hi)
    if used != d:
        notes.append(f"the light gives a {d:.2f} mm pupil ({luminance:.3g} cd/m^2): held at {used:g} mm, the "
                     f"{'largest' if d > hi else 'smallest'} pupil vrcorrect designs for")
    if upper_mm is not None and used > upper_mm:
        notes.append(f"pupil {used:.2f} mm held at {upper_mm:g} mm{': ' + upper_why if upper_why else ''}")
        used = float(upper_mm)
    return PupilEstimate(diameter_mm=used, formula_mm=d, luminance_cd_m2=luminance, area_deg2=area,
                         age_years=age_years, eyes=eyes, notes=tuple(notes))


@dataclass
class PupilDynamics:
    """The pupil following the light over time: a first-order follower of the light-adapted diameter,
    faster when it constricts (:data:`CONSTRICT_S`) than when it dilates (:data:`DILATE_S`).

    ``update(target_mm, dt_s)`` moves :attr:`diameter_mm` towards ``target_mm`` by
    ``1 - exp(-dt / tau)`` of the way; the first update (no diameter yet) jumps to the target.
    """

    constrict_s: float = CONSTRICT_S
    dilate_s: float = DILATE_S
    diameter_mm: float | None = None

    def update(self, target_mm: float, dt_s: float) -> float:
        if not math.isfinite(target_mm):
            raise ValidationError("target_mm", target_mm, "a finite pupil diameter")
        if self.diameter_mm is None:
            self.diameter_mm = float(target_mm)
            return self.diameter_mm
        if dt_s <= 0.0:
            return self.diameter_mm
        tau = self.constrict_s if target_mm < self.diameter_mm else self.dilate_s
        self.diameter_mm += (target_mm - self.diameter_mm) * (1.0 - math.exp(-dt_s / tau))
        return self.diameter_mm

    def reset(self) -> None:
        self.diameter_mm = None
