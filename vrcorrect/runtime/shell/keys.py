"""The keys the windows share (the mirror, the overlay, the headset's mirror), pure: GLFW's key
codes and modifier bits, key maps as text, the :class:`Screenshot` and :class:`Iterations` actions
and the iterations-per-frame knob of the iterative filters (:func:`change_iterations`,
:func:`knob_text`).

Layer 5: plain Python; never torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, Mapping, Sequence

from ...specs.vocabulary import ITERATIONS_PER_FRAME, ITERATIVE_FILTERS, names
from ..corrector import runs_iterations

if TYPE_CHECKING:  # pragma: no cover - typing only
    from ..corrector import Corrector

__all__ = ["GLFW_PRESS", "KEY_ESCAPE", "KEY_LEFT_BRACKET", "KEY_RIGHT_BRACKET", "MOD_SHIFT", "MOD_CONTROL", "MOD_ALT",
           "MOD_SUPER", "ITERATION_KEYS", "Screenshot", "Iterations", "key_letter", "key_map_text", "iteration_key",
           "next_iterations", "change_iterations", "knob_text"]

# GLFW key codes (glfw3.h: printable keys are their upper-case ASCII code) and modifier bits.
GLFW_PRESS = 1
KEY_ESCAPE = 256
KEY_LEFT_BRACKET, KEY_RIGHT_BRACKET = 91, 93      # GLFW_KEY_LEFT_BRACKET, GLFW_KEY_RIGHT_BRACKET ('[', ']')
MOD_SHIFT, MOD_CONTROL, MOD_ALT, MOD_SUPER = 0x1, 0x2, 0x4, 0x8

ITERATION_KEYS: tuple[tuple[str, str], ...] = (
    ("[ / ]", f"iterations per frame /2, x2 ({ITERATIONS_PER_FRAME.low}-{ITERATIONS_PER_FRAME.high}; "
              f"--filter {' or '.join(names(ITERATIVE_FILTERS))})"),
)
"""The knob's keys, in the mirror's, the overlay's and the headset mirror's key maps."""


@dataclass(frozen=True)
class Screenshot:
    """Write the window's picture, as shown, to a PNG."""


@dataclass(frozen=True)
class Iterations:
    """Double (``up``) or halve the projected-gradient iterations per frame (:func:`next_iterations`)."""

    up: bool


def key_letter(key: int) -> str | None:
    """The lower-case letter of a GLFW key code, or None for keys that are not letters."""
    return chr(key).lower() if ord("A") <= key <= ord("Z") else None


def key_map_text(keys: Sequence[tuple[str, str]]) -> str:
    """A key map (``(key, what)`` pairs) as printed at start: one key a line."""
    width = max(len(k) for k, _ in keys)
    return "\n".join(["keys:"] + [f"  {k:<{width}}  {what}" for k, what in keys])


def iteration_key(key: int) -> Iterations | None:
    """The knob's action for ``key`` (``[`` halves, ``]`` doubles), or None."""
    return {KEY_LEFT_BRACKET: Iterations(False), KEY_RIGHT_BRACKET: Iterations(True)}.get(key)


def next_iterations(k: int, up: bool) -> int:
    """``k`` doubled (``up``) or halved, within
    :data:`~vrcorrect.specs.vocabulary.ITERATIONS_PER_FRAME`."""
    low, high = ITERATIONS_PER_FRAME
    return min(high, max(low, 2 * k if up else k // 2))


def change_iterations(correctors: Iterable["Corrector"], up: bool) -> str:
    """Double (``up``) or halve the iterations per frame of every corrector that iterates over
    frames (:func:`runs_iterations`), all to one value (:func:`next_iterations` of the first's);
    returns the status message."""
    iterating = [c for c in correctors if runs_iterations(c)]
    if not iterating:
        return f"iterations per frame: only with --filter {' or '.join(names(ITERATIVE_FILTERS))}"
    budgeted = [c.budget for c in iterating if getattr(c, "budget", None) is not None]
    if budgeted:
        return (f"iterations per frame: chosen by the frame budget ({budgeted[0].budget_ms:g} ms, --budget-ms); "
                "run without it to set them by hand")
    k = next_iterations(iterating[0].iterations_per_frame, up)
    for c in iterating:
        c.iterations_per_frame = k
    return f"iterations per frame: {k}"


def knob_text(correctors: Mapping[str, "Corrector"], size: tuple[int, int], running: bool = True) -> str | None:
    """``"admm k 2   objective left 0.41 right 0.43 of uncorrected"`` for the correctors (by eye)
    that iterate over frames, or None when none does.  The objectives are the frame before the
    last one's (:meth:`~vrcorrect.runtime.corrector.Corrector.previous_objective_fraction`: no
    wait for the GPU); ``running`` False (correction off, or not shown) prints ``-``."""
    iterating = {eye: c for eye, c in correctors.items() if runs_iterations(c)}
    if not iterating:
        return None
    ks = sorted({c.iterations_per_frame for c in iterating.values()})
    methods = "/".join(sorted({c.options.filter for c in iterating.values()}))
    parts = []
    for eye, c in iterating.items():
        value = c.previous_objective_fraction(size) if running and c.enabled else None
        parts.append(f"{eye} {'-' if value is None else f'{value:.3f}'}")
    text = f"{methods} k {'/'.join(map(str, ks))}   objective {' '.join(parts)} of uncorrected"
    budgets = [c.budget for c in iterating.values() if getattr(c, "budget", None) is not None]
    if budgets:                                 # what the frame budget chose: iterations (mean) and window
        b = budgets[0]
        window = "" if b.fovea_deg is None else f", fovea {b.fovea_deg:.3g} deg"
        text += (f"   budget {b.budget_ms:g} ms: k " + "/".join(f"{x.q:.1f}" for x in budgets) + window
                 + ("" if b.last_ms is None else " (" + "/".join(
                     "-" if x.last_ms is None else f"{x.last_ms:.1f}" for x in budgets) + " ms)"))
    return text
