"""The geometric-optics PSF, for wavefronts too steep for a wave-optics pupil grid.

Physics and conventions (docs/architecture.md, 'Physics conventions', 'PSF' and 'Axes'):

* Where the wave-optics grid would exceed ``OpticsOptions.max_grid`` (:mod:`.wave_psf`) the
  wavefront is so steep that the defocus blur is many diffraction widths wide, and ray optics is
  accurate: the ray through pupil point ``(x, y)`` (mm, OSA frame) lands at the angle
  ``grad W(x, y)`` (um/mm = mrad), its transverse ray aberration.
* A pure sphero-cylinder maps the uniform pupil disc through the power matrix
  ``P = [[M + J0, J45], [J45, M - J0]]`` (D) onto a uniform ellipse (or a line, or a point),
  integrated over pixels exactly (:mod:`.disc_pixels`); with higher-order Zernike terms rays are
  traced through the pupil and deposited on a sub-pixel grid.
* The blur is then convolved with the pupil's Airy pattern integrated over pixels
  (:func:`vrcorrect.physics.wave_psf.airy_pixels`), clipped at 0 and normalised to sum 1.
  Orientation and centre are the wave PSF's: display coordinates (the OSA frame mirrored in ``x``,
  rows down), zero angle on the middle pixel of an odd-sized array.
* Its error (:func:`geometric_error_estimate`): the Airy disc's diameter over the diameter of the
  circle holding half the geometric blur's energy; checked against wave-optics PSFs in
  ``tests/test_optics_geometric.py``.

Units: wavelengths in nm, angles in radians, pupil coordinates in mm, blur sizes in display pixels.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft

from ..plumbing.errors import ModelLimitError
from ..specs.prescription import EyeRx, PowerVector
from .disc_pixels import sheared_disc_masses
from .options import OpticsOptions
from .refraction import max_meridian_power_D, max_wavefront_slope_rad, wavefront_um
from .sampling import PixelPsf, PsfSampling, check_psf_request, pixel_angle_rad
from .wave_psf import airy_pixels, diffraction_blur_rad

_RAY_BUDGET = 16_000_000               # most rays traced for one PSF with higher-order terms
_RAY_FINE_LIMIT = 3072                 # largest sub-pixel grid (per side) the rays are deposited on
_RAY_COARSE_CELLS = 192                # pupil cells across the diameter where the gradient is evaluated


def _convolve_full(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Full 2-D linear convolution of two real arrays by FFT."""
    shape = (a.shape[0] + b.shape[0] - 1, a.shape[1] + b.shape[1] - 1)
    fshape = tuple(scipy.fft.next_fast_len(n, real=True) for n in shape)
    spec = scipy.fft.rfft2(a, fshape, workers=-1) * scipy.fft.rfft2(b, fshape, workers=-1)
    return scipy.fft.irfft2(spec, fshape, workers=-1)[:shape[0], :shape[1]]


def _pad_square(a: np.ndarray) -> np.ndarray:
    n = max(a.shape)
    out = np.zeros((n, n))
    r0, c0 = (n - a.shape[0]) // 2, (n - a.shape[1]) // 2
    out[r0:r0 + a.shape[0], c0:c0 + a.shape[1]] = a
    return out


def _sphero_cylinder_masses(pv: PowerVector, pupil_radius_mm: float, p: float) -> np.ndarray:
    """Geometric blur of a pure sphero-cylindrical error, integrated over display pixels.

    The wavefront ``W = -(M (x^2+y^2) + J0 (x^2-y^2) + 2 J45 x y) / 2`` (um, x
    and y in mm, OSA frame) sends the ray through pupil point ``r`` to the
    angle ``grad W = -P r`` (mrad) with ``P = [[M + J0, J45], [J45, M - J0]]``.
    On the display (columns right = ``-theta_x``, rows down = ``-theta_y``,
    as in the wave-optics path) the uniform pupil disc maps to the uniform
    ellipse ``(col, row) = B u``, ``B = P R 1e-3 / p``, ``u`` on the unit
    disc; ``B`` may be singular (a line or a point).  Since the disc is
    rotation-invariant, ``B u`` has the law of ``L v`` with ``L`` lower
    triangular along the axis of the longer row of ``B``
    (:func:`~vrcorrect.physics.disc_pixels.sheared_disc_masses`).
    """
    P = np.array([[pv.M_D + pv.J0_D, pv.J45_D], [pv.J45_D, pv.M_D - pv.J0_D]])
    B = P * (pupil_radius_mm * 1e-3 / p)          # pixels per unit pupil radius
    norms = np.hypot(B[:, 0], B[:, 1])
    if norms.max() < 1e-9:
        return np.ones((1, 1))
    first = int(np.argmax(norms))                  # 0: quadrature along columns, 1: along rows
    b1, b2 = B[first], B[1 - first]
    l11 = float(norms[first])
    e1 = b1 / l11
    e2 = np.array([-e1[1], e1[0]])
    masses = sheared_disc_masses(l11, float(b2 @ e1), float(b2 @ e2))   # [other axis, first axis]
    grid = masses if first == 0 else masses.T     # [row, col]
    return _pad_square(grid)


def _ray_traced_masses(eye: EyeRx, pv: PowerVector, p: float) -> tuple[np.ndarray, int, int]:
    """Geometric blur with higher-order terms: rays traced through the pupil.

    The transverse ray aberration is the wavefront gradient: the ray through
    pupil point ``(x, y)`` lands at angle ``grad W(x, y)`` (um/mm = mrad),
    drawn on the display as in :func:`_sphero_cylinder_masses`.  The gradient
    is evaluated (central differences) at the corners of 192 x 192 pupil cells
    and interpolated bilinearly to ``s x s`` rays per cell, ``s`` chosen so
    neighbouring rays land at most half a sub-pixel apart (at most 16 M rays);
    each ray carries equal weight and is shared bilinearly between the four
    nearest cells of a grid 3 times finer than the display pixel (1 time
    where that grid would exceed 3072 per side), which is then summed over
    each pixel.  Returns (masses (n, n) centred, sub-pixels per pixel, rays
    across the pupil).
    """
    radius = eye.pupil_diameter_mm / 2.0
    nc = _RAY_COARSE_CELLS
    hc = 2.0 * radius / nc
    c = np.linspace(-radius, radius, nc + 1)
    X, Y = np.meshgrid(c, c)                       # rows: y ascending, columns: x ascending (OSA)
    eps = 1e-3 * hc
    gx = (wavefront_um(eye, pv, X + eps, Y) - wavefront_um(eye, pv, X - eps, Y)) / (2.0 * eps)
    gy = (wavefront_um(eye, pv, X, Y + eps) - wavefront_um(eye, pv, X, Y - eps)) / (2.0 * eps)
    col = -gx * 1e-3 / p                           # display columns go to -theta_x
    row = -gy * 1e-3 / p                           # display rows go to -theta_y
    mid = 0.5 * (c[1:] + c[:-1])
    MX, MY = np.meshgrid(mid, mid)
    touch = np.hypot(MX, MY) <= radius + hc * 0.7072    # cells that reach into the pupil
    iy, ix = np.nonzero(touch)
    corners_c = np.stack([col[iy, ix], col[iy, ix + 1], col[iy + 1, ix], col[iy + 1, ix + 1]])
    corners_r = np.stack([row[iy, ix], row[iy, ix + 1], row[iy + 1, ix], row[iy + 1, ix + 1]])
    half = int(math.ceil(max(np.abs(corners_c).max(), np.abs(corners_r).max()) + 1.0))
    n_pix = 2 * half + 1
    q = 3 if 3 * n_pix <= _RAY_FINE_LIMIT else 1
    nf = n_pix * q
    spread = max(np.ptp(corners_c, axis=0).max(), np.ptp(corners_r, axis=0).max()) * q   # sub-pixels per cell
    s_max = max(2, int(math.sqrt(_RAY_BUDGET / iy.size)))
    s = int(min(max(math.ceil(2.0 * spread), 2), s_max))
    t = (np.arange(s) + 0.5) / s
    x0, y0 = c[ix], c[iy]
    fine = np.zeros(nf * nf)
    centre = (nf - 1) / 2.0
    batch_c: list[np.ndarray] = []
    batch_r: list[np.ndarray] = []
    pending = 0

    def deposit() -> None:
        fc = np.concatenate(batch_c) * q + centre
        fr = np.concatenate(batch_r) * q + centre
        i0 = np.floor(fc).astype(np.int64)
        j0 = np.floor(fr).astype(np.int64)
        wc = fc - i0
        wr = fr - j0
        base = j0 * nf + i0
        n = nf * nf
        fine[:] += np.bincount(base, (1 - wc) * (1 - wr), minlength=n)
        fine[:] += np.bincount(base + 1, wc * (1 - wr), minlength=n)
        fine[:] += np.bincount(base + nf, (1 - wc) * wr, minlength=n)
        fine[:] += np.bincount(base + nf + 1, wc * wr, minlength=n)
        batch_c.clear()
        batch_r.clear()

    for ty in t:
        for tx in t:
            inside = (x0 + tx * hc) ** 2 + (y0 + ty * hc) ** 2 <= radius * radius
            w00, w01, w10, w11 = (1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty
            cc = w00 * corners_c[0] + w01 * corners_c[1] + w10 * corners_c[2] + w11 * corners_c[3]
            rr = w00 * corners_r[0] + w01 * corners_r[1] + w10 * corners_r[2] + w11 * corners_r[3]
            batch_c.append(cc[inside])
            batch_r.append(rr[inside])
            pending += int(inside.sum())
            if pending > 1_000_000:
                deposit()
                pending = 0
    if batch_c:
        deposit()
    masses = fine.reshape(n_pix, q, n_pix, q).sum(axis=(1, 3))
    return masses / masses.sum(), q, nc * s


def half_energy_radius_px(masses: np.ndarray) -> float:
    """Radius (pixels, from the centre pixel) of the circle holding half of ``masses``'
    energy, each pixel's mass taken at its centre and the cumulative energy
    interpolated linearly in radius (a pixel-resolution estimate)."""
    n = masses.shape[0]
    c = n // 2
    yy, xx = np.mgrid[:n, :n]
    r = np.hypot(xx - c, yy - c).ravel()
    order = np.argsort(r, kind="stable")
    cum = np.cumsum(masses.ravel()[order])
    return float(np.interp(0.5 * cum[-1], cum, r[order]))


def geometric_error_estimate(wavelength_nm: float, pupil_diameter_mm: float, blur_r50_rad: float) -> float:
    """Estimated relative error of the geometric-optics PSF.

    The ratio of the diffraction blur, the Airy disc's diameter
    ``2.44 lambda / D``, to the geometric blur's size, the diameter of the
    circle holding half its energy (``2 blur_r50_rad``; for a uniform disc
    of radius ``a`` that is ``sqrt(2) a``).  Geometric optics leaves out
    interference (the ripples of the defocused wave PSF, the diffraction
    structure of caustics); their effect on the blur's size, relative to it,
    is of this order or less.  Checked in ``tests/test_optics_geometric.py``
    against wave-optics PSFs where both are feasible (3 to 20 waves of
    aberration): the radii holding half the energy agreed to 0.2-1.3 %, at
    most 0.55 of this estimate.  Infinite for no geometric blur.
    """
    if not blur_r50_rad > 0.0:
        return math.inf
    return diffraction_blur_rad(wavelength_nm, pupil_diameter_mm) / (2.0 * blur_r50_rad)


def geometric_psf_pixels(eye: EyeRx, pv: PowerVector, wavelength_nm: float, pixels_per_degree: float,
                         options: OpticsOptions = OpticsOptions(), *, wave_grid_needed: int = 0) -> PixelPsf:
    """Monochromatic PSF by geometric optics, integrated over pixels, with the Airy core.

    For a wavefront so steep that a wave-optics pupil grid would be too large
    the defocus blur is many times the diffraction blur and geometric optics
    is accurate.  The PSF is the pupil's ray-traced blur patch integrated
    exactly over display pixels, convolved with the Airy pattern of the pupil
    at this wavelength (:func:`~vrcorrect.physics.wave_psf.airy_pixels`, also pixel-integrated), clipped
    at 0 and normalised to sum 1.

    * Pure sphero-cylinder (no higher-order terms): the blur patch is the
      uniform pupil disc mapped through the power matrix, an ellipse,
      possibly degenerate (a line or a point), integrated over pixels
      semi-analytically (:func:`_sphero_cylinder_masses`).
    * With higher-order terms: rays traced to ``grad W``
      (:func:`_ray_traced_masses`).

    Orientation and centre are those of :func:`~vrcorrect.physics.psf.psf_pixels`: rows down and
    columns right as the subject sees the display (the OSA frame mirrored in
    x), zero angle on the centre pixel.  The diffraction is applied at pixel
    resolution (the blur's pixel masses convolved with the pixel-integrated
    Airy pattern), which widens it by up to one pixel's box; that matters only
    where the Airy pattern is not small against the blur.

    Parameters
    ----------
    eye, pv, wavelength_nm, pixels_per_degree, options
        As for :func:`~vrcorrect.physics.psf.psf_pixels`.
    wave_grid_needed
        The wave-optics grid (per side) this PSF replaces, recorded in its
        sampling; 0 when geometric optics was asked for directly.

    Returns
    -------
    PixelPsf
        ``sampling.model == "geometric"``; ``sampling.model_error_estimate``
        from :func:`geometric_error_estimate`.

    Raises
    ------
    ModelLimitError
        If the blur would need more than ``options.max_grid`` pixels per side.
    """
    check_psf_request(wavelength_nm, pixels_per_degree)
    p = pixel_angle_rad(pixels_per_degree)
    D = eye.pupil_diameter_mm
    slope = max_wavefront_slope_rad(eye, pv)
    needed = 2 * int(math.ceil(slope / p + 2.0)) + 1
    if needed > options.max_grid:
        raise ModelLimitError(
            f"the geometric PSF at {wavelength_nm:.0f} nm would be {needed}x{needed} pixels (limit "
            f"{options.max_grid}): the blur ({max_meridian_power_D(pv):.1f} D over a {D:g} mm pupil) is too wide "
            f"for {pixels_per_degree:g} pixels per degree; use a smaller pupil_diameter_mm or a lower "
            f"pixels_per_degree")
    has_ho = eye.higher_order is not None and bool(eye.higher_order.coefficients_um)
    if has_ho:
        blur, q, rays = _ray_traced_masses(eye, pv, p)
    else:
        blur, q, rays = _sphero_cylinder_masses(pv, D / 2.0, p), 1, 0
    airy = airy_pixels(wavelength_nm, D, pixels_per_degree)
    pix = _convolve_full(blur, airy)
    np.maximum(pix, 0.0, out=pix)
    total = pix.sum()
    if not (total > 0 and math.isfinite(total)):
        raise ModelLimitError("geometric PSF computation produced no energy")
    pix = np.ascontiguousarray(pix / total)
    sampling = PsfSampling(wavelength_nm=float(wavelength_nm), oversample=q, grid=0, pupil_samples=float(rays),
                           fine_step_rad=p / q, max_phase_step_rad=math.nan, refinements=0, slope_rad=slope,
                           model="geometric",
                           model_error_estimate=geometric_error_estimate(
                               wavelength_nm, D, half_energy_radius_px(blur) * p),
                           wave_grid_needed=int(wave_grid_needed))
    return PixelPsf(pix, float(pixels_per_degree), sampling)

