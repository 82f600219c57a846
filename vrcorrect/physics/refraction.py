"""The eye's refractive state while it looks at the display, at every wavelength.

Physics and conventions (docs/architecture.md, 'Physics conventions'):

* Prescription as a power vector (Thibos 1997): ``M = S + C/2``, ``J0 = -(C/2) cos 2 alpha``,
  ``J45 = -(C/2) sin 2 alpha``, in dioptres (D); the power along a meridian (OSA/TABO angle, degrees)
  is ``M + J0 cos 2 theta + J45 sin 2 theta``.
* Viewing distance ``d`` (m): the refraction that would make the display sharp is ``R = M + 1/d``
  (``1/d`` is the vergence, 0 at infinity).  Accommodation removes positive ``R`` up to its
  amplitude, never negative ``R`` (:func:`refractive_state`); an eye with an accommodative lag
  responds to ``R`` with ``R (1 - lag / 2.5 D)`` (the lag as MEM retinoscopy measures it at 40 cm,
  growing in proportion to the demand), and the part of ``R`` it leaves is its lag at the display.
* Longitudinal chromatic aberration: Thibos et al. (1992) "chromatic eye",
  ``Rx(lambda) = p - q / (lambda - c)`` with ``p = 1.68524 D``, ``q = 633.46 D nm``,
  ``c = 214.102 nm``: about -1.0 D at 450 nm and +0.23 D at 650 nm relative to 590 nm (short
  wavelengths are focused in front of the retina, i.e. the eye is more myopic for blue).  The
  prescription holds at the reference wavelength (``OpticsOptions.reference_wavelength_nm``, 555 nm
  by default); at another wavelength the change of ``Rx`` is added to ``M``
  (:meth:`RefractiveState.at_wavelength`).
* The wavefront error (um) over pupil coordinates (mm, OSA frame: ``x`` to the examiner's right,
  ``y`` up) is ``W = -(M (x^2+y^2) + J0 (x^2-y^2) + 2 J45 x y) / 2`` from the residual power
  vector, plus the prescription's measured higher-order Zernike terms (:mod:`.zernike`), evaluated in
  physical coordinates of the pupil they were measured at (:func:`wavefront_um`).  Its slope
  (um/mm = mrad) bounds how finely a pupil must be sampled and how wide the geometric blur is
  (:func:`max_wavefront_slope_rad`).
* Depth of focus (:func:`depth_of_focus_D`): the defocus whose geometric blur disc is below the
  larger of one display pixel and the eye's 1 arcmin acuity limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..specs.prescription import LAG_MEASURED_AT_D, EyeRx, PowerVector
from .options import OpticsOptions
from .sampling import pixel_angle_rad
from .zernike import osa_nm, zernike

# Thibos, Ye, Zhang & Bradley (1992), Applied Optics 31(19):3594, chromatic eye.
LCA_P_D = 1.68524
LCA_Q_D_NM = 633.46
LCA_C_NM = 214.102

ARCMIN_RAD = math.radians(1.0 / 60.0)


def chromatic_refraction_D(wavelength_nm: np.ndarray | float) -> np.ndarray:
    """Refractive error of the Thibos (1992) chromatic eye at ``wavelength_nm`` (D).

    Zero near 590 nm; negative (myopic) at short wavelengths.
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    return LCA_P_D - LCA_Q_D_NM / (lam - LCA_C_NM)


def lca_defocus_D(wavelength_nm: np.ndarray | float, reference_wavelength_nm: float) -> np.ndarray:
    """Change in the eye's refraction at ``wavelength_nm`` relative to the reference (D)."""
    return chromatic_refraction_D(wavelength_nm) - chromatic_refraction_D(reference_wavelength_nm)


@dataclass(frozen=True)
class RefractiveState:
    """The eye's residual refractive error while looking at the display (D)."""

    residual: PowerVector          # at the reference wavelength, after distance and accommodation
    accommodation_used_D: float
    vergence_D: float              # 1/d of the display (0 at infinity)

    def at_wavelength(self, wavelength_nm: float, options: OpticsOptions) -> PowerVector:
        """Residual power vector at another wavelength (adds chromatic defocus)."""
        dM = float(lca_defocus_D(wavelength_nm, options.reference_wavelength_nm)) if options.chromatic_aberration else 0.0
        return PowerVector(self.residual.M_D + dM, self.residual.J0_D, self.residual.J45_D)


def refractive_state(eye: EyeRx, distance_m: float) -> RefractiveState:
    """Residual refraction of ``eye`` looking at a display at ``distance_m``.

    ``R = M + 1/d``; accommodation removes positive ``R`` up to
    ``eye.accommodation_D``, never negative ``R``.  An eye with an accommodative lag
    (``eye.accommodative_lag_D``, measured at :data:`~vrcorrect.specs.prescription.LAG_MEASURED_AT_D`)
    responds with ``R (1 - lag / 2.5)``, still at most its amplitude: it leaves ``R lag / 2.5`` of
    hyperopic defocus (the display focused behind the retina), none where it need not accommodate.
    """
    pv = eye.power_vector()
    vergence = 0.0 if math.isinf(distance_m) else 1.0 / distance_m
    R = pv.M_D + vergence
    response = max(R, 0.0) * (1.0 - eye.accommodative_lag_D / LAG_MEASURED_AT_D)
    used = min(response, eye.accommodation_D)
    return RefractiveState(PowerVector(R - used, pv.J0_D, pv.J45_D), used, vergence)


def max_meridian_power_D(pv: PowerVector) -> float:
    """Largest refractive error over all meridians, in magnitude (D)."""
    return abs(pv.M_D) + math.hypot(pv.J0_D, pv.J45_D)


def meridian_power_D(pv: PowerVector, meridian_deg: float) -> float:
    """Refractive error along one meridian (OSA/TABO angle, degrees)."""
    a = math.radians(2.0 * meridian_deg)
    return pv.M_D + pv.J0_D * math.cos(a) + pv.J45_D * math.sin(a)


def wavefront_um(eye: EyeRx, pv: PowerVector, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Wavefront error (um) over pupil coordinates (mm, OSA frame).

    Second order from the residual power vector ``pv``; higher orders from the
    prescription's measured coefficients, evaluated in physical coordinates of
    the pupil they were measured at (so no rescaling formula is needed when the
    eye's pupil is smaller).
    """
    x = np.asarray(x_mm, dtype=np.float64)
    y = np.asarray(y_mm, dtype=np.float64)
    w = -0.5 * (pv.M_D * (x * x + y * y) + pv.J0_D * (x * x - y * y) + 2.0 * pv.J45_D * x * y)
    ho = eye.higher_order
    if ho is not None and ho.coefficients_um:
        radius = ho.pupil_diameter_mm / 2.0
        rho = np.hypot(x, y) / radius
        theta = np.arctan2(y, x)
        for j, c in ho.coefficients_um:
            n, m = osa_nm(int(j))
            w = w + c * zernike(n, m, rho, theta)
    return w


def max_wavefront_slope_rad(eye: EyeRx, pv: PowerVector) -> float:
    """Largest wavefront slope over the pupil (radians; um/mm = mrad).

    Exact for second order; higher orders are sampled on a 129x129 grid.
    """
    radius_mm = eye.pupil_diameter_mm / 2.0
    slope = max_meridian_power_D(pv) * radius_mm * 1e-3  # D * mm -> mrad * 1e-3 = rad
    if eye.higher_order is not None and eye.higher_order.coefficients_um:
        n = 129
        c = np.linspace(-radius_mm, radius_mm, n)
        X, Y = np.meshgrid(c, c)
        inside = X * X + Y * Y <= radius_mm ** 2
        zero = PowerVector(0.0, 0.0, 0.0)
        w = wavefront_um(eye, zero, X, Y)
        gy, gx = np.gradient(w, c, c)
        ho_slope = float(np.max(np.hypot(gx, gy)[inside])) * 1e-3
        slope += ho_slope
    return slope


def depth_of_focus_D(pupil_diameter_mm: float, pixels_per_degree: float) -> float:
    """Half-width of the eye's depth of focus at this display (D).

    A blur disc is invisible on this display when its angular diameter is
    below the larger of one display pixel and the eye's 1 arcmin acuity limit;
    the geometric blur diameter of a defocus ``F`` (D) through a pupil of
    diameter ``D`` (m) is ``F * D`` radians.
    """
    tol = max(pixel_angle_rad(pixels_per_degree), ARCMIN_RAD)
    return tol / (pupil_diameter_mm * 1e-3)

