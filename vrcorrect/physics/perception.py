"""Cone responses to a display: Stockman & Sharpe (2000) 2-degree cone
fundamentals, the RGB->LMS matrix of a display, and the opponent transform
of Schmidt et al. (2014).

Normalisation: the matrix ``A[k, c] = sum_lambda cone_k(lambda) spd_c(lambda)``
(1 nm steps) is scaled per cone so that the display's white (R = G = B = 1)
maps to L = M = S = 1.  The same per-cone scale applies to the spectral
weights from which kernels are built, so a kernel's spatial sums equal ``A``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..specs.display import DisplayProfile, Spectra

#: Wavelengths over which every spectral integral is taken (1 nm steps).  The
#: cone fundamentals start at 390 nm; display spectra end at 780 nm.
INTEGRATION_GRID_NM = np.arange(390.0, 781.0, 1.0)
INTEGRATION_GRID_NM.setflags(write=False)

CONE_DATASET = "Stockman & Sharpe 2 Degree Cone Fundamentals"
CONES = ("L", "M", "S")

#: Opponent transform (Schmidt et al. 2014): O1 = (M + S) - L,
#: O2 = (L + S) - M, O3 = (L + M + S) / 3; rows act on (L, M, S).
OPPONENT_MATRIX = np.array([[-1.0, 1.0, 1.0],
                            [1.0, -1.0, 1.0],
                            [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0]])
OPPONENT_MATRIX.setflags(write=False)


@lru_cache(maxsize=1)
def cone_fundamentals() -> Spectra:
    """Stockman & Sharpe (2000) 2-degree cone fundamentals (CIE 2006 LMS),
    energy-based, from colour-science, on their native 1 nm grid (390-830 nm)."""
    import colour  # lazy: slow to import

    cmfs = colour.MSDS_CMFS[CONE_DATASET]
    return Spectra(wavelength_nm=np.asarray(cmfs.wavelengths, dtype=np.float64),
                   values=np.asarray(cmfs.values, dtype=np.float64),
                   labels=CONES,
                   source=f"colour-science MSDS_CMFS[{CONE_DATASET!r}] (Stockman & Sharpe 2000)")


def spectral_weights(primaries: Spectra,
                     wavelength_nm: np.ndarray = INTEGRATION_GRID_NM) -> np.ndarray:
    """Raw spectral weights ``cone_k(lambda) * spd_c(lambda)``, shape ``(3, 3, n)``.

    Both spectra are resampled (linearly, zero outside their data) to
    ``wavelength_nm`` first.
    """
    cones = cone_fundamentals().resample(wavelength_nm).values      # (n, 3)
    spd = primaries.resample(wavelength_nm).values                   # (n, 3)
    return np.einsum("nk,nc->kcn", cones, spd)


def white_normalisation(raw_matrix: np.ndarray) -> np.ndarray:
    """Per-cone scale that maps the display's white to L = M = S = 1."""
    return 1.0 / raw_matrix.sum(axis=1)


def normalised_weights(primaries: Spectra,
                       wavelength_nm: np.ndarray = INTEGRATION_GRID_NM) -> np.ndarray:
    """Spectral weights scaled so that their sum over wavelength is :func:`rgb_to_lms_matrix`."""
    raw = spectral_weights(primaries, wavelength_nm)
    scale = white_normalisation(raw.sum(axis=2))
    return raw * scale[:, None, None]


def rgb_to_lms_matrix(display: DisplayProfile | Spectra) -> np.ndarray:
    """3x3 matrix from linear display RGB to cone responses (white -> 1, 1, 1).

    ``A[k, c] = sum_lambda cone_k(lambda) spd_c(lambda)`` on a 1 nm grid,
    each row scaled so that it sums to 1.
    """
    spectra = display.primaries if isinstance(display, DisplayProfile) else display
    return normalised_weights(spectra).sum(axis=2)


def lms_to_rgb_matrix(display: DisplayProfile | Spectra) -> np.ndarray:
    """Inverse of :func:`rgb_to_lms_matrix`."""
    return np.linalg.inv(rgb_to_lms_matrix(display))


PHOTOPIC_DATASET = "CIE 1924 Photopic Standard Observer"


@lru_cache(maxsize=1)
def photopic_luminosity() -> Spectra:
    """The CIE 1924 photopic luminous efficiency V(lambda), from colour-science."""
    from colour.colorimetry import SDS_LEFS_PHOTOPIC  # lazy: slow to import

    sd = SDS_LEFS_PHOTOPIC[PHOTOPIC_DATASET]
    return Spectra(wavelength_nm=np.asarray(sd.wavelengths, dtype=np.float64),
                   values=np.asarray(sd.values, dtype=np.float64)[:, None], labels=("V",),
                   source=f"colour-science SDS_LEFS_PHOTOPIC[{PHOTOPIC_DATASET!r}]")


def luminance_weights(display: DisplayProfile | Spectra) -> np.ndarray:
    """Each primary's share of the display white's luminance: ``w_c = sum_lambda V(lambda) spd_c(lambda)``
    (CIE 1924 photopic V, 1 nm grid), scaled to sum to 1, so that ``w @ rgb`` is a linear image's
    luminance relative to the white (times the peak luminance: cd/m^2).  ``(3,)`` float64."""
    spectra = display.primaries if isinstance(display, DisplayProfile) else display
    v = photopic_luminosity().resample(INTEGRATION_GRID_NM).values[:, 0]
    w = (spectra.resample(INTEGRATION_GRID_NM).values * v[:, None]).sum(axis=0)
    return w / w.sum()


def apply_matrix(matrix: np.ndarray, image: np.ndarray) -> np.ndarray:
    """Apply a 3x3 colour matrix to an ``(..., 3)`` image; dtype follows the image."""
    m = np.asarray(matrix, dtype=image.dtype)
    return image @ m.T


def to_opponent(lms: np.ndarray) -> np.ndarray:
    """LMS ``(..., 3)`` -> opponent channels (O1, O2, O3) of Schmidt et al. (2014)."""
    return apply_matrix(OPPONENT_MATRIX, lms)


def from_opponent(opp: np.ndarray) -> np.ndarray:
    """Inverse of :func:`to_opponent`."""
    return apply_matrix(np.linalg.inv(OPPONENT_MATRIX), opp)
