"""Display profile files, and the built-in presets, which are such files.

A display profile is a JSON document (schema ``vrcorrect.display/1``, described in
:func:`load_display_profile` and in ``vrcorrect/data/displays.md``). The built-in presets are
profile files too, one per preset under ``vrcorrect/data/displays/``, each stating the sources
of its numbers; they are read by the same loader as a user's file, when first asked for, and
kept.
"""

from __future__ import annotations

import functools
import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ...plumbing.errors import InputError, FieldProblem, ValidationError, ValidationErrors, json_error_location
from ...plumbing.fileio import package_data
from ..validation import FileWording, Range, check_number, read_utf8_text, unknown_key_problem
from .profile import (
    KINDS,
    PHOTOMETRY_RULES,
    PPD_RANGE,
    PPD_RULE,
    PROFILE_SCHEMA,
    DisplayProfile,
    Photometry,
    check_field,
    default_photometry,
    distance_ok,
    photometry_problems,
    ppd_from_fov,
    ppd_from_pitch,
)
from .spectra import CSV_WAVELENGTH_RANGE_NM, RGB_LABELS, Spectra, gaussian_spectra, read_spectra_csv

__all__ = ["preset_names", "get_display", "load_display_profile"]

#: The built-in presets, in the order :func:`preset_names` gives; each is the profile file
#: ``vrcorrect/data/displays/<key>.json``.
_PRESET_ORDER: tuple[str, ...] = ("desktop", "crt", "quest2", "quest3", "index", "vivepro")

_PROFILE_KEYS = frozenset({
    "schema", "name", "title", "kind", "spectra_csv", "preset_primaries", "colour_primaries",
    "gaussian_primaries", "pixels_per_degree", "pixel_pitch_mm", "fov_deg", "distance_m", "transfer",
    "resolution_px", "sources", "peak_luminance_cd_m2", "contrast", "ambient_lux", "reflectivity",
    "photometry_sources",
})
#: The profile keys that give the primaries; a profile gives exactly one.
_PRIMARIES_KEYS = ("spectra_csv", "preset_primaries", "colour_primaries", "gaussian_primaries")
_PRIMARIES_ALLOWED = (
    "exactly one of spectra_csv (a CSV path), preset_primaries (a preset key), colour_primaries "
    "(a colour-science table) or gaussian_primaries (Gaussian bands)"
)
#: The keys of ``gaussian_primaries``: one list of bands per primary, and where they come from.
_GAUSSIAN_KEYS = RGB_LABELS + ("source",)
_BANDS_ALLOWED = "a non-empty list of bands [centre_nm, fwhm_nm, peak_height]"
_BAND_RULES = (
    Range(CSV_WAVELENGTH_RANGE_NM[0], CSV_WAVELENGTH_RANGE_NM[1],
          f"a centre wavelength from {CSV_WAVELENGTH_RANGE_NM[0]:g} to {CSV_WAVELENGTH_RANGE_NM[1]:g} nm"),
    Range(0.0, 1000.0, "a full width at half maximum > 0 nm, at most 1000 nm", lo_open=True),
    Range(0.0, math.inf, "a peak height >= 0 (relative radiance)"),
)

_PROFILE_FILE = FileWording(
    not_found="{path}: display profile not found",
    is_directory="{path}: is a directory, expected a display profile",
    unreadable="{path}: cannot read display profile: {reason}",
    not_utf8="{path}: display profile is not UTF-8 text (byte {offset})",
)


# --------------------------------------------------------------------------
# Primaries named by a profile
# --------------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _colour_tables() -> tuple[str, ...]:
    """The names of colour-science's ``MSDS_DISPLAY_PRIMARIES`` tables."""
    import colour  # reason: colour-science takes about a second to import; only these primaries need it

    return tuple(colour.MSDS_DISPLAY_PRIMARIES.keys())


@functools.lru_cache(maxsize=None)
def _colour_primaries(table: str) -> Spectra:
    """Primaries from colour-science's ``MSDS_DISPLAY_PRIMARIES`` (loaded lazily)."""
    import colour  # reason: as in _colour_tables

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


def _gaussian_bands(raw: Any, problems: list[FieldProblem]) -> dict[str, tuple[tuple[float, float, float], ...]] | None:
    """The bands of a ``gaussian_primaries`` object, ``{label: ((centre, fwhm, height), ...)}``, if valid."""
    field = "gaussian_primaries"
    if not isinstance(raw, dict):
        problems.append(FieldProblem(field, raw, "an object with red, green and blue: each " + _BANDS_ALLOWED
                                + ", and optionally source (a string)"))
        return None
    n_before = len(problems)
    bands: dict[str, tuple[tuple[float, float, float], ...]] = {}
    for label in RGB_LABELS:
        where = f"{field}.{label}"
        value = raw.get(label)
        if not isinstance(value, list) or not value:
            problems.append(FieldProblem(where, value, _BANDS_ALLOWED))
            continue
        out = []
        for k, band in enumerate(value):
            if not isinstance(band, list) or len(band) != 3:
                problems.append(FieldProblem(f"{where}[{k}]", band, "a band [centre_nm, fwhm_nm, peak_height]"))
                continue
            numbers = [check_number(problems, f"{where}[{k}]", v, rule) for v, rule in zip(band, _BAND_RULES)]
            if None not in numbers:
                out.append((numbers[0], numbers[1], numbers[2]))
        bands[label] = tuple(out)
    if "source" in raw and not isinstance(raw["source"], str):
        problems.append(FieldProblem(f"{field}.source", raw["source"], "a string naming where the bands come from"))
    for key in raw:
        if key not in _GAUSSIAN_KEYS:
            problems.append(unknown_key_problem(f"{field}.{key}", key, raw[key], _GAUSSIAN_KEYS))
    return bands if len(problems) == n_before else None


def _primaries(doc: Mapping[str, Any], path: Path, problems: list[FieldProblem]) -> Spectra | None:
    """The primaries a profile names (exactly one of :data:`_PRIMARIES_KEYS`), if valid."""
    given = [k for k in _PRIMARIES_KEYS if k in doc]
    if len(given) != 1:
        problems.append(FieldProblem("spectra_csv", doc.get("spectra_csv"), _PRIMARIES_ALLOWED))
        return None
    key = given[0]
    value = doc[key]
    if key == "spectra_csv":
        if not isinstance(value, str) or not value.strip():
            problems.append(FieldProblem("spectra_csv", value, "a path to a spectra CSV file"))
            return None
        csv_path = Path(value)
        if not csv_path.is_absolute():
            csv_path = path.parent / csv_path
        try:
            return read_spectra_csv(csv_path)
        except InputError as exc:
            problems.append(FieldProblem("spectra_csv", value, f"a readable spectra CSV ({exc})"))
            return None
    if key == "preset_primaries":
        if not isinstance(value, str) or value.strip().lower() not in _PRESET_ORDER:
            problems.append(FieldProblem("preset_primaries", value, "one of: " + ", ".join(_PRESET_ORDER)))
            return None
        return _preset(value.strip().lower()).primaries
    if key == "colour_primaries":
        if not isinstance(value, str) or value not in _colour_tables():
            problems.append(FieldProblem("colour_primaries", value, "one of colour-science's MSDS_DISPLAY_PRIMARIES: "
                                    + ", ".join(_colour_tables())))
            return None
        return _colour_primaries(value)
    bands = _gaussian_bands(value, problems)
    if bands is None:
        return None
    if "source" in value:
        return gaussian_spectra(bands, source=value["source"])
    return gaussian_spectra(bands)


# --------------------------------------------------------------------------
# Display profile JSON
# --------------------------------------------------------------------------


def _distance(doc: Mapping[str, Any], problems: list[FieldProblem]) -> float | None:
    if "distance_m" not in doc:
        problems.append(FieldProblem("distance_m", None, "a distance > 0 m, or \"inf\" (required)"))
        return None
    raw = doc["distance_m"]
    if isinstance(raw, str) and raw.strip().lower() in ("inf", "infinity"):
        return math.inf
    if distance_ok(raw):
        return float(raw)
    problems.append(FieldProblem("distance_m", raw, "a distance > 0 m, or \"inf\""))
    return None


def _pixels_per_degree(doc: Mapping[str, Any], kind: Any, distance: float | None,
                       resolution: tuple[int, int] | None, problems: list[FieldProblem]) -> float | None:
    """The angular resolution, from exactly one of pixels_per_degree, pixel_pitch_mm or fov_deg."""
    ppd: float | None = None
    lo, hi = PPD_RANGE
    ways = [k for k in ("pixels_per_degree", "pixel_pitch_mm", "fov_deg") if k in doc]
    ppd_allowed = ("pixels_per_degree, or pixel_pitch_mm with distance_m (monitor), "
                   "or resolution_px with fov_deg (headset)")
    if len(ways) != 1:
        problems.append(FieldProblem(
            "pixels_per_degree", {k: doc[k] for k in ways} if ways else None, f"exactly one of: {ppd_allowed}",
        ))
    elif ways[0] == "pixels_per_degree":
        ppd = check_number(problems, "pixels_per_degree", doc["pixels_per_degree"], PPD_RULE)
    elif ways[0] == "pixel_pitch_mm":
        pitch = check_number(problems, "pixel_pitch_mm", doc["pixel_pitch_mm"],
                             Range(0.0, math.inf, "a pixel pitch > 0 mm", lo_open=True))
        if kind == "headset":
            problems.append(FieldProblem("pixel_pitch_mm", doc["pixel_pitch_mm"],
                                    "not for a headset: give pixels_per_degree or resolution_px with fov_deg"))
        elif pitch is not None and distance is not None:
            if math.isinf(distance):
                problems.append(FieldProblem("distance_m", "inf", "a finite distance when pixel_pitch_mm is given"))
            else:
                ppd = ppd_from_pitch(pitch, distance)
    else:  # fov_deg
        fov = check_number(problems, "fov_deg", doc["fov_deg"],
                           Range(0.0, 180.0, "a per-eye field of view between 0 and 180 degrees",
                                 lo_open=True, hi_open=True))
        if kind == "monitor":
            problems.append(FieldProblem("fov_deg", doc["fov_deg"],
                                    "not for a monitor: give pixels_per_degree or pixel_pitch_mm"))
        elif "resolution_px" not in doc:
            problems.append(FieldProblem("resolution_px", None, "[width, height] per eye, required with fov_deg"))
        elif fov is not None and resolution is not None:
            ppd = ppd_from_fov(resolution[0], fov)
    if ppd is not None and not (lo <= ppd <= hi):
        problems.append(FieldProblem("pixels_per_degree", round(ppd, 3),
                                f"a computed pixel density from {lo:g} to {hi:g} per degree"))
        ppd = None
    return ppd


def _photometry(doc: Mapping[str, Any], kind: Any, problems: list[FieldProblem]) -> Photometry | None:
    """What the profile states, the kind's default for the rest; sources from the profile or a note."""
    given_sources = doc.get("photometry_sources")
    if "photometry_sources" in doc and not isinstance(given_sources, str):
        problems.append(FieldProblem("photometry_sources", given_sources,
                                "a string naming where the photometry figures come from"))
    if kind not in KINDS:
        return None
    base = default_photometry(kind)
    values = {k: doc.get(k, getattr(base, k)) for k in PHOTOMETRY_RULES}
    photo_problems = photometry_problems(values)
    problems.extend(photo_problems)
    if photo_problems or not isinstance(given_sources, (str, type(None))):
        return None
    if isinstance(given_sources, str):
        note = given_sources
    else:
        given = [k for k in PHOTOMETRY_RULES if k in doc]
        note = ("from the profile: " + ", ".join(given) + "; the rest " if given else "") + base.sources
    return Photometry(**{k: float(values[k]) for k in PHOTOMETRY_RULES}, sources=note)


def load_display_profile(path: str | os.PathLike[str]) -> DisplayProfile:
    """Read a display profile JSON document.

    Keys (unknown keys are rejected):

    - ``schema``: ``"vrcorrect.display/1"`` (required)
    - ``name`` (required), ``title`` (default: the name), ``sources``
    - ``kind``: ``"monitor"`` or ``"headset"`` (required)
    - primaries, exactly one of ``spectra_csv`` (path, relative to the JSON
      file's folder, of a file :func:`read_spectra_csv` accepts),
      ``preset_primaries`` (a preset key whose primaries to reuse),
      ``colour_primaries`` (the name of a table in colour-science's
      ``MSDS_DISPLAY_PRIMARIES``) or ``gaussian_primaries`` (an object
      ``{"red": [[centre_nm, fwhm_nm, peak_height], ...], "green": ...,
      "blue": ..., "source": "..."}``: each primary a sum of Gaussian bands,
      as :func:`gaussian_spectra`; ``source`` optional)
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
      black), ``ambient_lux``, ``reflectivity``; ``photometry_sources``, where
      those figures come from (default: a note of which were given and the
      default's sources)

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
    text = read_utf8_text(path, _PROFILE_FILE)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON at {json_error_location(exc)}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object, found {type(doc).__name__}")

    problems: list[FieldProblem] = []
    for key in sorted(set(doc) - _PROFILE_KEYS):
        problems.append(FieldProblem(key, doc[key], "no such key; allowed keys: " + ", ".join(sorted(_PROFILE_KEYS))))
    if doc.get("schema") != PROFILE_SCHEMA:
        problems.append(FieldProblem("schema", doc.get("schema"), repr(PROFILE_SCHEMA)))
    name = doc.get("name")
    title = doc.get("title", name if isinstance(name, str) else "")
    sources = doc.get("sources", "")
    kind = doc.get("kind")
    transfer = doc.get("transfer", "srgb")
    for field, value in (("name", name), ("title", title), ("sources", sources), ("kind", kind),
                         ("transfer", transfer)):
        check_field(problems, field, value)
    primaries = _primaries(doc, path, problems)
    distance = _distance(doc, problems)
    resolution: tuple[int, int] | None = None
    if "resolution_px" in doc and check_field(problems, "resolution_px", doc["resolution_px"]):
        resolution = (doc["resolution_px"][0], doc["resolution_px"][1])
    ppd = _pixels_per_degree(doc, kind, distance, resolution, problems)
    photometry = _photometry(doc, kind, problems)

    if problems:
        raise ValidationErrors(problems, source=str(path))
    try:
        return DisplayProfile(
            name=name, title=title, kind=kind, primaries=primaries,  # type: ignore[arg-type]
            pixels_per_degree=ppd, distance_m=distance,  # type: ignore[arg-type]
            transfer=transfer, resolution_px=resolution, sources=sources, photometry=photometry,
        )
    except ValidationError as exc:  # e.g. primaries with a dead channel
        raise ValidationErrors([FieldProblem(exc.field, exc.value, exc.allowed)], source=str(path)) from None


# --------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------


def _preset_path(key: str) -> Path:
    """The profile file of the built-in preset ``key``."""
    return package_data(f"displays/{key}.json")


@functools.lru_cache(maxsize=None)
def _preset(key: str) -> DisplayProfile:
    return load_display_profile(_preset_path(key))


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


@functools.lru_cache(maxsize=None)
def _oled_proxy_bands() -> dict[str, tuple[tuple[float, float, float], ...]]:
    doc = json.loads(read_utf8_text(_preset_path("vivepro"), _PROFILE_FILE))
    return {label: tuple((float(c), float(w), float(h)) for c, w, h in doc["gaussian_primaries"][label])
            for label in RGB_LABELS}


def __getattr__(name: str) -> Any:
    """``OLED_PROXY_BANDS``: the parametric OLED proxy's bands, ``{label: ((centre_nm, fwhm_nm,
    peak_height), ...)}``, read from the ``vivepro`` preset file when first asked for."""
    if name == "OLED_PROXY_BANDS":
        return _oled_proxy_bands()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
