"""Closed-form correction in one pass (numpy only; the GLSL fallback's mathematics).

Per spatial frequency f, with the eye's 3x3 kernel spectrum ``K(f)`` (cones x
primaries), solve the regularised system

    (K^H K + mu I) x(f) = K^H t'(f),      (t: target cone image)

then clip ``v = W t`` to [0, 1] and blend it with the target by the weight that
minimises the true objective (closed form).  ``mu`` (relative to the largest
eigenvalue of ``K^H K``) is chosen from a few values; the blend weight 0 is no
correction, so the result is never worse than no correction.  Contrast
compression of the target is the separate ``contrast`` option of every method.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.fft

from . import Problem

DEFAULT_REGULARISATION = (0.01, 0.03, 0.1, 0.3)


def padded_shape(height: int, width: int, kernel_size: int) -> tuple[int, int]:
    """FFT size that holds a linear convolution of the image with the kernel without wrap-around."""
    return (scipy.fft.next_fast_len(height + kernel_size - 1, real=True),
            scipy.fft.next_fast_len(width + kernel_size - 1, real=True))


def centred_kernel(kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``(..., s, s)`` kernel zero-padded to ``shape`` with its centre wrapped to the origin,
    so the circular convolution on that grid has no shift."""
    s = kernel.shape[-1]
    out = np.zeros(kernel.shape[:-2] + tuple(shape))
    out[..., :s, :s] = kernel
    return np.roll(out, (-(s // 2), -(s // 2)), axis=(-2, -1))


def spectral_norm_squared(kernel: np.ndarray) -> float:
    """Largest eigenvalue of K^H K over all frequencies (the kernel's spectral norm squared).

    The kernel is non-negative, so ``|K(f)| <= K(0) = A`` entrywise and, by
    Perron-Frobenius monotonicity, ``||K(f)|| <= ||A||``: the maximum is at DC.
    """
    return float(np.linalg.norm(kernel.sum(axis=(-2, -1)), 2) ** 2)


def _padded_spectra(problem: Problem):
    H, W = problem.target.shape[:2]
    P = padded_shape(H, W, problem.kernel.size)
    Kf = scipy.fft.rfft2(centred_kernel(problem.kernel.kernel, P), axes=(2, 3), workers=-1)   # (3, 3, P0, F1)
    # target cone image extended by mirror reflection, so the borders do not ring
    t = np.pad(problem.target_lms.astype(np.float64), ((0, P[0] - H), (0, P[1] - W), (0, 0)), mode="symmetric")
    Tf = scipy.fft.rfft2(np.moveaxis(t, 2, 0), axes=(1, 2), workers=-1)  # (3, P0, F1)
    return Kf, Tf, P


def inv3(M):
    """Inverse of 3x3 matrices stored as planes ``(3, 3, ...)``, by cofactors (numpy or torch)."""
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


def matmul3(A, B, conj_a: bool = False, transpose_a: bool = False):
    """Per-frequency product of 3x3 plane stacks: ``out[i, j] = sum_k op(A)[i, k] B[k, j]``
    with ``op`` an optional conjugate and/or transpose (numpy or torch)."""
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


def apply3(M, x):
    """Per-frequency matrix-vector product ``out[i] = sum_j M[i, j] x[j]`` (numpy or torch)."""
    out = x * 0
    for i in range(3):
        out[i] = M[i, 0] * x[0] + M[i, 1] * x[1] + M[i, 2] * x[2]
    return out


def gram(Kf):
    """``K^H K`` per frequency for spectra stored as planes ``(cones, primaries, ...)``."""
    return matmul3(Kf, Kf, conj_a=True, transpose_a=True)


def _inverse_from_spectrum(Kf: np.ndarray, mu_rel: float, lam_max: float) -> np.ndarray:
    """``W = (K^H K + mu I)^-1 K^H`` as planes (primaries, cones, ...)."""
    M = gram(Kf)
    for c in range(3):
        M[c, c] += mu_rel * lam_max
    return matmul3(inv3(M), np.conj(np.swapaxes(Kf, 0, 1)))


class _FastObjective:
    """The objective with the kernel's spectrum computed once (exact linear convolution, zero outside)."""

    def __init__(self, problem: Problem, Kf: np.ndarray, P: tuple[int, int]):
        self.Kf, self.P = Kf, P
        self.H, self.W = problem.target.shape[:2]
        self.t = np.moveaxis(problem.target_lms.astype(np.float64), 2, 0)

    def residual(self, x_chw: np.ndarray, offset: bool = True) -> np.ndarray:
        """``K x - t`` on the image (or ``K x`` without ``offset``), (3, H, W)."""
        X = scipy.fft.rfft2(x_chw, s=self.P, axes=(1, 2), workers=-1)
        y = scipy.fft.irfft2(apply3(self.Kf, X), s=self.P, axes=(1, 2), workers=-1)
        y = y[:, :self.H, :self.W]
        return y - self.t if offset else y


def wiener(problem: Problem, regularisation: Sequence[float] = DEFAULT_REGULARISATION) -> tuple[np.ndarray, dict]:
    """Best blend of the target and the clipped regularised inverse; returns (image, settings).

    For each ``mu_rel`` in ``regularisation``: ``v = W t`` clipped to [0, 1],
    then ``x = t + beta (clip(v) - t)`` with ``beta`` in [0, 1] minimising the
    objective in closed form (it is quadratic in ``beta``, and every blend of two
    images in [0, 1] stays in [0, 1]).  ``beta = 0`` is no correction, so the
    result is never worse than no correction.
    """
    H, W = problem.target.shape[:2]
    if problem.kernel.size == 1:
        x = np.clip(problem.target_lms @ np.linalg.inv(problem.kernel.matrix).T, 0, 1).astype(np.float32)
        return x, {"chosen": "colour matrix (identity kernel)", "beta": 1.0, "mu_rel": 0.0}
    Kf, Tf, P = _padded_spectra(problem)
    f = _FastObjective(problem, Kf, P)
    t_rgb = np.moveaxis(problem.target.astype(np.float64), 2, 0)
    r0 = f.residual(t_rgb)
    best = (float(np.mean(r0 * r0)), t_rgb, {"chosen": "no correction", "beta": 0.0, "mu_rel": None})
    lam_max = spectral_norm_squared(problem.kernel.kernel)
    tried = []
    for mu_rel in regularisation:
        Wf = _inverse_from_spectrum(Kf, mu_rel, lam_max)                 # (3 prim, 3 cones, P0, F1)
        v = scipy.fft.irfft2(apply3(Wf, Tf), s=P, axes=(1, 2), workers=-1)[:, :H, :W]
        d = np.clip(v, 0.0, 1.0) - t_rgb
        Kd = f.residual(d, offset=False)
        denom = float(np.sum(Kd * Kd))
        beta = float(np.clip(-np.sum(r0 * Kd) / denom, 0.0, 1.0)) if denom > 0 else 0.0
        x = t_rgb + beta * d
        res = r0 + beta * Kd
        obj = float(np.mean(res * res))
        tried.append({"mu_rel": mu_rel, "beta": beta, "objective": obj,
                      "clipped_fraction": float(np.mean((v < 0) | (v > 1)))})
        if obj < best[0]:
            best = (obj, x, {"chosen": "blend of target and clipped regularised inverse", "beta": beta,
                             "mu_rel": mu_rel})
    settings = dict(best[2])
    settings["candidates"] = tried
    return np.clip(np.moveaxis(best[1], 0, 2), 0.0, 1.0).astype(np.float32), settings
