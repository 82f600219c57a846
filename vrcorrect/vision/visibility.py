"""A visibility scale for the difference between two cone images: each band of a Laplacian pyramid of
the luminance, as contrast against the goal's local light, weighted by the eye's contrast
sensitivity at that band's frequency and that light.

``visibility_error(seen, goal)`` is ``sum_k mean_pixels (S_k (b_k(seen) - b_k(goal)) / La_k)^2``:

* luminance ``Y = peak (L/L_w + M/M_w) / 2 + floor`` (cd/m^2): each cone's light relative to white's,
  scaled to the display's peak, plus the light it shows for black (its black level and the room's
  light it reflects);
* ``b_k``: level ``k`` of a Laplacian pyramid (a 5-tap binomial filter, halving each level); the last
  level is the low-pass residual;
* ``La_k``: the goal's local mean light around each pixel at that level (the next level's Gaussian,
  brought back up), at least the floor;
* ``S_k``: Barten's simplified contrast sensitivity formula (Barten 2004, Proc. SPIE 5294) at the
  band's centre frequency, ``BAND_FREQUENCY * ppd / 2**k`` cycles per degree, and at ``La_k``, for a
  field as wide as the image.

So an error of the same size in light weighs more on a dark ground than on a bright one (contrast),
more at the frequencies the eye resolves best, and less in the dark, where sensitivity falls.  The
goal sets the adaptation, so the error is quadratic in the seen image: the guard reads it off three
points, as it does the objective.  No contrast masking (the lead that chose this form: a masking
term detected the falls worse) and no colour-opponent channels: colour errors count through their
luminance only.  The weighting by frequency is coarse: a band is an octave wide and neighbours
overlap, so a grating of 3 cycles per degree weighs only about 1.8 times one of 18 of the same
contrast on the desktop monitor, where the squared sensitivities differ about 25-fold.  It is a
guard's scale, not a judge (ColorVideoVDP judges).

Layer 3: numpy, float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..plumbing.errors import ValidationError

__all__ = ["BAND_FREQUENCY", "ViewingLight", "barten_csf", "visibility_error"]

#: A Laplacian band's centre frequency, of the pixels per degree: the finest band passes about a
#: quarter to a half of them (cycles per degree up to the Nyquist limit ``ppd / 2``).
BAND_FREQUENCY = 0.35

_BINOMIAL = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
_SMALLEST = 8                      # the pyramid stops at a level smaller than this (pixels)


@dataclass(frozen=True)
class ViewingLight:
    """Where the eye looks: the display's peak light and the light it shows for black (cd/m^2), and its
    pixels per degree."""

    peak_cd_m2: float
    floor_cd_m2: float
    pixels_per_degree: float

    def __post_init__(self) -> None:
        for name in ("peak_cd_m2", "floor_cd_m2", "pixels_per_degree"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ValidationError(f"viewing.{name}", value, "a finite number above 0")

    @classmethod
    def of(cls, display) -> "ViewingLight":
        """The viewing of a display profile (its photometry, which every profile has, and pixels per degree)."""
        light = display.photometry
        return cls(float(light.peak_luminance_cd_m2), float(light.black_cd_m2 + light.reflected_cd_m2),
                   float(display.pixels_per_degree))


def barten_csf(u_cpd, luminance_cd_m2, field_deg: float) -> np.ndarray:
    """Barten's simplified contrast sensitivity (Barten 2004): the reciprocal of the threshold
    modulation of a grating of ``u_cpd`` cycles per degree at ``luminance_cd_m2``, in a field of
    ``field_deg`` degrees (float64; frequencies and light are floored at 1e-3)."""
    u = np.maximum(np.asarray(u_cpd, np.float64), 1e-3)
    light = np.maximum(np.asarray(luminance_cd_m2, np.float64), 1e-3)
    optics = np.exp(-0.0016 * u * u * (1.0 + 100.0 / light) ** 0.08)
    noise = (1.0 + 144.0 / field_deg ** 2 + 0.64 * u * u) * (63.0 / light ** 0.83 + 1.0 / (1.0 - np.exp(-0.02 * u * u)))
    return 5200.0 * optics / np.sqrt(noise)


def _blur(a: np.ndarray) -> np.ndarray:
    """The separable 5-tap binomial filter, mirrored at the edges."""
    h, w = a.shape
    p = np.pad(a, ((2, 2), (0, 0)), mode="reflect")
    a = sum(_BINOMIAL[i] * p[i:i + h] for i in range(5))
    p = np.pad(a, ((0, 0), (2, 2)), mode="reflect")
    return sum(_BINOMIAL[i] * p[:, i:i + w] for i in range(5))


def _expand(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A level brought up to ``shape`` (zeros between its samples, then the filter, times 4)."""
    up = np.zeros(shape)
    up[::2, ::2] = a
    return 4.0 * _blur(up)


def _luminance(lms: np.ndarray, white: np.ndarray, viewing: ViewingLight) -> np.ndarray:
    relative = np.maximum(np.asarray(lms, np.float64), 0.0) / white
    return viewing.peak_cd_m2 * 0.5 * (relative[..., 0] + relative[..., 1]) + viewing.floor_cd_m2


def visibility_error(seen_lms: np.ndarray, goal_lms: np.ndarray, white: np.ndarray, viewing: ViewingLight) -> float:
    """The squared visible difference of ``seen_lms`` from ``goal_lms`` (``(H, W, 3)`` cone images,
    ``white``: white's cone light), on the scale of the module docstring (float64; 1 is about one
    threshold's contrast over the whole image in one band)."""
    seen, goal = np.asarray(seen_lms), np.asarray(goal_lms)
    if seen.shape != goal.shape or seen.ndim != 3 or seen.shape[2] != 3:
        raise ValidationError("seen_lms.shape", seen.shape, f"(H, W, 3), the goal's shape {goal.shape}")
    white = np.asarray(white, np.float64)
    if white.shape != (3,) or not np.all(white > 0):
        raise ValidationError("white", white.tolist(), "three positive cone lights")
    ys, yg = _luminance(seen, white, viewing), _luminance(goal, white, viewing)
    field = max(ys.shape) / viewing.pixels_per_degree
    total, level = 0.0, 0
    while min(ys.shape) >= _SMALLEST:
        gs, gg = _blur(ys)[::2, ::2], _blur(yg)[::2, ::2]
        mean = _expand(gg, yg.shape)
        adapt = np.maximum(mean, viewing.floor_cd_m2)
        band = (ys - _expand(gs, ys.shape)) - (yg - mean)
        s = barten_csf(BAND_FREQUENCY * viewing.pixels_per_degree / 2 ** level, adapt, field)
        total += float(np.mean((s * band / adapt) ** 2))
        ys, yg, level = gs, gg, level + 1
    adapt = np.maximum(yg, viewing.floor_cd_m2)
    s = barten_csf(BAND_FREQUENCY * viewing.pixels_per_degree / 2 ** level, adapt, field)
    return total + float(np.mean((s * (ys - yg) / adapt) ** 2))
