"""Display profiles: emission spectra, angular resolution, viewing distance
and transfer functions.

Layer 1 (plain, validated data). Imports only numpy, scipy, colour-science
(lazily, inside functions: ``import colour`` takes about a second) and
:mod:`vrcorrect.plumbing.errors`.

Conventions
-----------
- Wavelengths in nanometres (``wavelength_nm``), strictly increasing.
- Spectra are *relative* radiance per channel (non-negative, arbitrary
  scale). Downstream code states its own normalisation (for example display
  white maps to L = M = S = 1), so the absolute scale of a preset's spectra
  carries no meaning beyond the ratios inside one channel and, where the
  source measured them together, between channels.
- ``pixels_per_degree`` is the angular pixel density at the centre of the
  view; ``distance_m`` is the viewing distance of a monitor, or the distance
  of a headset's virtual image (``math.inf`` for collimated optics).
- Code values (what is written to the display) are in [0, 1]; the transfer
  function maps them to linear light in [0, 1].

The presets and the sources of every number are listed in
``vrcorrect/data/displays.md``.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..plumbing.errors import InputError, Problem, ValidationError, ValidationErrors, json_error_location

__all__ = [
    "Spectra",
    "Photometry",
    "DisplayProfile",
    "SpectraFit",
    "TRANSFERS",
    "KINDS",
    "PROFILE_SCHEMA",
    "ppd_from_pitch",
    "ppd_from_fov",
    "gaussian_spectra",
    "preset_names",
    "get_display",
    "load_display_profile",
    "read_spectra_csv",
    "fit_spectra",
    "srgb_to_linear",
    "linear_to_srgb",
    "decode",
    "encode",
]

#: Transfer functions a profile may name.
TRANSFERS: tuple[str, ...] = ("srgb", "gamma2.2", "linear")
#: Kinds of display.
KINDS: tuple[str, ...] = ("monitor", "headset")
#: ``schema`` value of a display profile JSON document.
PROFILE_SCHEMA = "vrcorrect.display/1"
#: Channel labels of a display's primaries, in order.
RGB_LABELS: tuple[str, str, str] = ("red", "green", "blue")

PPD_RANGE = (1.0, 500.0)
#: Allowed photometry: peak luminance (cd/m^2), contrast (peak : black), ambient illuminance (lux),
#: screen reflectivity (fraction of the ambient light reflected, Lambertian).
PEAK_LUMINANCE_RANGE = (1.0, 10000.0)
CONTRAST_RANGE = (2.0, 1e7)
AMBIENT_LUX_RANGE = (0.0, 100000.0)
REFLECTIVITY_RANGE = (0.0, 1.0)
CSV_WAVELENGTH_RANGE_NM = (300.0, 1000.0)
CSV_MIN_ROWS = 5


# --------------------------------------------------------------------------
# Spectra
# --------------------------------------------------------------------------


def _frozen_copy(array: np.ndarray) -> np.ndarray:
    out = np.array(array, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


def _wavelength_problem(wavelength_nm: Any, name: str) -> tuple[np.ndarray | None, Problem | None]:
    """Check a wavelength grid: 1-D, at least 2 samples, finite, strictly increasing."""
    try:
        wl = np.asarray(wavelength_nm, dtype=np.float64)
    except (TypeError, ValueError):
        return None, Problem(name, wavelength_nm, "a 1-D array of wavelengths in nm")
    if wl.ndim != 1 or wl.size < 2:
        return None, Problem(name, f"array of shape {wl.shape}", "a 1-D array of at least 2 wavelengths in nm")
    if not np.all(np.isfinite(wl)):
        return None, Problem(name, "array containing NaN or inf", "finite wavelengths in nm")
    steps = np.diff(wl)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0))
        return None, Problem(
            name,
            f"{wl[i]:g} nm followed by {wl[i + 1]:g} nm at index {i + 1}",
            "strictly increasing wavelengths in nm",
        )
    return wl, None


@dataclass(frozen=True, eq=False)
class Spectra:
    """Several emission spectra on one wavelength grid.

    A spectrum carries its wavelengths: resample explicitly (:meth:`resample`)
    before combining spectra measured on different grids.

    Parameters
    ----------
    wavelength_nm
        ``(n,)`` wavelengths in nm, strictly increasing and finite.
    values
        ``(n, c)`` relative spectral radiance of ``c`` channels (finite,
        ``>= 0``, arbitrary unit).
    labels
        ``c`` distinct channel names, e.g. ``("red", "green", "blue")``.
    source
        Where the data came from (file, table, or "estimate: ...").

    Both arrays are stored as read-only float64 copies.

    Raises
    ------
    ValidationError
        Naming the offending field (``wavelength_nm``, ``values``, ``labels``
        or ``source``).
    """

    wavelength_nm: np.ndarray
    values: np.ndarray
    labels: tuple[str, ...]
    source: str = ""

    def __post_init__(self) -> None:
        wl, problem = _wavelength_problem(self.wavelength_nm, "wavelength_nm")
        if problem is not None:
            raise ValidationError(problem.field, problem.value, problem.allowed)
        assert wl is not None
        try:
            values = np.asarray(self.values, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValidationError("values", self.values, "an (n, c) array of relative radiance") from None
        if values.ndim != 2 or values.shape[0] != wl.shape[0] or values.shape[1] < 1:
            raise ValidationError(
                "values",
                f"array of shape {values.shape}",
                f"shape ({wl.shape[0]}, c): one row per wavelength, one column per channel",
            )
        if not np.all(np.isfinite(values)):
            raise ValidationError("values", "array containing NaN or inf", "finite relative radiance")
        if np.any(values < 0):
            raise ValidationError("values", float(values.min()), "relative radiance >= 0")
        labels = self.labels
        if isinstance(labels, str) or not isinstance(labels, Iterable):
            raise ValidationError("labels", labels, f"a sequence of {values.shape[1]} channel names")
        labels = tuple(labels)
        if len(labels) != values.shape[1] or not all(isinstance(x, str) and x for x in labels):
            raise ValidationError("labels", labels, f"{values.shape[1]} non-empty channel names, one per column")
        if len(set(labels)) != len(labels):
            raise ValidationError("labels", labels, "distinct channel names")
        if not isinstance(self.source, str):
            raise ValidationError("source", self.source, "a string naming where the data came from")
        object.__setattr__(self, "wavelength_nm", _frozen_copy(wl))
        object.__setattr__(self, "values", _frozen_copy(values))
        object.__setattr__(self, "labels", labels)

    @property
    def n_channels(self) -> int:
        """Number of channels ``c``."""
        return int(self.values.shape[1])

    def channel(self, label: str) -> np.ndarray:
        """The ``(n,)`` spectrum of one channel (read-only view).

        Raises
        ------
        ValidationError
            If ``label`` is not one of :attr:`labels`.
        """
        try:
            i = self.labels.index(label)
        except ValueError:
            raise ValidationError("label", label, "one of: " + ", ".join(self.labels)) from None
        return self.values[:, i]

    def peak_wavelength_nm(self) -> np.ndarray:
        """``(c,)`` wavelength (nm) of each channel's maximum (first one on ties)."""
        return self.wavelength_nm[np.argmax(self.values, axis=0)]

    def resample(self, wavelength_nm: np.ndarray) -> "Spectra":
        """Spectra on a new wavelength grid.

        Linear interpolation between measured samples (exact at the measured
        wavelengths); **zero** outside the measured range (no extrapolation:
        a display emits nothing we did not measure).

        Parameters
        ----------
        wavelength_nm
            ``(m,)`` new grid in nm, strictly increasing and finite.

        Returns
        -------
        Spectra
            Same labels and source, values of shape ``(m, c)``.
        """
        wl, problem = _wavelength_problem(wavelength_nm, "wavelength_nm")
        if problem is not None:
            raise ValidationError(problem.field, problem.value, problem.allowed)
        assert wl is not None
        out = np.empty((wl.size, self.n_channels), dtype=np.float64)
        for c in range(self.n_channels):
            out[:, c] = np.interp(wl, self.wavelength_nm, self.values[:, c], left=0.0, right=0.0)
        return Spectra(wl, out, self.labels, self.source)

    def __repr__(self) -> str:
        wl = self.wavelength_nm
        return (
            f"Spectra({self.labels!r}, {wl.size} samples {wl[0]:g}-{wl[-1]:g} nm, "
            f"source={self.source!r})"
        )


def gaussian_spectra(
    components: Mapping[str, Sequence[tuple[float, float, float]]],
    wavelength_nm: np.ndarray | None = None,
    source: str = "parametric: sum of Gaussians",
) -> Spectra:
    """Parametric spectra: each channel a sum of Gaussian bands.

    Parameters
    ----------
    components
        ``{label: [(centre_nm, fwhm_nm, peak_height), ...]}``. ``fwhm_nm``
        is the full width at half maximum (nm, > 0); ``peak_height`` the
        relative radiance at the band's centre (>= 0).
    wavelength_nm
        Grid in nm; default 380-780 nm in 1 nm steps.
    source
        Recorded in :attr:`Spectra.source`.
    """
    wl = np.arange(380.0, 781.0, 1.0) if wavelength_nm is None else np.asarray(wavelength_nm, dtype=np.float64)
    labels = tuple(components)
    values = np.zeros((wl.size, len(labels)), dtype=np.float64)
    for c, label in enumerate(labels):
        for k, (centre_nm, fwhm_nm, height) in enumerate(components[label]):
            if not (math.isfinite(centre_nm) and math.isfinite(fwhm_nm) and fwhm_nm > 0):
                raise ValidationError(f"{label}[{k}]", (centre_nm, fwhm_nm, height), "finite centre_nm and fwhm_nm > 0")
            if not (math.isfinite(height) and height >= 0):
                raise ValidationError(f"{label}[{k}].peak_height", height, "a finite value >= 0")
            sigma = fwhm_nm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
            values[:, c] += height * np.exp(-0.5 * ((wl - centre_nm) / sigma) ** 2)
    return Spectra(wl, values, labels, source)


# --------------------------------------------------------------------------
# Angular resolution
# --------------------------------------------------------------------------


def _positive_finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValidationError(name, value, "a positive finite number")
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValidationError(name, value, "a positive finite number")
    return value


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
    pitch_m = _positive_finite("pixel_pitch_mm", pixel_pitch_mm) / 1000.0
    d = _positive_finite("distance_m", distance_m)
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
    fov = _positive_finite("fov_deg", fov_deg)
    if fov >= 180.0:
        raise ValidationError("fov_deg", fov, "a field of view between 0 and 180 degrees")
    return float(pixels) / fov


# --------------------------------------------------------------------------
# DisplayProfile
# --------------------------------------------------------------------------


def _is_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))


@dataclass(frozen=True)
class Photometry:
    """How bright the display is and the light around it: what a perceptual metric needs.

    ColorVideoVDP (:func:`vrcorrect.vision.metrics.jod`) turns code values into
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
        problems = _photometry_problems(self.peak_luminance_cd_m2, self.contrast, self.ambient_lux,
                                        self.reflectivity, prefix="photometry.")
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


def _photometry_problems(peak: Any, contrast: Any, ambient: Any, reflectivity: Any,
                         prefix: str = "") -> list[Problem]:
    problems: list[Problem] = []
    for key, value, (lo, hi), unit in (
        ("peak_luminance_cd_m2", peak, PEAK_LUMINANCE_RANGE, " cd/m^2"),
        ("contrast", contrast, CONTRAST_RANGE, " (peak : black)"),
        ("ambient_lux", ambient, AMBIENT_LUX_RANGE, " lux"),
        ("reflectivity", reflectivity, REFLECTIVITY_RANGE, ""),
    ):
        if not _is_number(value) or not (lo <= float(value) <= hi):
            problems.append(Problem(prefix + key, value, f"a number from {lo:g} to {hi:g}{unit}"))
    return problems


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
) -> list[Problem]:
    """Every problem with the fields of a :class:`DisplayProfile` (empty when valid)."""
    problems: list[Problem] = []
    if not isinstance(name, str) or not name.strip():
        problems.append(Problem("name", name, "a non-empty string"))
    if not isinstance(title, str):
        problems.append(Problem("title", title, "a string"))
    if kind not in KINDS:
        problems.append(Problem("kind", kind, "one of: " + ", ".join(KINDS)))
    if not isinstance(primaries, Spectra):
        problems.append(Problem("primaries", type(primaries).__name__, "a Spectra object"))
    elif primaries.labels != RGB_LABELS:
        problems.append(Problem("primaries.labels", primaries.labels, "('red', 'green', 'blue')"))
    elif np.any(primaries.values.max(axis=0) <= 0):
        problems.append(Problem("primaries.values", "a channel that is zero everywhere", "each primary emitting somewhere"))
    lo, hi = PPD_RANGE
    if not _is_number(pixels_per_degree) or not (lo <= float(pixels_per_degree) <= hi):
        problems.append(Problem("pixels_per_degree", pixels_per_degree, f"a number from {lo:g} to {hi:g}"))
    if not _is_number(distance_m) or math.isnan(float(distance_m)) or not float(distance_m) > 0:
        problems.append(Problem("distance_m", distance_m, "a distance > 0 m (inf for a collimated image)"))
    if transfer not in TRANSFERS:
        problems.append(Problem("transfer", transfer, "one of: " + ", ".join(TRANSFERS)))
    if resolution_px is not None:
        ok = (
            isinstance(resolution_px, (tuple, list))
            and len(resolution_px) == 2
            and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in resolution_px)
        )
        if not ok:
            problems.append(Problem("resolution_px", resolution_px, "[width, height] in pixels, positive integers"))
    if not isinstance(sources, str):
        problems.append(Problem("sources", sources, "a string"))
    if photometry is not None and not isinstance(photometry, Photometry):
        problems.append(Problem("photometry", type(photometry).__name__, "a Photometry object or None"))
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


# --------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------

# LCD proxy and parametric OLED proxy (see data/displays.md).
_LCD_PROXY = "Apple Studio Display"
_CRT_TABLE = "Typical CRT Brainard 1997"
#: Parametric OLED proxy: (centre_nm, fwhm_nm, peak height) per primary. Estimate.
OLED_PROXY_BANDS: dict[str, tuple[tuple[float, float, float], ...]] = {
    "red": ((620.0, 35.0, 1.0),),
    "green": ((530.0, 35.0, 1.0),),
    "blue": ((460.0, 25.0, 1.0),),
}

_PRESET_ORDER: tuple[str, ...] = ("desktop", "crt", "quest2", "quest3", "index", "vivepro")

# Geometry of each preset (the numbers are explained in data/displays.md).
_DESKTOP_PITCH_MM, _DESKTOP_DISTANCE_M = 0.2331, 0.60
_CRT_PITCH_MM, _CRT_DISTANCE_M = 0.28, 0.60
_QUEST2_PX, _QUEST2_FOV_DEG = (1832, 1920), 97.0
_QUEST3_PX, _QUEST3_PPD = (2064, 2208), 25.0
_INDEX_PX, _INDEX_FOV_DEG = (1440, 1600), 108.0
_VIVEPRO_PX, _VIVEPRO_FOV_DEG = (1440, 1600), 110.0


#: Preset photometry (see data/displays.md). Office monitor: ColorVideoVDP's 'standard_fhd' figures.
_MONITOR_PHOTOMETRY = Photometry(
    200.0, 1000.0, 250.0, sources=(
        "Peak 200 cd/m^2 and 250 lux ambient: estimate, a typical office SDR monitor as in "
        "ColorVideoVDP's 'standard_fhd' display (Mantiuk et al. 2024). Contrast 1000:1: estimate, the static "
        "contrast commonly specified for IPS LCD panels. Reflectivity 0.005: ColorVideoVDP's default."))
#: CRT: the sRGB reference viewing conditions (IEC 61966-2-1:1999), which were set around CRTs.
_CRT_PHOTOMETRY = Photometry(
    80.0, 1000.0, 64.0, sources=(
        "Peak 80 cd/m^2 and 64 lux ambient: the sRGB reference display and viewing environment "
        "(IEC 61966-2-1:1999). Contrast 1000:1: estimate. Reflectivity 0.005: ColorVideoVDP's default."))
#: LCD headsets: about 100 cd/m^2 in the dark (ColorVideoVDP's 'standard_hmd').
_LCD_HEADSET_PHOTOMETRY = Photometry(
    100.0, 1000.0, 0.0, sources=(
        "Peak 100 cd/m^2: estimate, as ColorVideoVDP's 'standard_hmd' display (Mantiuk et al. 2024); no "
        "measured figure for this headset. Contrast 1000:1: estimate for an LCD panel (standard_hmd's black "
        "of 0.1 cd/m^2). Ambient 0 lux: the headset shuts out room light."))
#: OLED headset: pixels switch off; the contrast is an estimate limited by stray light in the lenses.
_OLED_HEADSET_PHOTOMETRY = Photometry(
    100.0, 100000.0, 0.0, sources=(
        "Peak 100 cd/m^2: estimate, as ColorVideoVDP's 'standard_hmd' display. Contrast 100000:1: estimate "
        "for an AMOLED panel whose pixels switch off (stray light in the lenses, not the panel, limits it). "
        "Ambient 0 lux: the headset shuts out room light."))


@functools.lru_cache(maxsize=None)
def _colour_primaries(table: str) -> Spectra:
    """Primaries from colour-science's ``MSDS_DISPLAY_PRIMARIES`` (loaded lazily)."""
    import colour  # slow import: keep it inside

    msds = colour.MSDS_DISPLAY_PRIMARIES[table]
    labels = tuple(str(x).lower() for x in msds.labels)
    if labels != RGB_LABELS:  # pragma: no cover - guards against a changed table
        raise InputError(f"colour-science table {table!r} has labels {labels}, expected {RGB_LABELS}")
    return Spectra(
        np.asarray(msds.wavelengths, dtype=np.float64),
        np.asarray(msds.values, dtype=np.float64),
        labels,
        f"colour-science {colour.__version__}: colour.MSDS_DISPLAY_PRIMARIES[{table!r}]",
    )


def _oled_proxy() -> Spectra:
    bands = "; ".join(
        f"{label} {c:g} nm FWHM {w:g} nm" for label, ((c, w, _h),) in OLED_PROXY_BANDS.items()
    )
    return gaussian_spectra(
        OLED_PROXY_BANDS,
        source=f"estimate: parametric OLED proxy, one Gaussian per primary ({bands}), equal peak heights",
    )


def _build_preset(key: str) -> DisplayProfile:
    if key == "desktop":
        ppd = ppd_from_pitch(_DESKTOP_PITCH_MM, _DESKTOP_DISTANCE_M)
        return DisplayProfile(
            name="desktop",
            title="Desktop LCD monitor (27-inch, 2560x1440)",
            kind="monitor",
            primaries=_colour_primaries(_LCD_PROXY),
            pixels_per_degree=ppd,
            distance_m=_DESKTOP_DISTANCE_M,
            transfer="srgb",
            resolution_px=(2560, 1440),
            sources=(
                "Primaries: colour-science MSDS_DISPLAY_PRIMARIES['Apple Studio Display'] (flat-panel LCD, "
                "Fairchild & Wyble 1998). Geometry: 27-inch 2560x1440 panel, pixel pitch 0.2331 mm (nominal "
                f"figure for this panel class), viewed at 0.60 m (assumed typical desk distance) -> "
                f"{ppd:.2f} ppd by ppd_from_pitch. Transfer: sRGB (assumed)."
            ),
            photometry=_MONITOR_PHOTOMETRY,
        )
    if key == "crt":
        ppd = ppd_from_pitch(_CRT_PITCH_MM, _CRT_DISTANCE_M)
        return DisplayProfile(
            name="crt",
            title="Typical CRT monitor (Brainard 1997 primaries)",
            kind="monitor",
            primaries=_colour_primaries(_CRT_TABLE),
            pixels_per_degree=ppd,
            distance_m=_CRT_DISTANCE_M,
            transfer="gamma2.2",
            resolution_px=None,
            sources=(
                "Primaries: colour-science MSDS_DISPLAY_PRIMARIES['Typical CRT Brainard 1997'] (as collected "
                "by Machado 2010). Geometry: estimate, 0.28 mm dot pitch viewed at 0.60 m -> "
                f"{ppd:.2f} ppd by ppd_from_pitch. Transfer: estimate, pure 2.2 power law."
            ),
            photometry=_CRT_PHOTOMETRY,
        )
    if key == "quest2":
        ppd = ppd_from_fov(_QUEST2_PX[0], _QUEST2_FOV_DEG)
        return DisplayProfile(
            name="quest2",
            title="Meta Quest 2",
            kind="headset",
            primaries=_colour_primaries(_LCD_PROXY),
            pixels_per_degree=ppd,
            distance_m=1.3,
            transfer="srgb",
            resolution_px=_QUEST2_PX,
            sources=(
                "Panel: LCD, 1832x1920 per eye (Meta specification). Pixels per degree: estimate, "
                f"1832 px over a per-eye horizontal field of view of about {_QUEST2_FOV_DEG:g} deg (estimate; "
                f"Meta publishes no per-eye figure) -> {ppd:.2f} ppd by ppd_from_fov (mean across the view; "
                "the centre is likely somewhat denser). Virtual-image distance: estimate, 1.3 m (figure "
                "repeated in secondary sources, not verified against a Meta document). Spectra: proxy, the "
                "colour-science 'Apple Studio Display' LCD primaries (no measured Quest 2 spectra available). "
                "Transfer: sRGB (assumed)."
            ),
            photometry=_LCD_HEADSET_PHOTOMETRY,
        )
    if key == "quest3":
        ppd_mean = ppd_from_fov(_QUEST3_PX[0], 110.0)
        return DisplayProfile(
            name="quest3",
            title="Meta Quest 3",
            kind="headset",
            primaries=_colour_primaries(_LCD_PROXY),
            pixels_per_degree=_QUEST3_PPD,
            distance_m=1.3,
            transfer="srgb",
            resolution_px=_QUEST3_PX,
            sources=(
                "Panel: LCD, 2064x2208 per eye, pancake lenses (Meta specification). Pixels per degree: 25 "
                "at the centre, as stated by Meta for Quest 3 (not verified here against a primary Meta page; for comparison 2064 px over Meta's claimed "
                f"110 deg horizontal field of view gives a mean of {ppd_mean:.1f} ppd by ppd_from_fov). "
                "Virtual-image distance: estimate, 1.3 m (assumed equal to the Quest 2 figure; not verified). "
                "Spectra: proxy, the colour-science 'Apple Studio Display' LCD primaries (no measured Quest 3 "
                "spectra available). Transfer: sRGB (assumed)."
            ),
            photometry=_LCD_HEADSET_PHOTOMETRY,
        )
    if key == "index":
        ppd = ppd_from_fov(_INDEX_PX[0], _INDEX_FOV_DEG)
        return DisplayProfile(
            name="index",
            title="Valve Index",
            kind="headset",
            primaries=_colour_primaries(_LCD_PROXY),
            pixels_per_degree=ppd,
            distance_m=2.0,
            transfer="srgb",
            resolution_px=_INDEX_PX,
            sources=(
                "Panel: LCD with full RGB sub-pixels, 1440x1600 per eye (Valve specification as reported in "
                "secondary sources; the Index is LCD, not OLED). Pixels per degree: estimate, 1440 px over a per-eye horizontal field of view "
                f"of about {_INDEX_FOV_DEG:g} deg (estimate; the Index's field of view depends on the "
                f"eye-relief setting) -> {ppd:.2f} ppd by ppd_from_fov. Virtual-image distance: "
                "estimate, 2.0 m. Spectra: proxy, the colour-science 'Apple Studio Display' LCD primaries "
                "(no measured Index spectra available). Transfer: sRGB (assumed)."
            ),
            photometry=_LCD_HEADSET_PHOTOMETRY,
        )
    if key == "vivepro":
        ppd = ppd_from_fov(_VIVEPRO_PX[0], _VIVEPRO_FOV_DEG)
        return DisplayProfile(
            name="vivepro",
            title="HTC Vive Pro (OLED)",
            kind="headset",
            primaries=_oled_proxy(),
            pixels_per_degree=ppd,
            distance_m=2.0,
            transfer="srgb",
            resolution_px=_VIVEPRO_PX,
            sources=(
                "Panel: AMOLED, 1440x1600 per eye (HTC specification as widely reported; not verified here). Pixels per degree: estimate, 1440 px "
                f"over {_VIVEPRO_FOV_DEG:g} deg (HTC's advertised field of view, taken as the per-eye "
                f"horizontal one; estimate) -> {ppd:.2f} ppd by ppd_from_fov. Virtual-image distance: "
                "estimate, 2.0 m. Spectra: estimate, parametric OLED proxy (one Gaussian per primary: red "
                "620 nm, green 530 nm, blue 460 nm; FWHM 35, 35, 25 nm; equal peak heights), not a "
                "measurement. Transfer: sRGB (assumed)."
            ),
            photometry=_OLED_HEADSET_PHOTOMETRY,
        )
    raise KeyError(key)  # pragma: no cover - callers check the key


@functools.lru_cache(maxsize=None)
def _preset(key: str) -> DisplayProfile:
    return _build_preset(key)


def preset_names() -> tuple[str, ...]:
    """Keys of the built-in display presets, in a fixed order."""
    return _PRESET_ORDER


def _unknown_display_allowed() -> str:
    return "one of: " + ", ".join(_PRESET_ORDER) + " or a path to a .json display profile"


def get_display(name_or_path: str | os.PathLike[str]) -> DisplayProfile:
    """A display profile by preset key (case-insensitive) or JSON file path.

    Parameters
    ----------
    name_or_path
        A key from :func:`preset_names`, or the path of a display profile
        JSON document (see :func:`load_display_profile`).

    Raises
    ------
    ValidationError
        ``field="display"`` when the name is neither a preset nor a path to
        a ``.json`` file; the message lists the presets.
    InputError, ValidationErrors
        From :func:`load_display_profile`.
    """
    if isinstance(name_or_path, os.PathLike):
        return load_display_profile(Path(name_or_path))
    if not isinstance(name_or_path, str):
        raise ValidationError("display", name_or_path, _unknown_display_allowed())
    key = name_or_path.strip().lower()
    if key in _PRESET_ORDER:
        return _preset(key)
    path = Path(name_or_path)
    if path.suffix.lower() == ".json" or path.is_file():
        return load_display_profile(path)
    raise ValidationError("display", name_or_path, _unknown_display_allowed())


# --------------------------------------------------------------------------
# Spectra CSV
# --------------------------------------------------------------------------


def _read_text(path: Path, what: str) -> str:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a {what}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: {what} is not UTF-8 text (byte {exc.start})") from None


def read_spectra_csv(path: str | os.PathLike[str]) -> Spectra:
    """Read display primaries measured with a spectroradiometer.

    Format: UTF-8 text; blank lines and lines starting with ``#`` (comments,
    e.g. the data's source) are ignored; the first other line is the header
    ``wavelength_nm,r,g,b`` (case-insensitive, spaces allowed around
    fields); then one row per wavelength: wavelength in nm and the relative
    radiance of the red, green and blue primaries.

    Rules: exactly 4 columns; numbers only; finite; radiance ``>= 0``;
    wavelengths strictly increasing (no duplicates) within 300-1000 nm; at
    least 5 rows.

    Returns
    -------
    Spectra
        Labels ``("red", "green", "blue")``, source the file path.

    Raises
    ------
    InputError
        Unreadable or malformed file; the message names the file and the
        line number (1-based) of the first problem.
    """
    path = Path(path)
    text = _read_text(path, "spectra CSV")
    reader = csv.reader(io.StringIO(text, newline=""))
    lo, hi = CSV_WAVELENGTH_RANGE_NM
    header_seen = False
    rows: list[tuple[float, float, float, float]] = []
    last_line = 0

    def fail(line: int, message: str) -> InputError:
        return InputError(f"{path}: line {line}: {message}")

    try:
        for fields in reader:
            line = reader.line_num
            last_line = line
            cells = [f.strip() for f in fields]
            if not cells or all(c == "" for c in cells) or cells[0].startswith("#"):
                continue
            if not header_seen:
                if [c.lower() for c in cells] != ["wavelength_nm", "r", "g", "b"]:
                    raise fail(line, f"header is {','.join(fields)!r}; expected 'wavelength_nm,r,g,b'")
                header_seen = True
                continue
            if len(cells) != 4:
                raise fail(line, f"{len(cells)} columns; expected 4 (wavelength_nm,r,g,b)")
            numbers = []
            for name, cell in zip(("wavelength_nm", "r", "g", "b"), cells):
                try:
                    value = float(cell)
                except ValueError:
                    raise fail(line, f"{name} = {cell!r} is not a number") from None
                if not math.isfinite(value):
                    raise fail(line, f"{name} = {cell!r} is not finite")
                numbers.append(value)
            wl = numbers[0]
            if not (lo <= wl <= hi):
                raise fail(line, f"wavelength_nm = {wl:g} is outside {lo:g}-{hi:g} nm")
            for name, value in zip(("r", "g", "b"), numbers[1:]):
                if value < 0:
                    raise fail(line, f"{name} = {value:g} is negative; radiance must be >= 0")
            if rows and wl <= rows[-1][0]:
                what = "repeats" if wl == rows[-1][0] else "is below"
                raise fail(line, f"wavelength_nm = {wl:g} {what} the previous {rows[-1][0]:g}; "
                                 "wavelengths must strictly increase")
            rows.append((numbers[0], numbers[1], numbers[2], numbers[3]))
    except csv.Error as exc:
        raise fail(reader.line_num, f"malformed CSV: {exc}") from None
    if not header_seen:
        raise fail(max(last_line, 1), "no header; expected 'wavelength_nm,r,g,b'")
    if len(rows) < CSV_MIN_ROWS:
        raise fail(max(last_line, 1), f"only {len(rows)} data rows; need at least {CSV_MIN_ROWS}")
    data = np.asarray(rows, dtype=np.float64)
    return Spectra(data[:, 0], data[:, 1:], RGB_LABELS, str(path))


# --------------------------------------------------------------------------
# Display profile JSON
# --------------------------------------------------------------------------

_PROFILE_KEYS = frozenset({
    "schema", "name", "title", "kind", "spectra_csv", "preset_primaries", "pixels_per_degree",
    "pixel_pitch_mm", "fov_deg", "distance_m", "transfer", "resolution_px", "sources",
    "peak_luminance_cd_m2", "contrast", "ambient_lux", "reflectivity",
})
#: The profile keys of :class:`Photometry`; each is optional (default: :func:`default_photometry`).
_PHOTOMETRY_KEYS = ("peak_luminance_cd_m2", "contrast", "ambient_lux", "reflectivity")


def _number_field(doc: Mapping[str, Any], key: str, problems: list[Problem], allowed: str,
                  ok: Any) -> float | None:
    value = doc[key]
    if not _is_number(value) or not ok(float(value)):
        problems.append(Problem(key, value, allowed))
        return None
    return float(value)


def load_display_profile(path: str | os.PathLike[str]) -> DisplayProfile:
    """Read a display profile JSON document.

    Keys (unknown keys are rejected):

    - ``schema``: ``"vrcorrect.display/1"`` (required)
    - ``name`` (required), ``title`` (default: the name), ``sources``
    - ``kind``: ``"monitor"`` or ``"headset"`` (required)
    - primaries, exactly one of ``spectra_csv`` (path, relative to the JSON
      file's folder, of a file :func:`read_spectra_csv` accepts) or
      ``preset_primaries`` (a preset key whose primaries to reuse)
    - angular resolution, exactly one of: ``pixels_per_degree``; for a
      monitor ``pixel_pitch_mm`` (with ``distance_m``, via
      :func:`ppd_from_pitch`); for a headset ``resolution_px`` and
      ``fov_deg`` (per-eye horizontal field of view, via
      :func:`ppd_from_fov`)
    - ``distance_m`` (required): metres > 0, or ``"inf"``
    - ``transfer``: ``"srgb"`` (default), ``"gamma2.2"`` or ``"linear"``
    - ``resolution_px``: ``[width, height]``
    - photometry, each optional (default: :func:`default_photometry` of the
      kind, an estimate): ``peak_luminance_cd_m2``, ``contrast`` (peak :
      black), ``ambient_lux``, ``reflectivity``

    Raises
    ------
    InputError
        The file cannot be read or is not a JSON object.
    ValidationErrors
        Every problem in the document at once, each naming the field, the
        value and what is allowed (a malformed spectra CSV is one problem
        with its file and line).
    """
    path = Path(path)
    text = _read_text(path, "display profile")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON at {json_error_location(exc)}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object, found {type(doc).__name__}")

    problems: list[Problem] = []
    for key in sorted(set(doc) - _PROFILE_KEYS):
        problems.append(Problem(key, doc[key], "no such key; allowed keys: " + ", ".join(sorted(_PROFILE_KEYS))))

    if doc.get("schema") != PROFILE_SCHEMA:
        problems.append(Problem("schema", doc.get("schema"), repr(PROFILE_SCHEMA)))

    name = doc.get("name")
    if not isinstance(name, str) or not name.strip():
        problems.append(Problem("name", name, "a non-empty string"))
    title = doc.get("title", name if isinstance(name, str) else "")
    if not isinstance(title, str):
        problems.append(Problem("title", title, "a string"))
    sources = doc.get("sources", "")
    if not isinstance(sources, str):
        problems.append(Problem("sources", sources, "a string"))
    kind = doc.get("kind")
    if kind not in KINDS:
        problems.append(Problem("kind", kind, "one of: " + ", ".join(KINDS)))
    transfer = doc.get("transfer", "srgb")
    if transfer not in TRANSFERS:
        problems.append(Problem("transfer", transfer, "one of: " + ", ".join(TRANSFERS)))

    # primaries
    primaries: Spectra | None = None
    has_csv, has_preset = "spectra_csv" in doc, "preset_primaries" in doc
    if has_csv == has_preset:
        problems.append(Problem(
            "spectra_csv", doc.get("spectra_csv"),
            "exactly one of spectra_csv (a CSV path) or preset_primaries (a preset key)",
        ))
    elif has_csv:
        csv_value = doc["spectra_csv"]
        if not isinstance(csv_value, str) or not csv_value.strip():
            problems.append(Problem("spectra_csv", csv_value, "a path to a spectra CSV file"))
        else:
            csv_path = Path(csv_value)
            if not csv_path.is_absolute():
                csv_path = path.parent / csv_path
            try:
                primaries = read_spectra_csv(csv_path)
            except InputError as exc:
                problems.append(Problem("spectra_csv", csv_value, f"a readable spectra CSV ({exc})"))
    else:
        key = doc["preset_primaries"]
        if not isinstance(key, str) or key.strip().lower() not in _PRESET_ORDER:
            problems.append(Problem("preset_primaries", key, "one of: " + ", ".join(_PRESET_ORDER)))
        else:
            primaries = _preset(key.strip().lower()).primaries

    # distance
    distance: float | None = None
    if "distance_m" not in doc:
        problems.append(Problem("distance_m", None, "a distance > 0 m, or \"inf\" (required)"))
    else:
        raw = doc["distance_m"]
        if isinstance(raw, str) and raw.strip().lower() in ("inf", "infinity"):
            distance = math.inf
        elif _is_number(raw) and float(raw) > 0 and not math.isnan(float(raw)):
            distance = float(raw)
        else:
            problems.append(Problem("distance_m", raw, "a distance > 0 m, or \"inf\""))

    # resolution
    resolution: tuple[int, int] | None = None
    if "resolution_px" in doc:
        raw = doc["resolution_px"]
        if (isinstance(raw, list) and len(raw) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in raw)):
            resolution = (raw[0], raw[1])
        else:
            problems.append(Problem("resolution_px", raw, "[width, height] in pixels, positive integers"))

    # angular resolution
    ppd: float | None = None
    lo, hi = PPD_RANGE
    ways = [k for k in ("pixels_per_degree", "pixel_pitch_mm", "fov_deg") if k in doc]
    ppd_allowed = ("pixels_per_degree, or pixel_pitch_mm with distance_m (monitor), "
                   "or resolution_px with fov_deg (headset)")
    if len(ways) != 1:
        problems.append(Problem(
            "pixels_per_degree", {k: doc[k] for k in ways} if ways else None, f"exactly one of: {ppd_allowed}",
        ))
    elif ways[0] == "pixels_per_degree":
        ppd = _number_field(doc, "pixels_per_degree", problems, f"a number from {lo:g} to {hi:g}",
                            lambda v: lo <= v <= hi)
    elif ways[0] == "pixel_pitch_mm":
        pitch = _number_field(doc, "pixel_pitch_mm", problems, "a pixel pitch > 0 mm",
                              lambda v: math.isfinite(v) and v > 0)
        if kind == "headset":
            problems.append(Problem("pixel_pitch_mm", doc["pixel_pitch_mm"],
                                    "not for a headset: give pixels_per_degree or resolution_px with fov_deg"))
        elif pitch is not None and distance is not None:
            if math.isinf(distance):
                problems.append(Problem("distance_m", "inf", "a finite distance when pixel_pitch_mm is given"))
            else:
                ppd = ppd_from_pitch(pitch, distance)
    else:  # fov_deg
        fov = _number_field(doc, "fov_deg", problems, "a per-eye field of view between 0 and 180 degrees",
                            lambda v: 0 < v < 180)
        if kind == "monitor":
            problems.append(Problem("fov_deg", doc["fov_deg"],
                                    "not for a monitor: give pixels_per_degree or pixel_pitch_mm"))
        elif "resolution_px" not in doc:
            problems.append(Problem("resolution_px", None, "[width, height] per eye, required with fov_deg"))
        elif fov is not None and resolution is not None:
            ppd = ppd_from_fov(resolution[0], fov)
    if ppd is not None and not (lo <= ppd <= hi):
        problems.append(Problem("pixels_per_degree", round(ppd, 3),
                                f"a computed pixel density from {lo:g} to {hi:g} per degree"))
        ppd = None

    # photometry: what the profile states, the kind's default for the rest
    photometry: Photometry | None = None
    if kind in KINDS:
        base = default_photometry(kind)
        values = {k: doc.get(k, getattr(base, k)) for k in _PHOTOMETRY_KEYS}
        photo_problems = _photometry_problems(*(values[k] for k in _PHOTOMETRY_KEYS))
        problems.extend(photo_problems)
        if not photo_problems:
            given = [k for k in _PHOTOMETRY_KEYS if k in doc]
            note = ("from the profile: " + ", ".join(given) + "; the rest " if given else "") + base.sources
            photometry = Photometry(**{k: float(values[k]) for k in _PHOTOMETRY_KEYS}, sources=note)

    if problems:
        raise ValidationErrors(problems, source=str(path))
    try:
        return DisplayProfile(
            name=name, title=title, kind=kind, primaries=primaries,  # type: ignore[arg-type]
            pixels_per_degree=ppd, distance_m=distance,  # type: ignore[arg-type]
            transfer=transfer, resolution_px=resolution, sources=sources, photometry=photometry,
        )
    except ValidationError as exc:  # e.g. primaries with a dead channel
        raise ValidationErrors([Problem(exc.field, exc.value, exc.allowed)], source=str(path)) from None


# --------------------------------------------------------------------------
# Smooth proxy fit of measured spectra
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SpectraFit:
    """Result of :func:`fit_spectra`.

    Attributes
    ----------
    spectra
        The smooth non-negative proxy on a 1 nm grid covering the measured
        range (same labels as the measurement).
    rms_error, max_error
        Per channel, the RMS and the largest absolute difference between
        proxy and measurement at the measured wavelengths, as a fraction of
        that channel's measured peak.
    """

    spectra: Spectra
    rms_error: tuple[float, ...]
    max_error: tuple[float, ...]


def _gaussian_dictionary(wl: np.ndarray, centres: np.ndarray, sigmas: Sequence[float]) -> np.ndarray:
    cols = [np.exp(-0.5 * ((wl[:, None] - centres[None, :]) / s) ** 2) for s in sigmas]
    return np.concatenate(cols, axis=1)


def fit_spectra(measured: Spectra, *, min_sigma_nm: float | None = None,
                regularisation: float = 1e-4) -> SpectraFit:
    """Fit a smooth, non-negative proxy to measured spectra.

    Each channel is approximated by a non-negative combination of Gaussian
    bands (centres every ``s0`` nm across the measured range, widths
    ``sigma = s0, 2·s0, 4·s0, 8·s0, 16·s0``) found by non-negative least
    squares (:func:`scipy.optimize.nnls`) with a small ridge penalty. The
    proxy is therefore smooth (no band narrower than ``s0``) and
    non-negative by construction, and the fit is deterministic.

    Parameters
    ----------
    measured
        Measured spectra (any number of channels, at least 5 samples).
    min_sigma_nm
        Narrowest band ``s0`` (standard deviation, nm). Default:
        ``max(3 nm, median sample spacing)``: the data cannot resolve
        features finer than their sampling.
    regularisation
        Ridge weight relative to the mean squared column norm of the band
        dictionary (damps noise fitting; 0 disables it).

    Returns
    -------
    SpectraFit
        Proxy on a 1 nm grid from ``ceil(min)`` to ``floor(max)`` of the
        measured wavelengths, and the fit errors per channel.
    """
    from scipy.optimize import nnls

    if not isinstance(measured, Spectra):
        raise ValidationError("measured", type(measured).__name__, "a Spectra object")
    wl = measured.wavelength_nm
    if wl.size < CSV_MIN_ROWS:
        raise ValidationError("measured.wavelength_nm", f"{wl.size} samples", f"at least {CSV_MIN_ROWS} samples")
    step = float(np.median(np.diff(wl)))
    s0 = max(3.0, step) if min_sigma_nm is None else _positive_finite("min_sigma_nm", min_sigma_nm)
    if not (math.isfinite(regularisation) and regularisation >= 0):
        raise ValidationError("regularisation", regularisation, "a finite number >= 0")
    span = float(wl[-1] - wl[0])
    sigmas = [s0 * 2.0**k for k in range(5) if s0 * 2.0**k <= max(span, s0)]
    n_centres = int(math.ceil(span / s0)) + 1
    centres = np.linspace(wl[0], wl[-1], n_centres)
    design = _gaussian_dictionary(wl, centres, sigmas)  # (n, k)
    k = design.shape[1]
    ridge = math.sqrt(regularisation * float(np.mean(np.sum(design**2, axis=0))))
    system = np.vstack([design, ridge * np.eye(k)]) if ridge > 0 else design

    grid = np.arange(math.ceil(wl[0]), math.floor(wl[-1]) + 1, 1.0)
    if grid.size < 2:  # measured range spans less than 1 nm: use its end points
        grid = np.array([wl[0], wl[-1]])
    basis_grid = _gaussian_dictionary(grid, centres, sigmas)

    out = np.zeros((grid.size, measured.n_channels), dtype=np.float64)
    rms, mx = [], []
    for c in range(measured.n_channels):
        y = measured.values[:, c]
        peak = float(y.max())
        if peak <= 0:
            rms.append(0.0)
            mx.append(0.0)
            continue
        target = y / peak
        rhs = np.concatenate([target, np.zeros(k)]) if ridge > 0 else target
        try:
            coef, _ = nnls(system, rhs, maxiter=50 * k)
        except RuntimeError:  # pragma: no cover - iteration limit; fall back to a bounded solver
            from scipy.optimize import lsq_linear

            coef = np.clip(lsq_linear(system, rhs, bounds=(0.0, np.inf), method="bvls").x, 0.0, None)
        out[:, c] = np.clip(basis_grid @ coef, 0.0, None) * peak
        resid = (design @ coef) - target
        rms.append(float(np.sqrt(np.mean(resid**2))))
        mx.append(float(np.max(np.abs(resid))))
    source = f"smooth proxy (non-negative Gaussian fit, s0 = {s0:g} nm) of {measured.source}"
    return SpectraFit(Spectra(grid, out, measured.labels, source), tuple(rms), tuple(mx))


# --------------------------------------------------------------------------
# Transfer functions
# --------------------------------------------------------------------------


def _as_float_array(v: Any) -> tuple[np.ndarray, np.dtype | None]:
    """Input as a float array; returns (work array, dtype to cast back to or None)."""
    arr = np.asarray(v)
    if arr.dtype.kind in "iub":
        if arr.dtype.kind == "b" or isinstance(v, (np.ndarray, np.generic)):
            raise ValidationError(
                "v", f"array of dtype {arr.dtype}", "floating-point code values in [0, 1] (divide 8-bit codes by 255)"
            )
        arr = arr.astype(np.float64)  # Python ints / lists of ints: 0 and 1 are valid code values
    elif arr.dtype.kind != "f":
        try:
            arr = arr.astype(np.float64)
        except (TypeError, ValueError):
            raise ValidationError("v", f"array of dtype {arr.dtype}", "floating-point values in [0, 1]") from None
    if arr.dtype == np.float16:
        return arr.astype(np.float32), np.dtype(np.float16)
    return arr, None


def _finish(out: np.ndarray, cast: np.dtype | None) -> np.ndarray:
    return out.astype(cast) if cast is not None else out


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """sRGB code values -> linear light (IEC 61966-2-1 piecewise curve).

    ``v / 12.92`` for ``v <= 0.04045``, else ``((v + 0.055) / 1.055) ** 2.4``.
    Input is clipped to [0, 1] first; NaN stays NaN. The result has the
    input's floating dtype (float32 in, float32 out).
    """
    arr, cast = _as_float_array(v)
    x = np.clip(arr, 0.0, 1.0)
    with np.errstate(invalid="ignore"):
        out = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return _finish(out.astype(x.dtype, copy=False), cast)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """Linear light -> sRGB code values (inverse of :func:`srgb_to_linear`).

    ``12.92·v`` for ``v <= 0.0031308``, else ``1.055·v**(1/2.4) - 0.055``.
    Input clipped to [0, 1] first; NaN stays NaN; dtype follows the input.
    """
    arr, cast = _as_float_array(v)
    x = np.clip(arr, 0.0, 1.0)
    with np.errstate(invalid="ignore"):
        out = np.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1.0 / 2.4) - 0.055)
    return _finish(out.astype(x.dtype, copy=False), cast)


def _transfer_name(profile_or_transfer: DisplayProfile | str) -> str:
    if isinstance(profile_or_transfer, DisplayProfile):
        return profile_or_transfer.transfer
    if isinstance(profile_or_transfer, str) and profile_or_transfer.strip().lower() in TRANSFERS:
        return profile_or_transfer.strip().lower()
    raise ValidationError("transfer", profile_or_transfer, "a DisplayProfile or one of: " + ", ".join(TRANSFERS))


def decode(profile_or_transfer: DisplayProfile | str, v: np.ndarray) -> np.ndarray:
    """Display code values in [0, 1] -> linear light, by the transfer function.

    ``"srgb"``: :func:`srgb_to_linear`; ``"gamma2.2"``: ``v ** 2.2``;
    ``"linear"``: identity. Clips to [0, 1]; NaN stays NaN; dtype follows
    the input.
    """
    name = _transfer_name(profile_or_transfer)
    if name == "srgb":
        return srgb_to_linear(v)
    arr, cast = _as_float_array(v)
    x = np.clip(arr, 0.0, 1.0)
    if name == "gamma2.2":
        x = x**2.2
    return _finish(x.astype(arr.dtype, copy=False), cast)


def encode(profile_or_transfer: DisplayProfile | str, v: np.ndarray) -> np.ndarray:
    """Linear light in [0, 1] -> display code values (inverse of :func:`decode`)."""
    name = _transfer_name(profile_or_transfer)
    if name == "srgb":
        return linear_to_srgb(v)
    arr, cast = _as_float_array(v)
    x = np.clip(arr, 0.0, 1.0)
    if name == "gamma2.2":
        x = x ** (1.0 / 2.2)
    return _finish(x.astype(arr.dtype, copy=False), cast)
