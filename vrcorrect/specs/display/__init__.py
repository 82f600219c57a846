"""Display profiles: emission spectra, angular resolution, viewing distance,
transfer functions and photometry.

Layer 1 (plain, validated data). The package is four modules; every name is
also importable from here:

- :mod:`.spectra`: :class:`Spectra`, :func:`gaussian_spectra`, the spectra
  CSV (:func:`read_spectra_csv`) and the smooth proxy fit (:func:`fit_spectra`).
- :mod:`.profile`: :class:`DisplayProfile`, :class:`Photometry`, pixels per
  degree from geometry (:func:`ppd_from_pitch`, :func:`ppd_from_fov`).
- :mod:`.transfer`: code values <-> linear light (:func:`decode`,
  :func:`encode`, :func:`srgb_to_linear`, :func:`linear_to_srgb`).
- :mod:`.profile_files`: the display profile JSON loader
  (:func:`load_display_profile`) and the built-in presets
  (:func:`preset_names`, :func:`get_display`), which are profile files under
  ``vrcorrect/data/displays/`` read by that same loader.

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

The presets and the sources of every number are in their files,
``vrcorrect/data/displays/<key>.json``, and explained in
``vrcorrect/data/displays.md``.
"""

from __future__ import annotations

from typing import Any

from . import profile_files

# Importable from here as from the single module this package once was, though not in __all__:
# ranges, defaults and labels.
from .profile import (  # noqa: F401
    AMBIENT_LUX_RANGE,
    CONTRAST_RANGE,
    DEFAULT_PHOTOMETRY,
    KINDS,
    PEAK_LUMINANCE_RANGE,
    PPD_RANGE,
    PROFILE_SCHEMA,
    REFLECTIVITY_RANGE,
    TRANSFERS,
    DisplayProfile,
    Photometry,
    default_photometry,
    ppd_from_fov,
    ppd_from_pitch,
)
from .profile_files import get_display, load_display_profile, preset_names
from .spectra import (  # noqa: F401
    CSV_MIN_ROWS,
    CSV_WAVELENGTH_RANGE_NM,
    RGB_LABELS,
    Spectra,
    SpectraFit,
    fit_spectra,
    gaussian_spectra,
    read_spectra_csv,
)
from .transfer import decode, encode, linear_to_srgb, srgb_to_linear

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


def __getattr__(name: str) -> Any:
    """``OLED_PROXY_BANDS``, read from the ``vivepro`` preset file when first asked for."""
    if name == "OLED_PROXY_BANDS":
        return profile_files.OLED_PROXY_BANDS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
