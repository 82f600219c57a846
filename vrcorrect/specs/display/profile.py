"""Display profiles: what vrcorrect needs to know about one display (its primaries, angular
resolution, viewing distance, transfer function and photometry), as frozen, validated data.

- ``pixels_per_degree`` is the angular pixel density at the centre of the view; ``distance_m``
  is the viewing distance of a monitor, or the distance of a headset's virtual image
  (``math.inf`` for collimated optics).
- Code values (what is written to the display) are in [0, 1]; the transfer function maps them to
  linear light in [0, 1].

Reading a profile from a JSON file, and the built-in presets (which are such files), is
:mod:`vrcorrect.specs.display.profile_files`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ...plumbing.errors import FieldProblem, ValidationError
from ..validation import Range, check_number, is_number, positive_finite
from .spectra import RGB_LABELS, Spectra

__all__ = [
    "TRANSFERS",
    "KINDS",
    "PROFILE_SCHEMA",
    "PPD_RANGE",
    "PEAK_LUMINANCE_RANGE",
    "CONTRAST_RANGE",
    "AMBIENT_LUX_RANGE",
    "REFLECTIVITY_RANGE",
    "DEFAULT_PHOTOMETRY",
    "ppd_from_pitch",
    "ppd_from_fov",
    "Photometry",
    "default_photometry",
    "DisplayProfile",
]


#: Transfer functions a profile may name.
TRANSFERS: tuple[str, ...] = ("srgb", "gamma2.2", "linear")
#: Kinds of display.
KINDS: tuple[str, ...] = ("monitor", "headset")
#: ``schema`` value of a display profile JSON document.
PROFILE_SCHEMA = "vrcorrect.display/1"
#: Allowed pixels per degree.
PPD_RANGE = (1.0, 500.0)
#: Allowed photometry: peak luminance (cd/m^2), contrast (peak : black), ambient illuminance (lux),
#: screen reflectivity (fraction of the ambient light reflected, Lambertian).
PEAK_LUMINANCE_RANGE = (1.0, 10000.0)
CONTRAST_RANGE = (2.0, 1e7)
AMBIENT_LUX_RANGE = (0.0, 100000.0)
REFLECTIVITY_RANGE = (0.0, 1.0)

#: The rule of ``pixels_per_degree``, for a profile object and a profile file alike.
PPD_RULE = Range(PPD_RANGE[0], PPD_RANGE[1], f"a number from {PPD_RANGE[0]:g} to {PPD_RANGE[1]:g}")
#: The rules of the :class:`Photometry` fields (and the profile keys of the same names).
PHOTOMETRY_RULES: dict[str, Range] = {
    key: Range(lo, hi, f"a number from {lo:g} to {hi:g}{unit}")
    for key, (lo, hi), unit in (
        ("peak_luminance_cd_m2", PEAK_LUMINANCE_RANGE, " cd/m^2"),
        ("contrast", CONTRAST_RANGE, " (peak : black)"),
        ("ambient_lux", AMBIENT_LUX_RANGE, " lux"),
        ("reflectivity", REFLECTIVITY_RANGE, ""),
    )
}


# --------------------------------------------------------------------------
# Angular resolution
# --------------------------------------------------------------------------


def ppd_from_pitch(pixel_pitch_mm: float, distance_m: float) -> float:
    """Pixels per degree at the centre of a flat screen seen head-on.

    One pixel of pitch ``p`` at distance ``d`` subtends
    ``2·atan(p / (2·d))``; the result is the reciprocal of that angle in
    degrees. For ``p << d`` this tends to ``π·d / (180·p)``.

    Parameters
    ----------
    pixel_pitch_mm
        Centre-to-centre pixel spacing in mm (> 0).
    distance_m
        Eye-to-screen distance in m (> 0, finite).

    Returns
    -------
    float
        Pixels per degree of visual angle.
    """
    pitch_m = positive_finite("pixel_pitch_mm", pixel_pitch_mm) / 1000.0
    d = positive_finite("distance_m", distance_m)
    return 1.0 / math.degrees(2.0 * math.atan(pitch_m / (2.0 * d)))


def ppd_from_fov(pixels: int, fov_deg: float) -> float:
    """Mean pixels per degree across a headset's per-eye field of view.

    ``pixels / fov_deg``. Lens distortion makes the true density vary
    across the view (usually higher at the centre), so this is an average.

    Parameters
    ----------
    pixels
        Panel pixels per eye along the direction of ``fov_deg`` (> 0).
    fov_deg
        Per-eye field of view along the same direction, degrees (0-180).
    """
    if isinstance(pixels, bool) or not isinstance(pixels, (int, np.integer)) or pixels <= 0:
        raise ValidationError("pixels", pixels, "a positive integer")
    fov = positive_finite("fov_deg", fov_deg)
    if fov >= 180.0:
        raise ValidationError("fov_deg", fov, "a field of view between 0 and 180 degrees")
    return float(pixels) / fov


# --------------------------------------------------------------------------
# Photometry and DisplayProfile
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Photometry:
    """How bright the display is and the light around it: what a perceptual metric needs.

    ColorVideoVDP (:func:`vrcorrect.vision.vdp.jod`) turns code values into
    absolute luminance with these, after Mantiuk's gain-gamma-offset display
    model: ``L = (peak - black) * linear(V) + black + reflectivity * ambient / pi``
    with ``black = peak / contrast``.

    Parameters
    ----------
    peak_luminance_cd_m2
        Luminance of full white, cd/m^2 (1 to 10000).
    contrast
        Peak luminance over black level, the panel's own (``2`` to ``1e7``).
    ambient_lux
        Illuminance falling on the screen, lux (0 to 100000; 0 inside a headset).
    reflectivity
        Fraction of the ambient light the screen reflects (0 to 1; 0.005 is
        ColorVideoVDP's default for a matte panel).
    sources
        Where each number comes from, or "estimate".
    """

    peak_luminance_cd_m2: float
    contrast: float
    ambient_lux: float
    reflectivity: float = 0.005
    sources: str = ""

    def __post_init__(self) -> None:
        problems = photometry_problems({k: getattr(self, k) for k in PHOTOMETRY_RULES}, prefix="photometry.")
        if problems:
            p = problems[0]
            raise ValidationError(p.field, p.value, p.allowed)
        for name in ("peak_luminance_cd_m2", "contrast", "ambient_lux", "reflectivity"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def black_cd_m2(self) -> float:
        """The panel's own black level, cd/m^2 (``peak / contrast``)."""
        return self.peak_luminance_cd_m2 / self.contrast

    @property
    def reflected_cd_m2(self) -> float:
        """Ambient light reflected by the screen, cd/m^2 (``reflectivity * ambient / pi``)."""
        return self.reflectivity * self.ambient_lux / math.pi

    def describe(self) -> str:
        """One line: peak, contrast, ambient, effective contrast."""
        effective = self.peak_luminance_cd_m2 / (self.black_cd_m2 + self.reflected_cd_m2)
        return (f"peak {self.peak_luminance_cd_m2:g} cd/m^2, contrast {self.contrast:g}:1, ambient "
                f"{self.ambient_lux:g} lux (reflectivity {self.reflectivity:g}; effective contrast "
                f"{effective:.0f}:1)")


#: Photometry of a profile that states none, by kind (the figures of ColorVideoVDP's own standard
#: displays, Mantiuk et al. 2024: 'standard_fhd', an office monitor, and 'standard_hmd', a headset).
DEFAULT_PHOTOMETRY: dict[str, tuple[float, float, float]] = {
    "monitor": (200.0, 1000.0, 250.0),
    "headset": (100.0, 1000.0, 0.0),
}


def default_photometry(kind: str) -> Photometry:
    """The photometry assumed for a display of ``kind`` that states none (an estimate)."""
    peak, contrast, ambient = DEFAULT_PHOTOMETRY[kind]
    where = "an office monitor" if kind == "monitor" else "a headset (no ambient light reaches the panel)"
    return Photometry(peak, contrast, ambient, sources=(
        f"estimate: the default for {where}: peak {peak:g} cd/m^2, contrast {contrast:g}:1, ambient "
        f"{ambient:g} lux (ColorVideoVDP's standard_{'fhd' if kind == 'monitor' else 'hmd'} display)"))


def photometry_problems(values: dict[str, Any], prefix: str = "") -> list[FieldProblem]:
    """Every problem with the four :class:`Photometry` figures in ``values`` (empty when valid)."""
    problems: list[FieldProblem] = []
    for key, rule in PHOTOMETRY_RULES.items():
        check_number(problems, prefix + key, values[key], rule)
    return problems


def _is_resolution(value: Any) -> bool:
    return (
        isinstance(value, (tuple, list))
        and len(value) == 2
        and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in value)
    )


def distance_ok(value: Any) -> bool:
    """Whether ``value`` is a viewing distance: a number > 0 m (``inf`` included)."""
    return is_number(value) and not math.isnan(float(value)) and float(value) > 0


#: The fields a profile object and a profile file check alike: name -> (test, what is allowed).
FIELD_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "name": (lambda v: isinstance(v, str) and bool(v.strip()), "a non-empty string"),
    "title": (lambda v: isinstance(v, str), "a string"),
    "kind": (lambda v: v in KINDS, "one of: " + ", ".join(KINDS)),
    "transfer": (lambda v: v in TRANSFERS, "one of: " + ", ".join(TRANSFERS)),
    "resolution_px": (_is_resolution, "[width, height] in pixels, positive integers"),
    "sources": (lambda v: isinstance(v, str), "a string"),
}


def check_field(problems: list[FieldProblem], field: str, value: Any) -> bool:
    """Check ``value`` by :data:`FIELD_RULES` [``field``]; append a problem and return False if bad."""
    test, allowed = FIELD_RULES[field]
    if test(value):
        return True
    problems.append(FieldProblem(field, value, allowed))
    return False


def _profile_problems(
    name: Any,
    title: Any,
    kind: Any,
    primaries: Any,
    pixels_per_degree: Any,
    distance_m: Any,
    transfer: Any,
    resolution_px: Any,
    sources: Any,
    photometry: Any = None,
) -> list[FieldProblem]:
    """Every problem with the fields of a :class:`DisplayProfile` (empty when valid)."""
    problems: list[FieldProblem] = []
    check_field(problems, "name", name)
    check_field(problems, "title", title)
    check_field(problems, "kind", kind)
    if not isinstance(primaries, Spectra):
        problems.append(FieldProblem("primaries", type(primaries).__name__, "a Spectra object"))
    elif primaries.labels != RGB_LABELS:
        problems.append(FieldProblem("primaries.labels", primaries.labels, "('red', 'green', 'blue')"))
    elif np.any(primaries.values.max(axis=0) <= 0):
        problems.append(FieldProblem("primaries.values", "a channel that is zero everywhere", "each primary emitting somewhere"))
    check_number(problems, "pixels_per_degree", pixels_per_degree, PPD_RULE)
    if not distance_ok(distance_m):
        problems.append(FieldProblem("distance_m", distance_m, "a distance > 0 m (inf for a collimated image)"))
    check_field(problems, "transfer", transfer)
    if resolution_px is not None:
        check_field(problems, "resolution_px", resolution_px)
    check_field(problems, "sources", sources)
    if photometry is not None and not isinstance(photometry, Photometry):
        problems.append(FieldProblem("photometry", type(photometry).__name__, "a Photometry object or None"))
    return problems


@dataclass(frozen=True)
class DisplayProfile:
    """What vrcorrect needs to know about one display.

    Parameters
    ----------
    name
        Short key, e.g. ``"quest2"``.
    title
        Human-readable name, e.g. ``"Meta Quest 2"``.
    kind
        ``"monitor"`` or ``"headset"``.
    primaries
        Emission spectra of the red, green and blue sub-pixels at full drive
        (labels exactly ``("red", "green", "blue")``), relative radiance.
    pixels_per_degree
        Angular pixel density at the centre of the view, 1-500 px/deg.
    distance_m
        Monitor: eye-to-screen distance (m). Headset: distance of the
        lenses' virtual image (m); ``math.inf`` for a collimated image.
    transfer
        How code values map to linear light: ``"srgb"`` (IEC 61966-2-1),
        ``"gamma2.2"`` (pure power law) or ``"linear"``.
    resolution_px
        ``(width, height)`` in pixels: per eye for a headset, the panel for a
        monitor; ``None`` if unknown.
    sources
        Where each number comes from, or "estimate".
    photometry
        Peak luminance, contrast and ambient light (:class:`Photometry`);
        ``None``: :func:`default_photometry` of the kind.

    Raises
    ------
    ValidationError
        For the first invalid field (see :func:`load_display_profile` for a
        report of every problem in a file).
    """

    name: str
    title: str
    kind: str
    primaries: Spectra
    pixels_per_degree: float
    distance_m: float
    transfer: str = "srgb"
    resolution_px: tuple[int, int] | None = None
    sources: str = ""
    photometry: Photometry | None = None

    def __post_init__(self) -> None:
        problems = _profile_problems(
            self.name, self.title, self.kind, self.primaries, self.pixels_per_degree,
            self.distance_m, self.transfer, self.resolution_px, self.sources, self.photometry,
        )
        if problems:
            p = problems[0]
            raise ValidationError(p.field, p.value, p.allowed)
        object.__setattr__(self, "pixels_per_degree", float(self.pixels_per_degree))
        object.__setattr__(self, "distance_m", float(self.distance_m))
        if self.resolution_px is not None:
            object.__setattr__(self, "resolution_px", (int(self.resolution_px[0]), int(self.resolution_px[1])))
        if self.photometry is None:
            object.__setattr__(self, "photometry", default_photometry(self.kind))

    @property
    def vergence_D(self) -> float:
        """``1 / distance_m`` in dioptres (0 for an image at infinity)."""
        return 0.0 if math.isinf(self.distance_m) else 1.0 / self.distance_m

    @property
    def degrees_per_pixel(self) -> float:
        """Visual angle of one pixel at the centre of the view, degrees."""
        return 1.0 / self.pixels_per_degree
