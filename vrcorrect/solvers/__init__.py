"""Layer 4: the correction methods, which find the displayed image whose retinal image matches the target's.

One module per concept:

* :mod:`~vrcorrect.solvers.problem`: the :class:`Problem`, the objective, the guard's closed-form
  blend weight (:func:`guard_weight`), what a method returns (:class:`Correction`) and what
  :func:`solve` returns (:class:`SolveResult`);
* :mod:`~vrcorrect.solvers.spectral`: the per-frequency 3x3 algebra and the blur ``K x`` with its
  adjoint (:class:`~vrcorrect.solvers.spectral.Blur`), shared by every numpy method and the CPU twins;
* :mod:`~vrcorrect.solvers.wiener` (the one-pass regularised inverse and its filter design),
  :mod:`~vrcorrect.solvers.admm` (``fast``), :mod:`~vrcorrect.solvers.fista` (projected gradient,
  the learned model's conditioning and the FISTA twin), :mod:`~vrcorrect.solvers.iterative`
  (``paper`` and ``conventional``, torch);
* :mod:`~vrcorrect.solvers.methods`: :data:`METHODS` (name -> method, one signature and one result),
  :func:`solve`, the memory estimate;
* :mod:`~vrcorrect.solvers.realtime`: the CPU twins of the GPU's frame-to-frame iterations.

``none``, ``wiener`` (the real-time path's mathematics) and ``fast`` are numpy only; ``paper`` and
``conventional`` import torch when they run.  This module only hands names on.
"""

from __future__ import annotations

from .methods import LEARNED, METHODS, PEAK_MEMORY, BoundModel, peak_memory_bytes, solve
from .problem import Correction, Problem, SolveResult, guard_weight, make_problem, objective, scale_contrast

__all__ = ["Problem", "Correction", "SolveResult", "make_problem", "objective", "scale_contrast", "guard_weight",
           "METHODS", "LEARNED", "BoundModel", "solve", "PEAK_MEMORY", "peak_memory_bytes"]
