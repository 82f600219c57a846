"""Options the real-time commands share (``render``, ``mirror``, ``overlay``, ``xr``): the GLSL
strategy and its iterations per frame, ``--no-reprojection``, ``--frames``, and the corrector
options they make, each checked with a one-line error naming the option."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Sequence

from ..plumbing.errors import ValidationError
from ..runtime.eye_model import DEFAULT_COLD_ITERATIONS, DEFAULT_ITERATIONS
from ..runtime.model_path import model_for_backend
from ..specs.vocabulary import (
    ITERATIONS_PER_FRAME,
    ITERATIVE_FILTERS,
    MAX_ITERATIONS_PER_FRAME,
    Backend,
    Filter,
    Periphery,
    names,
)
from .common import (BAND_HELP, FOVEA_HELP, GAZE_HELP, PERIPHERY_HELP, PUPIL_HELP, REALTIME_BAND_HELP, ROBUST_HELP,
                     parse_fovea, parse_gaze, parse_pupil)

__all__ = ["FILTER_CHOICES", "parse_frames", "parse_whole_number", "parse_iterations_per_frame", "add_backend_option",
           "add_rx_option", "add_filter_options", "add_pupil_choice", "pupil_options", "add_fovea_choice",
           "fovea_options", "add_reprojection_option",
           "filter_options", "cold_start_choice", "corrector_options"]

KEPT_DESIGNS = ("\nEach eye's designs are kept in vrcorrect's cache folder ($VRCORRECT_CACHE_DIR, else\n"
                "~/.cache/vrcorrect): launched again, it starts without designing them. Deleting it is safe.")
"""What the windowed commands' descriptions say about the designs they keep between runs."""
FILTER_CHOICES = names(Filter)
_ITERATIVE = " or ".join(names(ITERATIVE_FILTERS))


def parse_whole_number(text: str | int | None, field: str, low: int, high: int, what: str) -> int:
    """``text`` as a whole number from ``low`` to ``high`` (``what``: the unit named in the error)."""
    try:
        value = int(text)
    except (TypeError, ValueError):
        value = low - 1
    if isinstance(text, bool) or not low <= value <= high:
        raise ValidationError(field, text, f"a whole number of {what} from {low} to {high}")
    return value


def parse_frames(text: str | None, field: str = "--frames", most: int = 10_000_000) -> int | None:
    """Check ``--frames``: ``None`` (run until closed) or a whole number from 1 to ``most``."""
    return None if text is None else parse_whole_number(text, field, 1, most, "frames")


def parse_iterations_per_frame(text: str | int | None, field: str = "--iterations-per-frame") -> int | None:
    """Check ``--iterations-per-frame``: ``None`` (the default) or a whole number in
    :data:`~vrcorrect.specs.vocabulary.ITERATIONS_PER_FRAME`."""
    return None if text is None else parse_whole_number(text, field, *ITERATIONS_PER_FRAME, "iterations")


def add_backend_option(p: argparse.ArgumentParser, help: str = "correction backend (default glsl)") -> None:
    """``--backend`` (``render``, ``mirror``, ``overlay``, ``xr``): a
    :class:`~vrcorrect.specs.vocabulary.Backend`, ``glsl`` by default."""
    p.add_argument("--backend", choices=names(Backend), default=Backend.GLSL.value, help=help)


def add_rx_option(p: argparse.ArgumentParser) -> None:
    """``--rx``, watched for changes (``mirror``, ``overlay``, ``xr``)."""
    p.add_argument("--rx", metavar="RX.json", help="prescription (default: the bundled sample); reloaded when it "
                                                   "changes on disk")


def add_filter_options(p: argparse.ArgumentParser, eye_tracker: bool = False) -> None:
    """``--filter``, ``--iterations-per-frame`` and ``--cold-iterations`` (``render``, ``mirror``,
    ``overlay``, ``xr``)."""
    low, high = ITERATIONS_PER_FRAME
    p.add_argument("--filter", choices=FILTER_CHOICES, default=FILTER_CHOICES[0],
                   help="GLSL method: admm (default; fast's ADMM iterations on the true objective, warm-started from "
                        "frame to frame with their duals, converging to the optimum over frames), fista "
                        "(projected-gradient iterations spread over frames: the same optimum, about twice the cost "
                        "per frame for the same quality), fft (one pass of the regularised inverse by FFT compute "
                        "shaders, blended per frame: further from the optimum) or separable (low-rank spatial "
                        "filters of that inverse)")
    p.add_argument("--iterations-per-frame", metavar="K",
                   help=f"with --filter {_ITERATIVE}: iterations per frame, {low} to {high} (default "
                        + ", ".join(f"{k} for {m}" for m, k in DEFAULT_ITERATIONS.items())
                        + "; the speed-accuracy knob)")
    p.add_argument("--cold-iterations", metavar="N",
                   help=f"with --filter admm: ADMM iterations at half resolution that start a shot's first frame (the "
                        f"first, after a cut, after a prescription change), 0 to {MAX_ITERATIONS_PER_FRAME} (default "
                        f"{DEFAULT_COLD_ITERATIONS}, fast's own coarse-to-fine start; 0: from the target, cheaper "
                        "but a shot then starts blurred)")
    p.add_argument("--budget-ms", metavar="MS",
                   help=f"with --filter {_ITERATIVE}: hold each eye's frame at this much GPU time, measured by "
                        "its own timer queries (two frames late): the iterations a frame are chosen to fit (their "
                        "mean time is the budget) and, with --fovea, the window's radius shrinks from DEG when even "
                        "one iteration overruns it by 15 %% (and grows back, with hysteresis); default: none, the "
                        "fixed settings")
    add_pupil_choice(p)
    add_fovea_choice(p, eye_tracker)
    p.add_argument("--cold-start", metavar="MODEL.onnx", nargs="?", const="default",
                   help="with --filter admm: what starts a shot's first frame (the first, after a cut, after a "
                        "prescription change). A model file: that unrolled model's pass (vrcorrect unroll -o RUN "
                        "writes RUN/unrolled.onnx; the frame is read back, corrected on onnxruntime and uploaded); "
                        "alone: the shipped models/default.onnx; none: the half-resolution level; auto (the "
                        "default): the shipped model where onnxruntime runs it on a GPU, the half-resolution level "
                        "where it would run on the CPU (seconds a cut at headset size)")


def add_pupil_choice(p: argparse.ArgumentParser) -> None:
    """``--pupil``, ``--robust`` and ``--band`` (``render``, ``mirror``, ``overlay``, ``xr``): the eye as it is.
    With ``auto`` the pupil follows each frame's light (measured on the GPU, with the pupil's own
    dynamics) and the correction switches between designs built off the render thread."""

    g = p.add_argument_group("the eye as it is")
    g.add_argument("--pupil", default="auto", metavar="auto|rx|MM",
                   help=PUPIL_HELP.replace("from the display's light, Watson & Yellott's formula on the image's mean "
                                           "luminance", "followed frame by frame from the light shown: Watson & "
                                           "Yellott's formula on the frame's mean luminance (measured on the GPU), "
                                           "with the pupil's own dynamics,"))
    g.add_argument("--robust", choices=("on", "off"), default="on", help=ROBUST_HELP)
    g.add_argument("--band", choices=("auto", "default"), default="auto",
                   help=BAND_HELP + REALTIME_BAND_HELP)


def add_fovea_choice(p: argparse.ArgumentParser, eye_tracker: bool = False) -> None:
    """``--fovea`` and ``--gaze`` (``render``, ``mirror``, ``overlay``, ``xr``): correct where the eye looks
    (``eye_tracker``: the command follows an OpenXR eye tracker, and ``--gaze`` is its fallback)."""

    g = p.add_argument_group("where the eye looks")
    g.add_argument("--fovea", default="off", metavar="DEG|off", help="with --filter admm: " + FOVEA_HELP)
    g.add_argument("--gaze", default="0,0", metavar="X,Y",
                   help="with --fovea: " + ("the window follows the eye tracker where the runtime offers one "
                                            "(XR_EXT_eye_gaze_interaction); without one, " if eye_tracker else "")
                        + GAZE_HELP)
    g.add_argument("--periphery", choices=names(Periphery), default=None,
                   help="with --fovea: " + PERIPHERY_HELP)


def fovea_options(args: argparse.Namespace) -> dict[str, Any]:
    """The :class:`~vrcorrect.runtime.eye_model.CorrectorOptions` fields of ``--fovea`` and ``--gaze``
    (none when the window is off; ``--gaze`` without a window is refused)."""

    fovea = parse_fovea(getattr(args, "fovea", "off"))
    gaze = parse_gaze(getattr(args, "gaze", "0,0"))
    periphery = getattr(args, "periphery", None)
    if fovea is None:
        if gaze != (0.0, 0.0):
            raise ValidationError("--gaze", args.gaze, "only with --fovea DEG (the window it places)")
        if periphery is not None:
            raise ValidationError("--periphery", periphery, "only with --fovea DEG (outside its window)")
        return {}
    if getattr(args, "filter", Filter.ADMM) != Filter.ADMM or getattr(args, "backend", Backend.GLSL) != Backend.GLSL:
        raise ValidationError("--fovea", args.fovea, "only with --filter admm on --backend glsl")
    return {"fovea_deg": fovea, "gaze_deg": gaze, **({} if periphery is None else {"fovea_periphery": periphery})}


def pupil_options(args: argparse.Namespace) -> dict[str, Any]:
    """The :class:`~vrcorrect.runtime.eye_model.CorrectorOptions` fields of ``--pupil``, ``--robust`` and
    ``--band``."""

    return {"pupil": parse_pupil(getattr(args, "pupil", "auto")), "robust": getattr(args, "robust", "on") == "on",
            "band": getattr(args, "band", "default")}


def add_reprojection_option(p: argparse.ArgumentParser) -> None:
    """``--no-reprojection`` (``mirror``, ``overlay``, ``xr``)."""
    p.add_argument("--no-reprojection", action="store_true",
                   help=f"with --filter {_ITERATIVE}: warm-start each frame from the previous solution as it was, instead "
                        "of moved by the motion since the last frame (an image, folder, video or screen source: "
                        "the pictures' estimated shift, with a cold start on a scene cut; xr's demo scene: the "
                        "turn of the tracked head)")


def filter_options(args: argparse.Namespace) -> dict[str, Any]:
    """The :class:`~vrcorrect.runtime.corrector.Corrector` options of :func:`add_filter_options`'s
    arguments (checked: one line naming the option when wrong)."""
    k = parse_iterations_per_frame(args.iterations_per_frame)
    options: dict[str, Any] = {"filter": args.filter, **pupil_options(args), **fovea_options(args)}
    if k is not None:
        if args.filter not in ITERATIVE_FILTERS:
            raise ValidationError("--iterations-per-frame", args.iterations_per_frame, f"only with --filter {_ITERATIVE}")
        options["iterations_per_frame"] = k
    if getattr(args, "cold_iterations", None) is not None:
        if args.filter != Filter.ADMM:
            raise ValidationError("--cold-iterations", args.cold_iterations, "only with --filter admm")
        options["cold_iterations"] = parse_whole_number(args.cold_iterations, "--cold-iterations", 0,
                                                        MAX_ITERATIONS_PER_FRAME, "iterations")
    model, args.cold_start_note = cold_start_choice(getattr(args, "cold_start", None), args.filter,
                                                    getattr(args, "backend", Backend.GLSL))
    if "fovea_deg" in options:
        if getattr(args, "cold_start", None) not in (None, "auto", "none"):
            raise ValidationError("--cold-start", args.cold_start, "none or auto with --fovea (the window's "
                                  "frames start from the target)")
        model, args.cold_start_note = None, "the target (--fovea: a window's frames start from the target)"
    if model is not None:
        options["cold_start_model"] = model
    if getattr(args, "budget_ms", None) is not None:
        options["budget_ms"] = parse_budget(args.budget_ms, args.filter)
    return options


def parse_budget(text: Any, filter: str, field: str = "--budget-ms") -> float:
    """``--budget-ms``: milliseconds a frame, with an iterative filter."""
    from ..runtime.budget import MAX_BUDGET_MS, MIN_BUDGET_MS  # on use: start-up time

    if filter not in ITERATIVE_FILTERS:
        raise ValidationError(field, text, f"only with --filter {_ITERATIVE}")
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = None
    if value is None or not (MIN_BUDGET_MS <= value <= MAX_BUDGET_MS):
        raise ValidationError(field, text, f"milliseconds a frame from {MIN_BUDGET_MS:g} to {MAX_BUDGET_MS:g}")
    return value


def cold_start_choice(value: str | None, filter: str, backend: str,
                      available: Sequence[str] | None = None) -> tuple[str | None, str]:
    """``--cold-start``'s model (``None``: the half-resolution level) and a line saying what starts a
    shot and why (empty where nothing iterates). ``value``: a path, ``default`` (the shipped
    model), ``none``, or ``auto``/``None`` (not given): the shipped model where onnxruntime offers a
    GPU execution provider (``available``: its providers, asked when not given), else the level."""

    from ..runtime.model_path import (
        DEFAULT_MODEL,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    iterating = filter == Filter.ADMM and backend == Backend.GLSL
    if value in (None, "auto"):
        if not iterating:
            return None, ""
        if not DEFAULT_MODEL.is_file():
            return None, f"half-resolution level (auto: no shipped model at {DEFAULT_MODEL})"
        from ..runtime.learned import gpu_provider  # on use: numpy and the optics stay out of start-up

        provider = gpu_provider(available)
        if provider is None:
            return None, ("half-resolution level (auto: onnxruntime has no GPU execution provider here, and the "
                          "learned pass on the CPU takes seconds a cut at headset size; --cold-start to use it)")
        return str(DEFAULT_MODEL), f"the shipped model's learned pass on {provider} (auto; --cold-start none: the level)"
    if value == "none":
        return None, "half-resolution level (--cold-start none)" if iterating else ""
    if not iterating:
        raise ValidationError("--cold-start", value, "only with --filter admm on --backend glsl")
    path = str(DEFAULT_MODEL) if value == "default" and not Path("default").is_file() else value
    if not Path(path).is_file():
        raise ValidationError("--cold-start", value, "an existing unrolled model file (.onnx), default, none or auto")
    return path, (f"the learned pass of {Path(path).name} (read back, onnxruntime, uploaded) instead of the "
                  "half-resolution level")


def corrector_options(args: argparse.Namespace) -> dict[str, Any]:
    """:func:`filter_options` and, with ``--backend onnx``, the model (``--model``, or the default
    model): the correctors' options of ``mirror``, ``overlay`` and ``xr``."""
    options = filter_options(args)
    model = model_for_backend(args.backend, args.model)
    if model:
        options["model"] = model
    return options
