"""Spectra: emission spectra that carry their wavelengths, parametric (Gaussian) spectra, the
spectra CSV a spectroradiometer measurement is written in, and a smooth proxy fitted to one.

Wavelengths in nanometres (``wavelength_nm``), strictly increasing; values are relative radiance
per channel (non-negative, arbitrary scale).
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ...plumbing.errors import InputError, FieldProblem, ValidationError
from ..validation import FileWording, positive_finite, read_utf8_text

__all__ = [
    "CSV_WAVELENGTH_RANGE_NM",
    "CSV_MIN_ROWS",
    "RGB_LABELS",
    "Spectra",
    "gaussian_spectra",
    "read_spectra_csv",
    "SpectraFit",
    "fit_spectra",
]

#: Channel labels of a display's primaries, in order.
RGB_LABELS: tuple[str, str, str] = ("red", "green", "blue")
CSV_WAVELENGTH_RANGE_NM = (300.0, 1000.0)
CSV_MIN_ROWS = 5


# --------------------------------------------------------------------------
# Spectra
# --------------------------------------------------------------------------


def _frozen_copy(array: np.ndarray) -> np.ndarray:
    out = np.array(array, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


def _wavelength_problem(wavelength_nm: Any, name: str) -> tuple[np.ndarray | None, FieldProblem | None]:
    """Check a wavelength grid: 1-D, at least 2 samples, finite, strictly increasing."""
    try:
        wl = np.asarray(wavelength_nm, dtype=np.float64)
    except (TypeError, ValueError):
        return None, FieldProblem(name, wavelength_nm, "a 1-D array of wavelengths in nm")
    if wl.ndim != 1 or wl.size < 2:
        return None, FieldProblem(name, f"array of shape {wl.shape}", "a 1-D array of at least 2 wavelengths in nm")
    if not np.all(np.isfinite(wl)):
        return None, FieldProblem(name, "array containing NaN or inf", "finite wavelengths in nm")
    steps = np.diff(wl)
    if np.any(steps <= 0):
        i = int(np.argmax(steps <= 0))
        return None, FieldProblem(
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
# Spectra CSV
# --------------------------------------------------------------------------


#: How a spectra CSV's reading problems are told.
_CSV_FILE = FileWording(
    not_found="{path}: spectra CSV not found",
    is_directory="{path}: is a directory, expected a spectra CSV",
    unreadable="{path}: cannot read spectra CSV: {reason}",
    not_utf8="{path}: spectra CSV is not UTF-8 text (byte {offset})",
)


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
    text = read_utf8_text(path, _CSV_FILE)
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
    from scipy.optimize import nnls  # reason: scipy.optimize takes about 0.6 s to import; only fitting needs it

    if not isinstance(measured, Spectra):
        raise ValidationError("measured", type(measured).__name__, "a Spectra object")
    wl = measured.wavelength_nm
    if wl.size < CSV_MIN_ROWS:
        raise ValidationError("measured.wavelength_nm", f"{wl.size} samples", f"at least {CSV_MIN_ROWS} samples")
    step = float(np.median(np.diff(wl)))
    s0 = max(3.0, step) if min_sigma_nm is None else positive_finite("min_sigma_nm", min_sigma_nm)
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
            from scipy.optimize import lsq_linear  # reason: as nnls above, and only on this rare path

            coef = np.clip(lsq_linear(system, rhs, bounds=(0.0, np.inf), method="bvls").x, 0.0, None)
        out[:, c] = np.clip(basis_grid @ coef, 0.0, None) * peak
        resid = (design @ coef) - target
        rms.append(float(np.sqrt(np.mean(resid**2))))
        mx.append(float(np.max(np.abs(resid))))
    source = f"smooth proxy (non-negative Gaussian fit, s0 = {s0:g} nm) of {measured.source}"
    return SpectraFit(Spectra(grid, out, measured.labels, source), tuple(rms), tuple(mx))
