"""Exact pixel masses of a uniform disc seen through a linear map: the blur patch of a sphero-cylinder.

A defocused, astigmatic eye spreads the light of a point over the image of its pupil disc under a
linear map: a uniform ellipse, possibly degenerate (a line or a point).  :func:`sheared_disc_masses`
integrates such a patch over display pixels without sampling it: along one axis the disc's marginal
is cut into pieces of exactly known mass, along the other each piece is an interval (or, over the
piece, a trapezoid) whose overlap with every pixel is exact.  Pure geometry: coordinates and sizes
in display pixels; the optics that produce the map are in :mod:`.geometric_psf`.
"""

from __future__ import annotations

import math

import numpy as np

PIECES_PER_PIXEL = 16                  # quadrature pieces per pixel along the blur's main axis


def _uniform_cdf(z: np.ndarray, w: np.ndarray) -> np.ndarray:
    """CDF at ``z`` of the uniform law on ``[-w, w]`` (a unit step at 0 where ``w == 0``)."""
    wide = w > 0.0
    return np.where(wide, np.clip((z + w) / (2.0 * np.where(wide, w, 1.0)), 0.0, 1.0), (z >= 0.0) * 1.0)


def _uniform_cdf_integral(z: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``int_-inf^z`` of :func:`_uniform_cdf` (``max(z, 0)`` where ``w == 0``)."""
    inner = (z + w) ** 2 / (4.0 * np.where(w > 0.0, w, 1.0))
    return np.where(z >= w, z, np.where(z <= -w, 0.0, inner))


def _trapezoid_cdf(z: np.ndarray, w: np.ndarray, d: np.ndarray) -> np.ndarray:
    """CDF at ``z`` of ``U[-w, w] + U[-d, d]`` (either width may be 0)."""
    moving = d > 1e-6
    dd = np.where(moving, d, 1.0)
    trapezoid = (_uniform_cdf_integral(z + dd, w) - _uniform_cdf_integral(z - dd, w)) / (2.0 * dd)
    out = np.where(moving, trapezoid, _uniform_cdf(z, w))
    return np.where(z >= w + d, 1.0, np.where(z < -(w + d), 0.0, out))


def _column_cdfs(col: np.ndarray, m: np.ndarray, c: np.ndarray, w: np.ndarray, d: np.ndarray,
                 n1: int, h2: int) -> np.ndarray:
    """``cdf[j, k] = sum over pieces in column j of m * F(e_k - c)`` at the pixel boundaries
    ``e_k = k - h2 - 1/2`` (``k = 0 .. 2 h2 + 1``), ``F`` = :func:`_trapezoid_cdf` with
    half-widths ``w`` and ``d`` (``d < 1/2``; supports inside ``(-h2 - 1/2, h2 + 1/2)``)."""
    n2 = 2 * h2 + 1
    ne = n2 + 1                                               # pixel boundaries e_k = k - h2 - 1/2
    off = h2 + 0.5
    edges = np.arange(ne, dtype=np.float64) - off
    size = n1 * (ne + 1)                                      # one spare slot per column: "above all"

    def binned(k: np.ndarray, weights: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """Sum ``weights`` into (column, boundary ``k``) cells; shape (n1, ne + 1)."""
        k = np.clip(k, 0, ne)
        return np.bincount((col * (ne + 1) + k)[keep], weights[keep], minlength=size).reshape(n1, ne + 1)

    def at_edge(k: np.ndarray, values: np.ndarray, keep: np.ndarray) -> np.ndarray:
        keep = keep & (k >= 0) & (k < ne)
        return binned(k, values, keep)[:, :ne]

    def first_edge_at_or_above(x: np.ndarray) -> np.ndarray:
        return np.ceil(x + off).astype(np.int64)

    out = np.zeros((n1, ne))
    wide = w >= 0.5
    narrow = ~wide
    # Wide intervals: the uniform CDF is (ramp(z + w) - ramp(z - w)) / (2 w); sum the ramps.
    a1 = np.zeros((n1, ne + 1))
    a0 = np.zeros((n1, ne + 1))
    safe_w = np.where(wide, w, 1.0)
    for sign, start in ((1.0, c - w), (-1.0, c + w)):
        alpha = sign * m / (2.0 * safe_w)
        k = np.floor(start + off).astype(np.int64) + 1      # first boundary strictly above `start`
        a1 += binned(k, alpha, wide)
        a0 += binned(k, alpha * start, wide)
    out += edges[None, :] * np.cumsum(a1, axis=1)[:, :ne] - np.cumsum(a0, axis=1)[:, :ne]
    # ... and the trapezoid's corrections within d of each end: a window narrower than a pixel,
    # so at most one boundary, and (as 2 w >= 1) never the other end's boundary.
    for kink in (c - w, c + w):
        k = first_edge_at_or_above(kink - d)
        z = np.clip(k, 0, ne - 1) - off - c
        out += at_edge(k, m * (_trapezoid_cdf(z, w, d) - _uniform_cdf(z, w)), wide)
    # Narrow intervals (support under 1.2 pixels): a step of m above the support, exact values inside.
    top = first_edge_at_or_above(c + w + d)
    out += np.cumsum(binned(top, m, narrow), axis=1)[:, :ne]
    k0 = first_edge_at_or_above(c - w - d)
    for k in (k0, k0 + 1):
        z = np.clip(k, 0, ne - 1) - off - c
        out += at_edge(k, m * _trapezoid_cdf(z, w, d), narrow & (k < top))
    return out


def sheared_disc_masses(l11: float, l21: float, l22: float,
                        pieces_per_px: int = PIECES_PER_PIXEL) -> np.ndarray:
    """Pixel masses of ``(a1, a2) = (l11 v1, l21 v1 + l22 v2)`` for ``(v1, v2)``
    uniform on the unit disc (``a`` in pixels, ``l11 > 0``, ``|l21| <= l11``).

    Given ``v1``, ``a2`` is uniform on ``l21 v1 +- |l22| sqrt(1 - v1^2)``, so
    its mass in each pixel along axis 2 is an exact interval overlap (a step
    when ``l22 = 0``: a line).  Along axis 1 the range of ``v1`` is cut into
    pieces (at every pixel boundary, and at ``sin`` of equal angles so that
    they are finer near the disc's rim, ``pieces_per_px`` per pixel) whose
    masses are exact (the marginal's CDF
    ``1/2 + (v sqrt(1 - v^2) + asin v) / pi``).  Within a piece the
    interval's centre moves linearly with ``v1`` (by at most
    ``1 / pieces_per_px`` pixel); taking ``v1`` as uniform within the piece,
    the law of ``a2`` is the interval at the piece's middle convolved with
    that motion (a trapezoid), whose CDF is evaluated exactly at the pixel
    boundaries, so a line crossing pixel rows is split between them
    correctly.  The sum over pieces of each column's CDF is accumulated in
    ``O(pieces + pixels)``: the piecewise-linear part as ramps by cumulative
    sums, the corrections near the interval's ends (at most two boundaries
    each) directly.  Returns ``(2 h2 + 1, 2 h1 + 1)`` masses indexed
    ``[a2, a1]``, centred, summing to 1.
    """
    l22 = abs(l22)
    h1 = int(math.ceil(l11 + 0.5))
    h2 = int(math.ceil(math.hypot(l21, l22) + 0.5))
    n1 = 2 * h1 + 1
    n_pieces = max(64, int(math.ceil(math.pi / 2 * pieces_per_px * 2.0 * l11)))
    v = np.sin(np.linspace(-math.pi / 2, math.pi / 2, n_pieces + 1))
    cuts = (np.arange(-h1, h1 + 1) + 0.5) / l11          # pixel boundaries a1 = i + 1/2
    v = np.unique(np.concatenate([v, cuts[np.abs(cuts) < 1.0], [-1.0, 1.0]]))
    cdf = 0.5 + (v * np.sqrt(np.maximum(1.0 - v * v, 0.0)) + np.arcsin(v)) / math.pi
    m = np.diff(cdf)
    mid = 0.5 * (v[1:] + v[:-1])
    col = np.clip(np.floor(l11 * mid + 0.5).astype(np.int64) + h1, 0, n1 - 1)
    c = l21 * mid                                             # centre of the interval along a2
    w = l22 * np.sqrt(np.maximum(1.0 - mid * mid, 0.0))       # its half-width
    d = 0.5 * abs(l21) * np.diff(v)                           # half the centre's motion over the piece
    return np.diff(_column_cdfs(col, m, c, w, d, n1, h2), axis=1).T

