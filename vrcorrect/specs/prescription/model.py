"""The prescription model: one eye's refraction (:class:`EyeRx`), both eyes
(:class:`Prescription`), power vectors and higher-order aberrations, as frozen, validated data.

The field rules here (ranges and what is allowed, in words) are the one table that both
programmatic construction and prescription files (:mod:`.document`) are checked against.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numpy as np

from ...plumbing.errors import FieldProblem, ValidationError, ValidationErrors
from ..validation import Range, check_number, unknown_key_problem
from ..vocabulary import Eye, either, names

__all__ = ["SCHEMA", "J_MIN", "J_MAX", "PowerVector", "HigherOrder", "EyeRx", "Prescription",
           "accommodation_from_age", "LAG_MEASURED_AT_D"]

SCHEMA = "vrcorrect.prescription/1"

#: Range of the OSA/ANSI single index accepted for higher-order terms
#: (j = 6 is Z(3,-3); j = 65 is Z(10,10)).
J_MIN = 6
J_MAX = 65


# --------------------------------------------------------------------------
# Field rules (one table used by files and by programmatic construction)
# --------------------------------------------------------------------------

SPHERE = Range(-20.0, 20.0, "a finite number from -20 to 20 (dioptres)")
CYLINDER = Range(-10.0, 10.0, "a finite number from -10 to 10 (dioptres; minus- or plus-cylinder form)")
AXIS = Range(0.0, 180.0, "a finite number from 0 to 180 (degrees, TABO / ISO 8429)")
PUPIL = Range(1.0, 9.0, "a finite number from 1 to 9 (millimetres)")
ACCOMMODATION = Range(0.0, 15.0, "a finite number from 0 to 15 (dioptres of accommodation amplitude)")
LAG = Range(0.0, 2.0, "a finite number from 0 to 2 (dioptres of accommodative lag at 40 cm, as MEM "
            "retinoscopy measures it; 0.25 to 0.75 is usual)")
HO_PUPIL = Range(1.0, 9.0, "a finite number from 1 to 9 (millimetres; the pupil the coefficients were measured at)")
AGE = Range(1.0, 120.0, "a finite number of years from 1 to 120")
COEFFICIENT = Range(-10.0, 10.0, "a finite number from -10 to 10 (micrometres)")

#: Hofstetter's (1950) mean amplitude of accommodation by age: ``18.5 - 0.30 age`` dioptres (his
#: least and greatest: ``15 - 0.25 age`` and ``25 - 0.40 age``).
HOFSTETTER_MEAN = (18.5, 0.30)

#: The demand an ``accommodative_lag_D`` is measured at, dioptres: a near card at 40 cm, as MEM
#: (monocular estimate method) retinoscopy does it.  The eye's response to a demand ``A`` is taken as
#: ``A (1 - lag / LAG_MEASURED_AT_D)`` (:func:`vrcorrect.physics.refraction.refractive_state`).
LAG_MEASURED_AT_D = 2.5


def accommodation_from_age(age_years: float) -> float:
    """The accommodation amplitude an eye of ``age_years`` is expected to have, dioptres: Hofstetter's
    mean, ``18.5 - 0.30 age`` (Hofstetter 1950, from Duane's measurements), held within the field's
    0 to 15 D (15 D up to age 11, 0 from about 62).

    Why the mean and not 0 when a prescription states no amplitude: an eye that focuses on the display
    by itself sees it sharp, and a correction designed for the blur it does not see over-sharpens what
    it sees, which is worse than none (docs/realtime.md, "Accommodation from age"); an amplitude
    assumed too large only leaves blur uncorrected that the eye would have gained from correcting."""
    if isinstance(age_years, bool) or not isinstance(age_years, (int, float)) or not math.isfinite(age_years):
        raise ValidationError("age_years", age_years, AGE.allowed)
    base, slope = HOFSTETTER_MEAN
    return float(min(max(base - slope * float(age_years), ACCOMMODATION.lo), ACCOMMODATION.hi))


J_ALLOWED = (
    f"an integer OSA/ANSI single index j from {J_MIN} to {J_MAX} (radial orders 3 to 10), "
    "written as a string key such as \"7\"; j 0-5 (piston, tilt, defocus, astigmatism) "
    "come from sphere_D, cylinder_D and axis_deg and must not be given here"
)

# Eye fields: name -> (rule, required)
EYE_FIELDS: dict[str, tuple[Range, bool]] = {
    "sphere_D": (SPHERE, True),
    "cylinder_D": (CYLINDER, True),
    "axis_deg": (AXIS, True),
    "pupil_diameter_mm": (PUPIL, True),
    "accommodation_D": (ACCOMMODATION, False),
    "accommodative_lag_D": (LAG, False),
}
COEFFS_ALLOWED = (
    "an object mapping OSA/ANSI index j (a string key, 6 to 65) to a coefficient in micrometres"
)


def join_field(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def parse_j(key: Any) -> int | None:
    """OSA/ANSI index from a coefficient key: a canonical decimal string or an int."""
    if isinstance(key, (bool, np.bool_)):
        return None
    if isinstance(key, (int, np.integer)):
        return int(key)
    if isinstance(key, str) and re.fullmatch(r"0|[1-9][0-9]{0,5}", key):
        return int(key)
    return None


def check_j(problems: list[FieldProblem], field: str, key: Any) -> int | None:
    j = parse_j(key)
    if j is None or not (J_MIN <= j <= J_MAX):
        problems.append(FieldProblem(field, key, J_ALLOWED))
        return None
    return j


def pupil_vs_measured_allowed(ho_pupil_mm: float) -> str:
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
                     problems: list[FieldProblem]) -> tuple[float | None, tuple[tuple[int, float], ...] | None]:
    """Validate programmatic HigherOrder fields (coefficients: mapping or pairs)."""
    pupil = check_number(problems, join_field(prefix, "pupil_diameter_mm"), pupil_diameter_mm, HO_PUPIL)
    cfield = join_field(prefix, "coefficients_um")
    if isinstance(coefficients, Mapping):
        pairs: list[Any] = list(coefficients.items())
    elif isinstance(coefficients, (str, bytes)) or not isinstance(coefficients, Iterable):
        problems.append(FieldProblem(cfield, coefficients, COEFFS_ALLOWED + " (or a sequence of (j, coefficient) pairs)"))
        return pupil, None
    else:
        pairs = list(coefficients)
    out: dict[int, float] = {}
    ok = True
    for pair in pairs:
        if not (isinstance(pair, tuple) or isinstance(pair, list)) or len(pair) != 2:
            problems.append(FieldProblem(cfield, pair, "(j, coefficient_um) pairs"))
            ok = False
            continue
        key, value = pair
        j = check_j(problems, join_field(cfield, str(key)), key)
        c = check_number(problems, join_field(cfield, str(key)), value, COEFFICIENT)
        if j is None or c is None:
            ok = False
            continue
        if j in out:
            problems.append(FieldProblem(join_field(cfield, str(j)), value, "each index j given once"))
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
        problems: list[FieldProblem] = []
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


def _snap_to_limits(value: float, rule: Range, tolerance: float = 1e-9) -> float:
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
        The pupil this eye is modelled through, millimetres, 1 to 9.  In a prescription file it is
        the pupil the prescription gives (``--pupil rx`` designs for it); the commands take the
        viewing pupil from the display's light by default (``--pupil auto``,
        :mod:`vrcorrect.physics.pupil`) and model the eye through that.
    accommodation_D
        Accommodation amplitude, dioptres, 0 to 15 (default 0: none).
    higher_order
        Optional higher-order aberrations; their measured pupil must be at
        least ``pupil_diameter_mm``.
    accommodative_lag_D
        How far behind a near card at 40 cm the eye focuses, dioptres, 0 to 2 (default 0: it focuses
        exactly; MEM retinoscopy measures it, 0.25 to 0.75 D is usual).  The lag is taken to grow with
        the demand (:data:`LAG_MEASURED_AT_D`), and to apply only while the eye accommodates.

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
    accommodative_lag_D: float = 0.0

    def __post_init__(self) -> None:
        problems: list[FieldProblem] = []
        values: dict[str, float] = {}
        for name, (rule, _required) in EYE_FIELDS.items():
            number = check_number(problems, name, getattr(self, name), rule)
            if number is not None:
                values[name] = number
        ho = self.higher_order
        if ho is not None and not isinstance(ho, HigherOrder):
            problems.append(FieldProblem("higher_order", ho, "a HigherOrder or None"))
        elif ho is not None and "pupil_diameter_mm" in values and values["pupil_diameter_mm"] > ho.pupil_diameter_mm:
            problems.append(FieldProblem("pupil_diameter_mm", self.pupil_diameter_mm,
                                    pupil_vs_measured_allowed(ho.pupil_diameter_mm)))
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
            raise ValidationErrors(unknown_key_problem(k, k, changes[k], names) for k in unknown)
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
        problems: list[FieldProblem] = []
        m = check_number(problems, "M_D", pv.M_D, Range(-math.inf, math.inf, "a finite number (dioptres)"))
        j0 = check_number(problems, "J0_D", pv.J0_D, Range(-math.inf, math.inf, "a finite number (dioptres)"))
        j45 = check_number(problems, "J45_D", pv.J45_D, Range(-math.inf, math.inf, "a finite number (dioptres)"))
        if problems:
            raise ValidationErrors(problems)
        assert m is not None and j0 is not None and j45 is not None
        radius = math.hypot(j0, j45)
        # Round-off (e.g. a -10 D cylinder coming back as -10.000000000000002)
        # must not make a limit case invalid: snap values within 1e-9 D of a limit.
        cylinder = _snap_to_limits(-2.0 * radius + 0.0, CYLINDER)
        sphere = _snap_to_limits(m - cylinder / 2.0, SPHERE)
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
    age_years
        The wearer's age (1 to 120), or None: the viewing pupil's formula then uses its reference
        age (:mod:`vrcorrect.physics.pupil`).  A prescription file that gives it, for an eye that
        states no ``accommodation_D``, sets that eye's amplitude to :func:`accommodation_from_age`.
    accommodation_unstated
        The eyes (``"right"``, ``"left"``) whose file states no amplitude: theirs is the one expected
        at ``age_years`` (:attr:`accommodation_from_age`), or 0 without an age, and follows the age
        (:meth:`with_age`).  Not compared: the same eyes are equal however their amplitude came.
    """

    right: EyeRx
    left: EyeRx
    notes: str = ""
    age_years: float | None = None
    accommodation_unstated: tuple[str, ...] = dataclasses.field(default=(), compare=False)

    def __post_init__(self) -> None:
        problems: list[FieldProblem] = []
        for name in names(Eye):
            if not isinstance(getattr(self, name), EyeRx):
                problems.append(FieldProblem(name, getattr(self, name), "an EyeRx"))
        if not isinstance(self.notes, str):
            problems.append(FieldProblem("notes", self.notes, "a string"))
        if self.age_years is not None:
            age = check_number(problems, "age_years", self.age_years, AGE)
            if age is not None:
                object.__setattr__(self, "age_years", age)
        if not isinstance(self.accommodation_unstated, tuple) or \
                any(e not in names(Eye) for e in self.accommodation_unstated):
            problems.append(FieldProblem("accommodation_unstated", self.accommodation_unstated,
                                         "a tuple of right and/or left"))
        if problems:
            raise ValidationErrors(problems)

    @property
    def accommodation_from_age(self) -> tuple[str, ...]:
        """The eyes whose amplitude is the one expected at ``age_years`` (:func:`accommodation_from_age`):
        those that state none, where an age is given."""
        return self.accommodation_unstated if self.age_years is not None else ()

    def with_age(self, age_years: float) -> "Prescription":
        """This prescription for a wearer of ``age_years`` (1 to 120): the age replaced, and each eye that
        states no amplitude (:attr:`accommodation_unstated`) given the one expected at that age; a
        stated amplitude is kept.  (An option that sets the wearer's age, the OpenXR layer's
        ``age_years``, sets both the viewing pupil's formula and these amplitudes.)

        Raises
        ------
        ValidationError, ValidationErrors
            For an age that is not a number (the first), or not one of years from 1 to 120.
        """
        amplitude = accommodation_from_age(age_years)
        eyes = {name: self.eye(name).with_changes(accommodation_D=amplitude) if name in self.accommodation_unstated
                else self.eye(name) for name in names(Eye)}
        return dataclasses.replace(self, age_years=age_years, **eyes)

    def eye(self, name: str) -> EyeRx:
        """The eye called ``"right"`` or ``"left"``.

        Raises
        ------
        ValidationError
            For any other name.
        """
        if name not in names(Eye):
            raise ValidationError("eye", name, either(Eye))
        return getattr(self, name)
