"""The ``fast`` method: box-constrained least squares by ADMM (numpy and scipy.fft; no torch).

``min ||C K x - t||^2`` subject to ``0 <= x <= 1`` inside the image and ``x = 0``
outside, with ``K`` the eye's 3x3 kernel bank (cones x primaries), ``C`` the crop
to the image and ``t`` the target's cone image: the same objective as ``paper``.
A robust design's problem (``Problem.capped``) has ``x <= light_cap(target)`` instead of
``x <= 1`` (:func:`~vrcorrect.solvers.problem.light_cap`): the same clip, per pixel.

Split (Almeida & Figueiredo 2013, boundary-aware deconvolution): on a padded
periodic domain, ``v = K u`` (the retina, cropped by ``C`` only in the data term)
and ``z = u`` (the box and the black surround).  Each step is exact and cheap:
``u`` by one 3x3 solve per frequency, ``(K^H K + n I)^-1`` with ``n = ||K||^2``
the kernel's spectral norm squared (at DC, since K >= 0), ``v`` per pixel, ``z`` by
clipping; over-relaxed.

Warm start, coarse to fine: a closed-form start on the coarsest of ``levels``
halvings (2x2 blocks, with the kernel those blocks see: :func:`coarse_kernel`), the
ridge inverse of the cone target (regularised toward zero, unlike ``wiener``'s), clipped
and blended with the target by the weight that minimises the objective
(:func:`_ridge_start`); ADMM there, then on each finer level, upsampling the image
and ADMM's scaled duals both (with zero duals the finer level first loses ground;
with the coarse duals its first iteration is already below what the paper's 100
Adam steps reach on the evaluation images).

Stopping: the true objective at the feasible ``z`` after every full-resolution
iteration; the best ``z`` so far is kept and returned; stop when an iteration lowers
the best by less than ``tolerance`` (relative), or after :data:`PATIENCE` iterations
without a new best (over-relaxed ADMM is not monotone, so a rise alone does not stop
it).  On the paper's evaluation (35 cases at 512x512) the default, 1e-2, stops after 5
iterations on average and ends below ``paper``'s objective in 23 cases, at most 2 % above
it in the others; 3e-3: 32 of 35, at most 0.25 % above, 10 iterations; 1e-3: 33 of 35, 14.

float32 images, complex64 spectra, scipy's FFT (several times faster than torch's on
this kind of CPU), the per-frequency algebra and the blur of :mod:`vrcorrect.solvers.spectral`;
numpy only, so ``fast`` runs wherever numpy does.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .problem import LIGHT_CAP_FLOOR, Correction, Problem, guard_weight, light_cap, objective
from .spectral import (Blur, apply3, conj_transpose, hermitian_inverse, irfft_grid, kernel_spectrum, margin_shape,
                       mirror_fill, padded_shape, rfft_grid, spectral_norm_squared)

__all__ = ["fast", "fast_start", "FAST_RHO", "FAST_RELAXATION", "coarse_kernel", "coarse_level_pays", "COARSE_ITERATIONS"]

#: ``fast``'s penalty (relative to ``||K||^2``) and over-relaxation: its defaults, :func:`fast_start`'s and
#: the unrolled correction's starting settings (:mod:`vrcorrect.learn.unrolled`).
FAST_RHO = 0.1
FAST_RELAXATION = 1.8
#: Full-resolution iterations in a row without a new best objective after which ``fast`` stops.
PATIENCE = 5
#: ADMM iterations on the coarsest level of ``fast``'s coarse-to-fine start (and of the real-time
#: path's cold frames, :class:`vrcorrect.solvers.realtime.AdmmFrames`).
COARSE_ITERATIONS = 15


def coarse_level_pays(height: int, width: int, kernel_size: int) -> bool:
    """Whether a half-resolution level is worth solving first: the image at least 64 px on its short
    side and the kernel at least 9 px (a smaller kernel's blur is solved as fast at full size)."""
    return min(height, width) >= 64 and kernel_size >= 9


def _admm(kernel: np.ndarray, t_lms: np.ndarray, z0: np.ndarray, rho: float, relaxation: float,
          balance: float, max_iterations: int, tolerance: float,
          progress: Callable[[int, int], None] | None = None,
          duals: tuple[np.ndarray, np.ndarray] | None = None, track: bool = True,
          upper: np.ndarray | None = None
          ) -> tuple[np.ndarray, int, list[float], float, tuple[np.ndarray, np.ndarray]]:
    """ADMM on (3, H, W) float32 arrays, optionally warm-started in the scaled duals too (inside
    the image; zero outside); returns (z, iterations, history, norm2, duals cropped to the image).
    ``upper``: the box's upper end inside the image, ``(3, H, W)`` (the light cap,
    :func:`~vrcorrect.solvers.problem.light_cap`; None: 1).

    With ``track``, ``history`` holds the true objective at the feasible ``z`` after every
    iteration (one more convolution per step) and the loop stops when one iteration improves it
    by less than ``tolerance`` (relative; 0: never); without it (the coarse levels) it runs
    ``max_iterations``.  The loop works in preallocated buffers: fresh multi-megabyte
    temporaries per step cost more in page faults than the arithmetic.
    """
    H, W = t_lms.shape[1:]
    P = padded_shape(H, W, kernel.shape[-1])
    K = Blur(kernel_spectrum(kernel, P, np.float32), P, (H, W))           # complex64 (cones, primaries, P0, F1)
    Kf = K.spectrum
    norm2 = spectral_norm_squared(kernel) * balance           # box split weighed against the retina split
    G = hermitian_inverse(Kf, norm2)                                       # (K^H K + n I)^-1
    Kh = np.ascontiguousarray(conj_transpose(Kf))                          # (primaries, cones, P0, F1)
    spec = Kf.shape[2:]
    R = np.empty((3,) + spec, np.complex64)                               # spectral buffers
    U = np.empty_like(R)
    KU = np.empty_like(R)
    ctmp = np.empty(spec, np.complex64)
    a = np.empty((3,) + P, np.float32)                                    # spatial buffers
    z = np.zeros((3,) + P, np.float32)
    z[:, :H, :W] = z0
    v = K.apply(z, KU, ctmp, crop=False).astype(np.float32)
    d1 = np.zeros_like(v)
    d2 = np.zeros_like(z)
    if duals is not None:
        d1[:, :H, :W] = duals[0]
        d2[:, :H, :W] = duals[1]
    n = float(H * W * 3)
    rho_eff = rho * norm2
    t_scaled = (2.0 / (2.0 + rho_eff)) * t_lms                             # the v-step inside the image:
    keep = np.float32(rho_eff / (2.0 + rho_eff))                           # v = (2 t + rho s) / (2 + rho)
    alpha, beta = np.float32(relaxation), np.float32(1.0 - relaxation)
    history: list[float] = []
    iterations = 0
    best, stale = np.inf, 0
    best_z = np.empty((3, H, W), np.float32) if track else None
    for it in range(1, max_iterations + 1):
        np.subtract(v, d1, out=a)
        apply3(Kh, rfft_grid(a, P), R, ctmp)                               # R = K^H F(v - d1) + n F(z - d2)
        np.subtract(z, d2, out=a)
        Fb = rfft_grid(a, P)
        Fb *= np.float32(norm2)
        R += Fb
        apply3(G, R, U, ctmp)                                              # U = (K^H K + n I)^-1 R
        apply3(Kf, U, KU, ctmp)
        u = irfft_grid(U, P)
        Ku = irfft_grid(KU, P)
        if relaxation != 1.0:                                              # over-relaxation (Eckstein & Bertsekas)
            Ku *= alpha
            Ku += np.multiply(v, beta, out=a)
            u *= alpha
            u += np.multiply(z, beta, out=a)
        np.add(Ku, d1, out=v)                                              # v: retina, data term inside only
        inner = v[:, :H, :W]
        inner *= keep
        inner += t_scaled
        np.add(u, d2, out=z)                                               # z: box inside, black outside
        np.clip(z, 0.0, 1.0, out=z)
        if upper is not None:
            np.minimum(z[:, :H, :W], upper, out=z[:, :H, :W])
        z[:, H:, :] = 0.0
        z[:, :H, W:] = 0.0
        d1 += Ku
        d1 -= v
        d2 += u
        d2 -= z
        iterations = it
        if progress is not None:
            progress(it, max_iterations)
        if track:                                                          # the objective at z
            r = K.apply(z, KU, ctmp) - t_lms
            value = float(np.vdot(r, r)) / n
            history.append(value)
            if value < best:
                gain, best, stale = best - value, value, 0
                np.copyto(best_z, z[:, :H, :W])
                if tolerance > 0 and it > 1 and gain <= tolerance * (best + gain):
                    break
            else:                                                          # over-relaxed ADMM is not monotone:
                stale += 1                                                 # a rise is no sign of convergence
                if tolerance > 0 and stale >= PATIENCE:
                    break
    z_out = best_z if track else z[:, :H, :W].copy()
    return z_out, iterations, history, norm2, (d1[:, :H, :W].copy(), d2[:, :H, :W].copy())


def coarse_kernel(kernel: np.ndarray) -> np.ndarray:
    """The kernel seen by an image of half the resolution (2x2 pixel blocks): the kernel
    convolved with the two box pixels ([1,2,1]/4 per axis) and sampled every second pixel
    about its centre; sums kept equal to the fine kernel's (scaled, for a non-negative plane; the
    difference added at the centre, for a signed one: a robust design's effective kernels,
    :mod:`vrcorrect.physics.robust`)."""
    tri = np.array([0.25, 0.5, 0.25])
    k = kernel
    k = np.apply_along_axis(lambda v: np.convolve(v, tri), -1, k)
    k = np.apply_along_axis(lambda v: np.convolve(v, tri), -2, k)
    c = k.shape[-1] // 2
    half = c // 2
    idx = c + 2 * np.arange(-half, half + 1)
    out = k[..., idx[:, None], idx[None, :]]
    sums = out.sum(axis=(-2, -1), keepdims=True)
    want = kernel.sum(axis=(-2, -1), keepdims=True)
    scale = (sums > 0) & (want > 0)                                     # a physical kernel's planes
    out = out * np.where(scale, want / np.where(scale, sums, 1), 1)
    if not scale.all():                                                # signed planes (an effective kernel's) and
        out[..., half, half] += np.where(scale, 0, want - out.sum(axis=(-2, -1), keepdims=True))[..., 0, 0]
    return out                                                         # zero ones: the sum restored at the centre


def _pool2(a: np.ndarray) -> np.ndarray:
    """2x2 block means of a (3, H, W) array (odd last row/column dropped)."""
    H2, W2 = a.shape[1] // 2 * 2, a.shape[2] // 2 * 2
    b = a[:, :H2, :W2]
    return (0.25 * (b[:, 0::2, 0::2] + b[:, 1::2, 0::2] + b[:, 0::2, 1::2] + b[:, 1::2, 1::2])).astype(np.float32)


def _upsample2(a: np.ndarray) -> np.ndarray:
    """Bilinear 2x upsampling of a (3, h, w) array with pixel centres aligned as block means:
    output pixel 2k sits at k - 1/4, 2k + 1 at k + 1/4 (edges repeated)."""
    def axis(x: np.ndarray, ax: int) -> np.ndarray:
        n = x.shape[ax]
        prev = np.take(x, np.maximum(np.arange(n) - 1, 0), axis=ax)
        nxt = np.take(x, np.minimum(np.arange(n) + 1, n - 1), axis=ax)
        even, odd = 0.75 * x + 0.25 * prev, 0.75 * x + 0.25 * nxt
        out = np.stack([even, odd], axis=ax + 1)
        shape = list(x.shape)
        shape[ax] = 2 * n
        return out.reshape(shape)

    return axis(axis(a, 1), 2).astype(np.float32)


def _coarse_to_fine(kernel: np.ndarray, target: np.ndarray, t_lms: np.ndarray, levels: int, coarse_iterations: int,
                    level_iterations: int, rho: float, relaxation: float,
                    balance: float, warm_start: bool, capped: bool = False
                    ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None, list[str]]:
    """Starting point at this resolution, primal and dual (see the module docstring); ``capped``:
    the box's upper end is the light cap of this level's target."""
    H, W = t_lms.shape[1:]
    upper = light_cap(target) if capped else None
    if levels > 0 and coarse_level_pays(H, W, kernel.shape[-1]):
        Kc = coarse_kernel(kernel)
        coarse_target = _pool2(target)
        zc, dc, notes = _coarse_to_fine(Kc, coarse_target, _pool2(t_lms), levels - 1, coarse_iterations,
                                        level_iterations, rho, relaxation, balance, warm_start, capped)
        deeper = dc is not None
        its = level_iterations if deeper else coarse_iterations
        zc, done, _, _, dc = _admm(Kc, _pool2(t_lms), zc, rho, relaxation, balance, its, 0.0, duals=dc,
                                   track=False, upper=light_cap(coarse_target) if capped else None)
        notes.append(f"{done} ADMM iterations at {zc.shape[2]}x{zc.shape[1]}")
        H2, W2 = H // 2 * 2, W // 2 * 2

        def up(a: np.ndarray, fill: np.ndarray) -> np.ndarray:
            out = fill.copy()
            out[:, :H2, :W2] = _upsample2(a)
            return out

        zero = np.zeros_like(target)
        return np.clip(up(zc, target), 0.0, 1.0 if upper is None else upper), (up(dc[0], zero), up(dc[1], zero)), notes
    if not warm_start:
        return target.copy(), None, ["target"]
    return _ridge_start(kernel, target, t_lms, upper=upper), None, ["regularised inverse blended with the target"]


def _ridge_start(kernel: np.ndarray, target: np.ndarray, t_lms: np.ndarray, mu_rel: float = 0.03,
                 upper: np.ndarray | None = None) -> np.ndarray:
    """Closed-form start: the ridge inverse of the cone target, regularised toward zero,
    ``d = clip((K^H K + mu I)^-1 K^H t_lms) - t`` (``mu`` relative to ``||K||^2``), on a periodic
    grid holding ``t_lms`` mirror-filled around the image (one kernel width each side), then the
    blend ``t + beta d`` with the weight ``beta`` in [0, 1] that minimises the objective (closed
    form, :func:`~vrcorrect.solvers.guard_weight`, the blend ``wiener`` and the real-time guard
    use), so the start is never worse than the target itself; float32.

    Not ``wiener``'s inverse: that one is regularised toward the target (``F(0) = I``, a flat field
    kept), this one toward zero, which shrinks a flat field along the colour matrix's weak
    directions (docs/architecture.md, 'Regularise toward the target'); here it is only a starting
    point, which the blend keeps no worse than the target and ADMM's iterations then improve.
    ``upper``: the box's upper end (the light cap; None: 1), which the inverse is clipped to."""
    _, H, W = t_lms.shape
    m = kernel.shape[-1]
    Q = margin_shape(H, W, m)
    K = Blur(kernel_spectrum(kernel, Q, np.float32), Q, (H, W))          # black surround (Q > H + m)
    G = hermitian_inverse(K.spectrum, mu_rel * spectral_norm_squared(kernel))
    R = apply3(conj_transpose(K.spectrum), rfft_grid(mirror_fill(t_lms, Q, m), Q))
    d = np.clip(irfft_grid(apply3(G, R), Q)[:, m:m + H, m:m + W], 0.0, 1.0 if upper is None else upper) - target
    r0, Kd = K.apply(target) - t_lms, K.apply(d)
    beta = guard_weight(float(np.vdot(r0, Kd)), float(np.vdot(Kd, Kd)))
    return (target + np.float32(beta) * d).astype(np.float32)


def fast_start(kernel: np.ndarray, target: np.ndarray, t_lms: np.ndarray, levels: int = 1,
               rho: float = FAST_RHO, relaxation: float = FAST_RELAXATION, capped: bool = False
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where :func:`fast`'s full-resolution iterations start, with its default settings: the
    primal ``z0`` and the scaled duals ``(d1, d2)`` inside the image, each ``(3, H, W)`` float32
    for a ``(3, H, W)`` linear ``target`` and its cone image ``t_lms``. The coarse level's solution
    and duals where that level pays (:func:`coarse_level_pays`), else the closed-form start and zero
    duals. ``capped``: in the box under the light cap, as ``fast`` starts a robust design. The
    unrolled correction (:mod:`vrcorrect.learn.unrolled`) starts its stages here."""
    z0, duals, _ = _coarse_to_fine(kernel, np.asarray(target, np.float32), np.asarray(t_lms, np.float32), levels,
                                   COARSE_ITERATIONS, 3, rho, relaxation, 1.0, True, capped)
    if duals is None:
        zero = np.zeros_like(z0, dtype=np.float32)
        duals = (zero, zero.copy())
    return (np.ascontiguousarray(z0, np.float32), np.ascontiguousarray(duals[0], np.float32),
            np.ascontiguousarray(duals[1], np.float32))


def fast(problem: Problem, tolerance: float = 1e-2, max_iterations: int = 200, rho: float = FAST_RHO,
         relaxation: float = FAST_RELAXATION, balance: float = 1.0, levels: int = 1,
         coarse_iterations: int = COARSE_ITERATIONS, level_iterations: int = 3, warm_start: bool = True,
         progress: Callable[[int, int], None] | None = None) -> Correction:
    """ADMM for the LMS objective in the box (see the module docstring).  Stops when an iteration
    lowers the best objective by less than ``tolerance`` (relative), after :data:`PATIENCE`
    iterations without a new best, or after ``max_iterations`` on the full-resolution level;
    returns the best iterate, or the target itself where that is no worse by the problem's objective
    (an eye in focus or nearly so, whose over-relaxed first steps leave an optimum that no later
    iterate regains within the tolerance).  A robust problem (``problem.members``) is solved on its effective
    kernel (:mod:`vrcorrect.physics.robust`), as the real-time path solves it, and in its box
    (``problem.capped``: below the light cap, :func:`~vrcorrect.solvers.problem.light_cap`)."""
    K = problem.kernel.kernel
    t = np.ascontiguousarray(np.moveaxis(problem.target_lms, 2, 0), dtype=np.float32)
    target = np.ascontiguousarray(np.moveaxis(problem.target, 2, 0), dtype=np.float32)
    z0, duals, notes = _coarse_to_fine(K, target, t, levels, coarse_iterations, level_iterations,
                                       rho, relaxation, balance, warm_start, problem.capped)
    z, iterations, history, norm2, _ = _admm(K, t, z0, rho, relaxation, balance, max_iterations, tolerance,
                                             progress, duals, upper=light_cap(target) if problem.capped else None)
    settings = {"solver": "ADMM (boundary-aware split), over-relaxed", "rho": rho, "relaxation": relaxation,
                "spectral_norm_squared": norm2, "tolerance": tolerance,
                "box": "0 to the light cap min(1, 2 t + %g)" % LIGHT_CAP_FLOOR if problem.capped else "0 to 1",
                "warm_start": ", then ".join(notes)}
    image = np.moveaxis(z, 0, 2).astype(np.float32)
    shown = np.asarray(problem.target, np.float32)
    none, corrected = objective(shown, problem), objective(image, problem)
    if none <= corrected:                                           # never worse than the picture itself: an
        settings["kept"] = "the target itself (no iterate was better by the objective)"   # eye near focus
        image, corrected = shown.copy(), none
    return Correction(image, iterations, settings, history, objective=corrected)
