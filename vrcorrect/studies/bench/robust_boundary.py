"""``vrcorrect bench robust``'s boundary table: what the image's boundary (the crop of the data term) does
to the effective kernel, whose expectation is one 3x3 solve a frequency, against the exact expectation's
solution (one split per member).

Layer 6: the studies.
"""

from __future__ import annotations

import time
from typing import Any

from ...solvers import objective, solve
from ...solvers.expectation import fast_expectation


def boundary_case(case: dict) -> dict[str, Any]:
    """The expectation for the effective kernel's solution and the exact expectation's."""
    problem, design = case["_problem"], case["_default"]
    effective = solve(problem, "fast", tolerance=1e-3).image
    t0 = time.perf_counter()
    exact, iterations, _, _ = fast_expectation(problem.target, problem.members, design.kernel, problem.target_lms,
                                               tolerance=1e-3, max_iterations=60, capped=problem.capped)
    seconds = time.perf_counter() - t0
    none = objective(problem.target, problem)
    return {"display": case["display"], "image": case["image"], "none": none,
            "effective": objective(effective, problem), "exact": objective(exact, problem),
            "exact_iterations": iterations, "exact_seconds": seconds}


def gap_left(bound: dict) -> str:
    """The boundary table's "gap left": the effective kernel's expectation above the exact one's, as a share
    of the exact one's gain over no correction; "-" where that gain is under 0.1 % of none's (an eye in focus
    at the display: nothing to share)."""
    gain = bound["none"] - bound["exact"]
    if not gain > 1e-3 * bound["none"]:
        return "- (no gain)"
    return f"{100 * (bound['effective'] - bound['exact']) / gain:.1f} %"
