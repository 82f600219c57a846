"""The per-frequency algebra every method shares, and the blur ``K x`` (numpy and scipy.fft; no torch).

The eye's kernel bank ``K[cone, primary, y, x]`` acts on a displayed image by convolution; by the
convolution theorem it is one 3x3 matrix per spatial frequency.  Spectra are stored as planes:
``(3, 3, NY, NX // 2 + 1)`` (cones x primaries, then the real-to-complex frequencies), images as
``(3, H, W)``, and every 3x3 operation below works plane by plane (a loop over nine planes is far
faster than a batched ``np.linalg`` call on 3x3 blocks).

* Grids: :func:`smooth_length` (the smallest FFT length of small prime factors, 2, 3 and 5, at least
  a given one: the real-time path's mixed-radix grids), :func:`padded_shape` (room for a linear
  convolution, no wrap-around), :func:`margin_shape`
  (room for a mirrored border), :func:`centred_kernel`
  (the kernel's centre wrapped to the origin, so no shift), :func:`kernel_spectrum`,
  :func:`mirror_fill` (an image and its mirrored repeat, the one-pass filters' borders).
* 3x3 per frequency: :func:`apply3` (matrix times vector, with ``out=`` for the loops that must
  not allocate), :func:`matmul3`, :func:`conj_transpose`, :func:`gram` (``K^H K``), :func:`inv3`
  and :func:`hermitian_inverse` (``(K^H K + n I)^-1``), :func:`spectral_norm_squared` (``||K||^2``).
* :class:`Blur`: ``K x`` with a black surround (the objective's forward model,
  :func:`vrcorrect.solvers.objective`) and its adjoint ``K^H r``, used by ``wiener``, ``fast``, FISTA
  and the CPU twins of the real-time iterations.  (``paper`` and ``conventional`` need autograd:
  :class:`vrcorrect.solvers.iterative.FftOperator` is the same operator in torch.)

Layer 4: numpy and scipy.fft only, so the real-time path may import it.
"""

from __future__ import annotations

import numpy as np
import scipy.fft

from ..plumbing.errors import ValidationError

__all__ = ["FFT_PRIMES", "smooth_length", "padded_shape", "margin_shape", "centred_kernel", "kernel_spectrum",
           "mirror_fill", "rfft_grid",
           "irfft_grid", "apply3", "matmul3", "conj_transpose", "gram", "inv3", "hermitian_inverse",
           "spectral_norm_squared", "Blur"]


# ---------------------------------------------------------------------------------------------- grids

FFT_PRIMES = (2, 3, 5)
"""The prime factors a GPU line transform handles (radix 2, 3, 4, 5 and 8 butterflies,
``shaders/fft_line.glsl``): its lengths are 5-smooth."""


def smooth_length(n: int, primes: tuple[int, ...] = FFT_PRIMES) -> int:
    """The smallest integer at least ``n`` (and at least 1) whose prime factors are all in ``primes``
    (by default 5-smooth: 2^a 3^b 5^c)."""
    if not primes or any(int(p) < 2 for p in primes):
        raise ValidationError("primes", primes, "one or more integers of at least 2")
    m = max(1, int(n))
    while True:
        rest = m
        for p in primes:
            while rest % p == 0:
                rest //= p
        if rest == 1:
            return m
        m += 1


def padded_shape(height: int, width: int, kernel_size: int) -> tuple[int, int]:
    """FFT size that holds a linear convolution of the image with the kernel without wrap-around."""
    return (scipy.fft.next_fast_len(height + kernel_size - 1, real=True),
            scipy.fft.next_fast_len(width + kernel_size - 1, real=True))


def margin_shape(height: int, width: int, margin: int) -> tuple[int, int]:
    """FFT size that holds the image with ``margin`` pixels on each side (a mirror-filled border:
    :func:`mirror_fill`)."""
    return (scipy.fft.next_fast_len(height + 2 * margin, real=True),
            scipy.fft.next_fast_len(width + 2 * margin, real=True))


def centred_kernel(kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``(..., s, s)`` kernel zero-padded to ``shape`` with its centre wrapped to the origin,
    so the circular convolution on that grid has no shift."""
    s = kernel.shape[-1]
    out = np.zeros(kernel.shape[:-2] + tuple(shape), dtype=kernel.dtype)
    ys = (np.arange(s) - s // 2) % shape[0]
    xs = (np.arange(s) - s // 2) % shape[1]
    out[..., ys[:, None], xs[None, :]] = kernel
    return out


def kernel_spectrum(kernel: np.ndarray, grid: tuple[int, int], dtype=np.float64) -> np.ndarray:
    """The real-to-complex spectrum ``(3, 3, NY, NX // 2 + 1)`` of a ``(3, 3, s, s)`` kernel centred on
    the origin of ``grid``, computed from the kernel in ``dtype`` (float64: complex128; float32:
    complex64)."""
    return scipy.fft.rfft2(centred_kernel(np.asarray(kernel, dtype), grid), axes=(-2, -1), workers=-1)


def mirror_fill(image_chw: np.ndarray, shape: tuple[int, int], margin: int) -> np.ndarray:
    """The image on a periodic ``shape`` grid at offset ``(margin, margin)``, the rest of the grid
    filled by mirrored repeat (edge pixel repeated, period twice the image)."""
    _, H, W = image_chw.shape

    def mirror(i, n):
        m = np.mod(i, 2 * n)
        return np.where(m < n, m, 2 * n - 1 - m)

    ys = mirror(np.arange(shape[0]) - margin, H)
    xs = mirror(np.arange(shape[1]) - margin, W)
    return image_chw[:, ys[:, None], xs[None, :]]


def rfft_grid(x: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Real-to-complex transform of ``(..., h, w)`` planes on ``grid`` (zero-padded to it)."""
    return scipy.fft.rfft2(x, s=grid, axes=(-2, -1), workers=-1)


def irfft_grid(X: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """The inverse of :func:`rfft_grid`: ``(..., NY, NX)`` real planes."""
    return scipy.fft.irfft2(X, s=grid, axes=(-2, -1), workers=-1)


# --------------------------------------------------------------------------------- 3x3 per frequency


def apply3(M: np.ndarray, x: np.ndarray, out: np.ndarray | None = None, tmp: np.ndarray | None = None
           ) -> np.ndarray:
    """Per-frequency matrix-vector product ``out[i] = sum_j M[i, j] x[j]`` for ``M`` ``(3, 3, ...)``
    and ``x`` ``(3, ...)``; the sum is taken in the order ``j = 0, 1, 2``.

    ``out`` (``(3, ...)``, not aliasing ``x``) and ``tmp`` (one plane) are preallocated buffers for
    loops that must not allocate; without them both are allocated here (``out`` like ``x``)."""
    if out is None:
        out = np.empty_like(x)
    if tmp is None:
        tmp = np.empty_like(out[0])
    for i in range(3):
        np.multiply(M[i, 0], x[0], out=out[i])
        for j in (1, 2):
            np.multiply(M[i, j], x[j], out=tmp)
            out[i] += tmp
    return out


def matmul3(A, B, conj_a: bool = False, transpose_a: bool = False):
    """Per-frequency product of 3x3 plane stacks: ``out[i, j] = sum_k op(A)[i, k] B[k, j]``
    with ``op`` an optional conjugate and/or transpose."""
    out = B * 0
    for i in range(3):
        for j in range(3):
            acc = None
            for k in range(3):
                a = A[k, i] if transpose_a else A[i, k]
                if conj_a:
                    a = a.conj()
                term = a * B[k, j]
                acc = term if acc is None else acc + term
            out[i, j] = acc
    return out


def conj_transpose(M: np.ndarray) -> np.ndarray:
    """``M^H`` per frequency: ``(3, 3, ...)`` planes with the first two axes swapped and conjugated
    (``K^H``: primaries x cones)."""
    return np.conj(np.swapaxes(M, 0, 1))


def gram(Kf):
    """``K^H K`` per frequency for spectra stored as planes ``(cones, primaries, ...)``."""
    return matmul3(Kf, Kf, conj_a=True, transpose_a=True)


def inv3(M):
    """Inverse of 3x3 matrices stored as planes ``(3, 3, ...)``, by cofactors."""
    a, b, c = M[0, 0], M[0, 1], M[0, 2]
    d, e, f = M[1, 0], M[1, 1], M[1, 2]
    g, h, i = M[2, 0], M[2, 1], M[2, 2]
    A_, B_, C_ = e * i - f * h, f * g - d * i, d * h - e * g
    inv_det = 1.0 / (a * A_ + b * B_ + c * C_)
    out = M * 0
    out[0, 0], out[0, 1], out[0, 2] = A_ * inv_det, (c * h - b * i) * inv_det, (b * f - c * e) * inv_det
    out[1, 0], out[1, 1], out[1, 2] = B_ * inv_det, (a * i - c * g) * inv_det, (c * d - a * f) * inv_det
    out[2, 0], out[2, 1], out[2, 2] = C_ * inv_det, (b * g - a * h) * inv_det, (a * e - b * d) * inv_det
    return out


def hermitian_inverse(Kf: np.ndarray, n: float) -> np.ndarray:
    """``(K^H K + n I)^-1`` per frequency for ``K`` stored as ``(3, 3, ...)`` planes, by cofactors of
    the Hermitian matrix (:func:`gram`, :func:`inv3`), in ``Kf``'s precision: ADMM's ``u`` step
    (``n = ||K||^2``) and a ridge inverse (``n = mu``)."""
    M = gram(Kf)
    for c in range(3):
        M[c, c] += n
    return inv3(M)


def spectral_norm_squared(kernel: np.ndarray) -> float:
    """Largest eigenvalue of K^H K over all frequencies (the kernel's spectral norm squared).

    The kernel is non-negative, so ``|K(f)| <= K(0) = A`` entrywise and, by
    Perron-Frobenius monotonicity, ``||K(f)|| <= ||A||``: the maximum is at DC.
    """
    return float(np.linalg.norm(kernel.sum(axis=(-2, -1)), 2) ** 2)


# ---------------------------------------------------------------------------------------------- the blur


class Blur:
    """The blur ``y_k = sum_c K[k, c] * x_c`` of ``(3, H, W)`` images (true convolution, black
    outside the image: the objective's forward model) and its adjoint, by real FFTs on ``grid``.

    Parameters
    ----------
    spectrum
        The kernel's spectrum on ``grid`` (:func:`kernel_spectrum`; complex128 or complex64, which
        sets the arithmetic's precision with the input's).
    grid
        ``(NY, NX)``, at least the image plus the kernel less one on each axis (:func:`padded_shape`,
        or the real-time path's 5-smooth grid, :func:`vrcorrect.solvers.realtime.admm_grid`), so
        nothing wraps around.
    shape
        The images' ``(H, W)``; the image sits at the grid's origin.
    """

    def __init__(self, spectrum: np.ndarray, grid: tuple[int, int], shape: tuple[int, int]):
        self.spectrum = spectrum
        self.grid = (int(grid[0]), int(grid[1]))
        self.shape = (int(shape[0]), int(shape[1]))

    @classmethod
    def of(cls, kernel: np.ndarray, shape: tuple[int, int], grid: tuple[int, int] | None = None,
           dtype=np.float64) -> "Blur":
        """The blur of a ``(3, 3, s, s)`` kernel for images of ``shape``, on ``grid`` (default
        :func:`padded_shape`), its spectrum computed in ``dtype`` (:func:`kernel_spectrum`)."""
        H, W = shape
        grid = padded_shape(H, W, kernel.shape[-1]) if grid is None else grid
        return cls(kernel_spectrum(kernel, grid, dtype), grid, shape)

    def apply(self, x: np.ndarray, out: np.ndarray | None = None, tmp: np.ndarray | None = None,
              crop: bool = True) -> np.ndarray:
        """``K x`` for ``x`` ``(3, H, W)`` (or already on the grid, zero outside the image):
        ``(3, H, W)``, or the whole grid without ``crop``.  ``out``/``tmp``: :func:`apply3`'s
        spectral buffers."""
        y = irfft_grid(apply3(self.spectrum, rfft_grid(x, self.grid), out, tmp), self.grid)
        return y[:, :self.shape[0], :self.shape[1]] if crop else y

    def adjoint(self, r: np.ndarray) -> np.ndarray:
        """``K^H C^H r``: a ``(3, H, W)`` cone residual back on the image's primaries, ``(3, H, W)``
        (``C`` the crop to the image)."""
        y = irfft_grid(apply3(conj_transpose(self.spectrum), rfft_grid(r, self.grid)), self.grid)
        return y[:, :self.shape[0], :self.shape[1]]
