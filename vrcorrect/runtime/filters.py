"""Separable low-rank filter banks: a 3 x 3 bank of 2-D filters as two 1-D passes.

The GLSL fallback runs the ``wiener`` correction (and the preview runs the eye's
forward model) as a bank ``out_i = sum_j F[i, j] * in_j`` of 2-D filters (``*``:
convolution; ``i`` output primary, ``j`` input primary).  A direct 2-D filter
costs ``S^2`` taps per pixel; here each input channel's three filters share one
set of horizontal profiles (a singular value decomposition of the three filters
stacked), so

    F[i, j](dy, dx) ~= sum_k  col[i, (j, k)](dy) * row[(j, k)](dx)

and the bank runs as a horizontal pass (one image per component ``(j, k)``)
followed by a vertical pass (each output sums all components): ``S * C`` taps
per pixel in the first pass and ``3 * S * C`` multiply-adds in the second, with
``C = sum_j rank_j``: linear in the filter width, not its area.  The rank of each
input channel is the smallest whose reconstruction error keeps every output
within ``tolerance``, the error measured as the largest gain of the difference
filter over spatial frequencies (``max_f |F(f) - F_r(f)|``, summed over the
inputs): the most by which any sinusoidal pattern of unit amplitude is changed.
(The absolute sum of the difference, the bound for adversarial inputs, asks for
about twice the rank for a difference no image shows.)

numpy only (layer 5, no GL here): :class:`SeparableBank` is what the GL code
uploads, and :func:`apply_separable` is its CPU twin for tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..plumbing.errors import ValidationError

__all__ = ["SeparableBank", "separable_bank", "apply_separable", "DEFAULT_RANK_TOLERANCE"]

DEFAULT_RANK_TOLERANCE = 1e-3
"""Largest reconstruction error (largest gain over frequencies, per output primary) of the bank."""


@dataclass(frozen=True, eq=False)
class SeparableBank:
    """A 3 x 3 filter bank as ``C`` separable components (see the module docstring).

    Attributes
    ----------
    channel
        ``(C,)`` int: the input primary each component reads.
    rows
        ``(C, S)`` float64 horizontal profiles, convolution order (index ``t`` is offset ``t - r``).
    cols
        ``(3, C, S)`` float64 vertical profiles per output primary, convolution order.
    ranks
        Components per input primary.
    error
        Largest over output primaries of the reconstruction error's largest gain over frequencies
        (summed over the inputs).
    """

    channel: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    ranks: tuple[int, int, int]
    error: float

    @property
    def size(self) -> int:
        """Filter width ``S`` (odd)."""
        return int(self.rows.shape[1])

    @property
    def radius(self) -> int:
        return self.size // 2

    @property
    def components(self) -> int:
        return int(self.rows.shape[0])

    @property
    def taps_per_pixel(self) -> int:
        """Multiply-adds per output pixel, both passes: ``S C`` + ``3 S C``."""
        return 4 * self.size * self.components

    def dense(self) -> np.ndarray:
        """The ``(3, 3, S, S)`` bank this decomposition stands for."""
        out = np.zeros((3, 3, self.size, self.size))
        for c in range(self.components):
            j = int(self.channel[c])
            out[:, j] += self.cols[:, c, :, None] * self.rows[c][None, None, :]
        return out


def separable_bank(taps: np.ndarray, tolerance: float = DEFAULT_RANK_TOLERANCE,
                   max_rank: int | None = None) -> SeparableBank:
    """Decompose a ``(3, 3, S, S)`` bank (outputs x inputs) into separable components.

    Parameters
    ----------
    taps
        The bank, centred, ``S`` odd (e.g. :func:`vrcorrect.solvers.wiener.correction_filters`).
    tolerance
        Largest allowed reconstruction error per output primary (largest gain over spatial
        frequencies of the difference filters, summed over the three inputs), > 0.
    max_rank
        Cap on the rank per input primary (default ``S``); the achieved error is reported.
    """
    taps = np.asarray(taps, dtype=np.float64)
    if taps.ndim != 4 or taps.shape[:2] != (3, 3) or taps.shape[2] != taps.shape[3] or taps.shape[2] % 2 != 1:
        raise ValidationError("taps", f"shape {taps.shape}", "a (3, 3, S, S) bank with S odd")
    if not np.isfinite(taps).all():
        raise ValidationError("taps", "non-finite values", "finite numbers")
    if not (isinstance(tolerance, (int, float)) and tolerance > 0 and np.isfinite(tolerance)):
        raise ValidationError("tolerance", tolerance, "a number > 0")
    S = taps.shape[-1]
    cap = S if max_rank is None else int(max_rank)
    if cap < 1:
        raise ValidationError("max_rank", max_rank, "an integer >= 1")
    budget = tolerance / 3.0                          # each input's share of an output's error
    channel, rows, cols, ranks = [], [], [], []
    worst = np.zeros(3)
    for j in range(3):
        stacked = taps[:, j].reshape(3 * S, S)        # the three outputs' filters, one above another
        U, sv, Vt = np.linalg.svd(stacked, full_matrices=False)
        chosen = min(cap, len(sv))
        err = np.zeros(3)
        approx = np.zeros_like(stacked)
        for r in range(0, min(cap, len(sv)) + 1):
            if r > 0:
                approx += sv[r - 1] * np.outer(U[:, r - 1], Vt[r - 1])
            diff = (stacked - approx).reshape(3, S, S)
            err = np.abs(np.fft.rfft2(diff, s=(2 * S, 2 * S))).max(axis=(1, 2))   # DTFT sampled 2x
            if err.max() <= budget:
                chosen = r
                break
        worst += err
        for k in range(chosen):
            channel.append(j)
            rows.append(Vt[k])
            cols.append((U[:, k] * sv[k]).reshape(3, S))
        ranks.append(chosen)
    if not rows:                                      # an all-zero bank: one zero component
        channel, rows, cols = [0], [np.zeros(S)], [np.zeros((3, S))]
    return SeparableBank(channel=np.array(channel, dtype=np.int32), rows=np.array(rows),
                         cols=np.moveaxis(np.array(cols), 0, 1), ranks=tuple(ranks), error=float(worst.max()))


def _mirror(index: np.ndarray, n: int) -> np.ndarray:
    """Mirrored-repeat indices (edge repeated, period 2n): OpenGL's ``MIRRORED_REPEAT``."""
    m = np.mod(index, 2 * n)
    return np.where(m < n, m, 2 * n - 1 - m)


def apply_separable(image: np.ndarray, bank: SeparableBank, border: str = "mirror") -> np.ndarray:
    """CPU twin of the GL passes: ``(H, W, 3)`` float image -> ``(H, W, 3)`` float64.

    ``border``: ``"mirror"`` (mirrored repeat) or ``"zero"`` (black outside).
    """
    if border not in ("mirror", "zero"):
        raise ValidationError("border", border, "'mirror' or 'zero'")
    img = np.asarray(image, dtype=np.float64)
    H, W = img.shape[:2]
    r = bank.radius
    offsets = np.arange(-r, r + 1)
    if border == "mirror":
        xs, ys = _mirror(np.arange(W)[:, None] - offsets[None, :], W), _mirror(np.arange(H)[:, None] - offsets[None, :], H)
        padded = img
    else:
        padded = np.pad(img, ((r, r), (r, r), (0, 0)))
        xs = np.arange(W)[:, None] - offsets[None, :] + r
        ys = np.arange(H)[:, None] - offsets[None, :] + r
    out = np.zeros((H, W, 3))
    for c in range(bank.components):
        j = int(bank.channel[c])
        src = padded[..., j]
        rows_src = src if border == "mirror" else src[r:r + H]
        h = np.einsum("ywt,t->yw", rows_src[:, xs], bank.rows[c])            # (H, W)
        hp = h if border == "mirror" else np.pad(h, ((r, r), (0, 0)))
        for i in range(3):
            out[..., i] += np.einsum("ytw,t->yw", hp[ys], bank.cols[i, c])
    return out
