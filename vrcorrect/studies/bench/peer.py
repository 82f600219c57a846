"""``vrcorrect bench cost --peer torch``: the real-time default's frame written plainly in torch on
cuFFT, timed in the same run and on the same GPU as the project's GLSL frame (issue 43).

The peer is a straightforward reference, not a tuned one: float32 throughout, the FFTs by
``torch.fft.rfft2`` / ``irfft2`` on the grid the GLSL frame uses (:func:`~vrcorrect.solvers.realtime.admm_grid`),
the 3x3 per-frequency products as ``einsum``, every element-wise step its own kernel.  One frame is
what :class:`~vrcorrect.solvers.realtime.AdmmFrames` (``precision="single"``, no half-resolution
cold start) computes for content that changes each frame: the target ``T = K_ref t`` (one FFT round
trip), the warm start (``w += T - T_prev``, ``q += t - t_prev``; a cold frame: ``w = T``, ``q = t``),
``k`` ADMM iterations (one round trip each) and the guard (``K z`` and ``K t``, one round trip, and the
blend weight).  ``tests/test_bench_peer.py`` holds it to the twin on the CPU.

On a CUDA device the frames are timed by CUDA events around each frame, after a warm-up, captured as
one CUDA graph where torch can (else eagerly): the median GPU time of ``frames`` changing frames.
Without one the peer is not run and the bench says so, in exactly :data:`NO_DEVICE`'s words.

torch is imported only here, inside the functions (layer 6; the real-time path never imports it).
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

__all__ = ["NO_DEVICE", "PEERS", "TorchAdmmPeer", "peer_device", "time_torch_peer", "peer_against_twin"]

NO_DEVICE = "no CUDA device: peer not run"
"""What the bench prints (and its table says) where torch sees no CUDA device."""
PEERS = ("torch",)
"""The peers ``--peer`` accepts."""


def peer_device() -> tuple[Any, str]:
    """``(torch.device("cuda"), name)`` where torch sees a CUDA device, else ``(None, why)``."""
    try:
        import torch  # on use: torch (the learn extra; heavy)
    except ImportError:
        return None, "torch is not installed"
    if not torch.cuda.is_available():
        return None, "torch.cuda.is_available() is False"
    return torch.device("cuda"), torch.cuda.get_device_name(0)


class TorchAdmmPeer:
    """The real-time default's frame in plain torch (module docstring) for one eye and image size.

    Parameters mirror :class:`~vrcorrect.solvers.realtime.AdmmFrames`: ``kernel`` and ``reference``
    (:class:`~vrcorrect.physics.kernel.EyeKernel`; ``None`` for the ideal target ``A t``), ``shape``
    ``(H, W)``, ``grid_kernel_size`` (the grid holds a kernel this large: the GLSL frame's
    ``EyeModel.margin``); ``device`` a torch device.  The kernels' spectra and the per-frequency inverse
    ``G = (K^H K + n I)^-1`` are computed once in float64 on the CPU (as the twin does) and kept as
    complex64 on the device."""

    def __init__(self, kernel: Any, reference: Any, shape: tuple[int, int], device: Any,
                 grid_kernel_size: int | None = None):
        import torch  # on use: torch (the learn extra; heavy)

        from ...solvers.realtime import (  # on use: start-up time (the CLI imports the studies to build its parser)
            ADMM_RELAXATION,
            admm_grid,
            admm_weights,
        )
        from ...solvers.spectral import (  # on use: start-up time (the CLI imports the studies to build its parser)
            hermitian_inverse,
            kernel_spectrum,
        )

        H, W = (int(v) for v in shape)
        self.shape, self.device = (H, W), device
        size = max(kernel.size, reference.size if reference is not None else 1, grid_kernel_size or 1)
        self.grid = admm_grid(W, H, size)
        keep, n = admm_weights(kernel.kernel)
        Kf = kernel_spectrum(kernel.kernel, self.grid).astype(np.complex64)
        G = hermitian_inverse(Kf.astype(np.complex128), n).astype(np.complex64)

        def on(a: np.ndarray) -> Any:
            return torch.from_numpy(np.ascontiguousarray(a)).to(device)

        self.K = on(Kf)
        self.Kh = on(np.conj(np.swapaxes(Kf, 0, 1)))
        self.G = on(G)
        self.R = None if reference is None else on(kernel_spectrum(reference.kernel, self.grid).astype(np.complex64))
        self.A = on(kernel.matrix.astype(np.float32))
        self.keep = float(np.float32(keep))
        self.n = float(np.float32(n))
        self.alpha = float(np.float32(ADMM_RELAXATION))
        inside = torch.zeros(self.grid, dtype=torch.bool)
        inside[:H, :W] = True
        self.inside = inside.to(device)
        self.w = self.q = self.t_prev = self.T_prev = None

    # ------------------------------------------------------------------ the pieces

    def _fft(self, a: Any) -> Any:
        import torch  # on use: torch (the learn extra; heavy)

        return torch.fft.rfft2(a, s=self.grid)

    def _ifft(self, A: Any) -> Any:
        import torch  # on use: torch (the learn extra; heavy)

        return torch.fft.irfft2(A, s=self.grid)

    @staticmethod
    def _apply3(M: Any, X: Any) -> Any:
        import torch  # on use: torch (the learn extra; heavy)

        return torch.einsum("ijyx,jyx->iyx", M, X)

    def _on_grid(self, image: Any) -> Any:
        import torch  # on use: torch (the learn extra; heavy)

        H, W = self.shape
        g = torch.zeros((3,) + self.grid, dtype=torch.float32, device=self.device)
        g[:, :H, :W] = image
        return g

    def _prox(self, w: Any, T: Any) -> Any:
        import torch  # on use: torch (the learn extra; heavy)

        return torch.where(self.inside, self.keep * w + (1.0 - self.keep) * T, w)

    def _proj(self, q: Any) -> Any:
        import torch  # on use: torch (the learn extra; heavy)

        return torch.where(self.inside, q.clamp(0.0, 1.0), torch.zeros_like(q))

    def reset(self) -> None:
        """The next frame starts cold."""
        self.w = self.q = self.t_prev = self.T_prev = None

    def frame(self, t: Any, iterations: int) -> tuple[Any, Any, Any]:
        """One frame for a ``(3, H, W)`` float32 target on the device: ``(shown (3, H, W), beta,
        objective)``, the last two 0-d tensors (no read-back: nothing waits for the GPU)."""
        import torch  # on use: torch (the learn extra; heavy)

        H, W = self.shape
        tg = self._on_grid(t)
        if self.R is None:
            T = self._on_grid(torch.einsum("ij,jyx->iyx", self.A, t))
        else:
            T = self._ifft(self._apply3(self.R, self._fft(tg)))
        T_in = T[:, :H, :W]                                   # (T spills into the surround: kept, as the twin)
        if self.w is None:
            w, q = T.clone(), tg.clone()
        else:
            w, q = self.w.clone(), self.q.clone()
            w[:, :H, :W] += T_in - self.T_prev
            q[:, :H, :W] += t - self.t_prev
        for _ in range(int(iterations)):
            pw, pq = self._prox(w, T), self._proj(q)
            R = self._apply3(self.Kh, self._fft(2 * pw - w)) + self.n * self._fft(2 * pq - q)
            U = self._apply3(self.G, R)
            u, Ku = self._ifft(U), self._ifft(self._apply3(self.K, U))
            w = w + self.alpha * (Ku - pw)
            q = q + self.alpha * (u - pq)
        if self.w is None:                                    # the state lives in tensors of its own,
            self.w, self.q = torch.empty_like(w), torch.empty_like(q)      # updated in place (a captured
            self.t_prev, self.T_prev = torch.empty_like(t), torch.empty_like(T_in)   # graph replays it)
        self.w.copy_(w)
        self.q.copy_(q)
        self.t_prev.copy_(t)
        self.T_prev.copy_(T_in)
        z = self._proj(q)[:, :H, :W]
        both = torch.stack([self._on_grid(z), tg])                          # K z and K t in one round trip
        K_both = self._ifft(torch.einsum("ijyx,bjyx->biyx", self.K, self._fft(both)))[:, :, :H, :W]
        r0 = K_both[1] - T_in
        kd = K_both[0] - K_both[1]
        s_rk, s_kk, s_rr = (r0 * kd).sum(), (kd * kd).sum(), (r0 * r0).sum()
        beta = torch.where(s_kk > 1e-10 * s_rr, (-s_rk / s_kk).clamp(0.0, 1.0), torch.zeros_like(s_kk))
        shown = t + beta * (z - t)
        objective = (s_rr + 2 * beta * s_rk + beta * beta * s_kk) / r0.numel()
        return shown, beta, objective


def time_torch_peer(kernel: Any, reference: Any, size: tuple[int, int], iterations: int, frames: int,
                    warm_up_s: float, seed: int = 0, grid_kernel_size: int | None = None) -> dict[str, Any]:
    """Time the peer's changing-content frames for one eye at ``size`` (``W, H``) on the CUDA device:
    ``{"status": "run", "device", "gpu_ms" (median), "frames_ms", "graph" (captured or not)}``, or
    ``{"status": NO_DEVICE, "reason"}`` where there is none."""

    device, name = peer_device()
    if device is None:
        return {"status": NO_DEVICE, "reason": name}
    import torch  # on use: torch (the learn extra; heavy)

    W, H = size
    peer = TorchAdmmPeer(kernel, reference, (H, W), device, grid_kernel_size)
    g = torch.Generator(device="cpu").manual_seed(seed)
    pictures = [torch.rand((3, H, W), generator=g).to(device) for _ in range(2)]
    target = pictures[0].clone()

    def step() -> None:
        peer.frame(target, iterations)

    peer.frame(target, iterations)                                    # the cold frame: the state exists
    until = time.perf_counter() + warm_up_s
    shown = 0
    while time.perf_counter() < until:
        shown += 1
        target.copy_(pictures[shown % 2])
        step()
    torch.cuda.synchronize()
    graph, run = None, step
    try:                                                              # one CUDA graph a frame, as the peer
        stream = torch.cuda.Stream()
        stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream):
            step()
        torch.cuda.current_stream().wait_stream(stream)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            peer.frame(target, iterations)
        run = graph.replay
    except Exception:                                                 # capture unsupported: eager frames
        graph, run = None, step
    times = []
    start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    for i in range(int(frames)):
        target.copy_(pictures[(shown + i + 1) % 2])
        torch.cuda.synchronize()
        start.record()
        run()
        end.record()
        end.synchronize()
        times.append(float(start.elapsed_time(end)))
    return {"status": "run", "device": name, "gpu_ms": statistics.median(times), "frames_ms": times,
            "graph": graph is not None, "grid": list(peer.grid)}


def peer_against_twin(kernel: Any, reference: Any, device: Any, shape: tuple[int, int] = (72, 96),
                      frames: int = 3, iterations: int = 2, seed: int = 1) -> dict[str, float]:
    """The peer against :class:`~vrcorrect.solvers.realtime.AdmmFrames` (single precision, no
    half-resolution cold start) on ``frames`` random ``shape`` frames, the first cold: the largest
    difference of the frames shown, of the guard's weights and of the objectives (relative)."""
    import torch  # on use: torch (the learn extra; heavy)

    from ...solvers.realtime import (
        AdmmFrames,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    H, W = shape
    twin = AdmmFrames(kernel, reference, (H, W), precision="single", cold_iterations=0)
    peer = TorchAdmmPeer(kernel, reference, (H, W), device)
    rng = np.random.default_rng(seed)
    worst = {"shown": 0.0, "beta": 0.0, "objective": 0.0}
    for _ in range(int(frames)):
        target = rng.random((H, W, 3), dtype=np.float32)
        want = twin.frame(target, iterations)
        shown, beta, objective = peer.frame(torch.from_numpy(np.ascontiguousarray(np.moveaxis(target, 2, 0))).to(device),
                                            iterations)
        got = np.moveaxis(shown.cpu().numpy(), 0, 2)
        worst["shown"] = max(worst["shown"], float(np.abs(got - want.shown).max()))
        worst["beta"] = max(worst["beta"], abs(float(beta) - want.beta))
        worst["objective"] = max(worst["objective"], abs(float(objective) - want.objective) / want.objective)
    return worst
