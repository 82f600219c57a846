"""Zernike polynomials (OSA/ANSI Z80.28) and the wavefronts they describe.

Conventions (docs/architecture.md, 'Physics conventions', 'Zernike' and 'Axes'):

* Single index ``j = (n(n+2)+m)/2``; each term normalised to unit RMS over the unit disc,
  ``Z_n^m = N R_n^|m|(rho) cos(m theta)`` for ``m >= 0`` and ``-N R_n^|m|(rho) sin(m theta)`` for
  ``m < 0``.  Coefficients are in micrometres for a stated pupil radius (mm).
* Pupil coordinates ``(x, y)`` in mm, in the OSA/ISO 8429 frame: the eye as seen by the examiner,
  ``x`` to the examiner's right (the subject's left), ``y`` up, angles counter-clockwise from +x.
* Second-order terms from a power vector (Thibos 1997), ``r`` in mm, powers in D, ``c`` in um:
  ``c(2,0) = -M r^2/(4 sqrt 3)``, ``c(2,2) = -J0 r^2/(2 sqrt 6)``, ``c(2,-2) = -J45 r^2/(2 sqrt 6)``;
  the resulting wavefront is ``W(x, y) = -(M (x^2+y^2) + J0 (x^2-y^2) + 2 J45 x y) / 2`` (+ piston),
  so a myopic eye (negative M) has a positive defocus coefficient.

The eye's own wavefront (its residual refraction plus measured higher-order terms) is
:func:`vrcorrect.physics.refraction.wavefront_um`.
"""

from __future__ import annotations

import math

import numpy as np

from ..plumbing.errors import ValidationError
from ..specs.prescription import PowerVector


def osa_index(n: int, m: int) -> int:
    """OSA/ANSI single index ``j`` of ``Z_n^m``."""
    if n < 0 or abs(m) > n or (n - m) % 2:
        raise ValidationError("zernike (n, m)", (n, m), "n >= 0, |m| <= n, n - m even")
    return (n * (n + 2) + m) // 2


def osa_nm(j: int) -> tuple[int, int]:
    """Radial order ``n`` and azimuthal frequency ``m`` of OSA/ANSI index ``j``."""
    if j < 0:
        raise ValidationError("zernike j", j, "an integer >= 0")
    n = int(math.ceil((-3 + math.sqrt(9 + 8 * j)) / 2))
    m = 2 * j - n * (n + 2)
    return n, m


def _radial(n: int, m_abs: int, rho: np.ndarray) -> np.ndarray:
    out = np.zeros_like(rho)
    for s in range((n - m_abs) // 2 + 1):
        coef = ((-1) ** s * math.factorial(n - s)
                / (math.factorial(s) * math.factorial((n + m_abs) // 2 - s)
                   * math.factorial((n - m_abs) // 2 - s)))
        out += coef * rho ** (n - 2 * s)
    return out


def zernike(n: int, m: int, rho: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """OSA/ANSI normalised Zernike polynomial ``Z_n^m(rho, theta)``.

    Parameters
    ----------
    n, m
        Radial order and azimuthal frequency.
    rho
        Normalised radius (0..1 inside the pupil); float64 array.
    theta
        Azimuth in radians, counter-clockwise from +x (OSA frame).

    Returns
    -------
    numpy.ndarray
        Values with unit RMS over the unit disc (not masked outside it).
    """
    osa_index(n, m)  # validates
    rho = np.asarray(rho, dtype=np.float64)
    theta = np.asarray(theta, dtype=np.float64)
    norm = math.sqrt((2 * (n + 1)) / (2.0 if m == 0 else 1.0))
    radial = _radial(n, abs(m), rho)
    if m > 0:
        return norm * radial * np.cos(m * theta)
    if m < 0:
        return -norm * radial * np.sin(m * theta)
    return norm * radial


def power_vector_to_zernike_um(pv: PowerVector, pupil_radius_mm: float) -> dict[tuple[int, int], float]:
    """Second-order Zernike coefficients (um) of a power vector over a pupil radius (mm)."""
    r2 = pupil_radius_mm ** 2
    return {
        (2, 0): -pv.M_D * r2 / (4.0 * math.sqrt(3.0)),
        (2, 2): -pv.J0_D * r2 / (2.0 * math.sqrt(6.0)),
        (2, -2): -pv.J45_D * r2 / (2.0 * math.sqrt(6.0)),
    }


def zernike_um_to_power_vector(coefficients: dict[tuple[int, int], float],
                               pupil_radius_mm: float) -> PowerVector:
    """Inverse of :func:`power_vector_to_zernike_um` (second order only)."""
    r2 = pupil_radius_mm ** 2
    return PowerVector(
        M_D=-coefficients.get((2, 0), 0.0) * 4.0 * math.sqrt(3.0) / r2,
        J0_D=-coefficients.get((2, 2), 0.0) * 2.0 * math.sqrt(6.0) / r2,
        J45_D=-coefficients.get((2, -2), 0.0) * 2.0 * math.sqrt(6.0) / r2,
    )


def wavefront_from_zernike_um(coefficients: dict[tuple[int, int], float], pupil_radius_mm: float,
                              x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Wavefront (um) from OSA Zernike coefficients (um) for a pupil radius (mm)."""
    rho = np.hypot(x_mm, y_mm) / pupil_radius_mm
    theta = np.arctan2(y_mm, x_mm)
    out = np.zeros(np.broadcast(rho, theta).shape)
    for (n, m), c in coefficients.items():
        out = out + c * zernike(n, m, rho, theta)
    return out

