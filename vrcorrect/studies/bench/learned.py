"""``vrcorrect bench learned``: a learned model against ``fast`` and ``wiener`` on data it never saw.

Held out twice: images that were not in the training folder (scikit-image's ``rocket`` and
``retina`` by default) and eyes drawn from the model's own training ranges with a seed of
their own (the ranges are continuous, so no held-out eye equals a training eye).  Per case
(image x eye) the objective of uncorrected, ``wiener``, the learned model and ``fast``, the
share of the uncorrected-to-``fast`` gap the model closes, and FLIP of what the eye sees;
the same for :data:`FISTA_STEPS` accelerated projected-gradient steps alone (the model's input
without the network, at several costs: the network-free side of the speed-accuracy trade).
Speed: the network alone (onnxruntime, CPU provider) and the whole learned pass (with its
pre-correction channels, numpy) at 512x512 and at one 1832x1920 headset eye, against
``fast`` at 512x512, medians of several runs in this one process; and the floor under any
such network on this machine (:func:`speed_floor`): one 3x3 convolution from the two image
inputs to the output, and untrained U-Nets of smaller sizes, at 512x512.

Writes its section of ``docs/benchmarks.md``, two pictures - what the eye sees in two held-out
cases (``plot``) and the gap closed against ms (``tradeoff``) - and, with ``card``, the model card.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from tqdm import tqdm

from ...learn.dataset import HELD_OUT_IMAGES
from ...physics.kernel import build_kernel, build_reference_kernel
from ...plumbing.errors import ValidationError
from ...plumbing.fileio import write_text_atomic
from ...plumbing.images import prepare_image
from ...runtime.learned import LearnedModel
from ...runtime.onnx_backend import small_onnx_model
from ...solvers import make_problem, objective, solve
from ...solvers.fista import gradient_plan, projected_gradient
from ...specs.display import decode, get_display
from ...specs.vocabulary import Method
from ...vision.metrics import evaluate_seen
from ..plots import pyplot, save_figure
from . import machine_description, markdown_table, median_seconds, write_section

EYE_SEED = 20261123
#: Untrained U-Net sizes (width, depth) whose speed :func:`speed_floor` measures beside the model.
FLOOR_UNETS = ((8, 3), (4, 1))
#: Accelerated projected-gradient (FISTA) step counts scored beside the model: its input alone,
#: without the network, at several costs (the speed-accuracy trade of network-free correction).
FISTA_STEPS = (1, 3, 5, 8, 12, 20)


def _held_out_image(name: str, size: int) -> np.ndarray:
    from skimage import data  # optional: scikit-image (bundled photographs)


    return prepare_image(getattr(data, name)()[..., :3], size, name)


def held_out_eyes(ranges, count: int, seed: int = EYE_SEED) -> list:
    """``count`` eyes drawn uniformly from ``ranges`` with a seed of their own."""
    rng = np.random.default_rng(seed)
    return [ranges.sample(rng) for _ in range(count)]


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    return 1e3 * median_seconds(fn, repeats)[0]


def _one_convolution() -> bytes:
    """An ONNX graph of one 3x3 convolution from 6 channels (image and pre-correction) to 3, with
    dynamic height and width: the least work a convolutional network on those inputs can do."""
    from onnx import TensorProto, helper, numpy_helper  # optional: onnx (the learn extra)


    rng = np.random.default_rng(0)
    weights = numpy_helper.from_array(rng.normal(0.0, 0.1, (3, 6, 3, 3)).astype(np.float32), "w")
    bias = numpy_helper.from_array(np.zeros(3, np.float32), "b")
    graph = helper.make_graph([helper.make_node("Conv", ["x", "w", "b"], ["y"], pads=[1, 1, 1, 1])], "one_conv",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 6, "H", "W"])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, "H", "W"])],
                              [weights, bias])
    return small_onnx_model(graph).SerializeToString()


def speed_floor(size: tuple[int, int] = (512, 512), repeats: int = 5,
                unets: Sequence[tuple[int, int]] = FLOOR_UNETS) -> list[tuple[str, float | None]]:
    """Milliseconds (median of ``repeats``) of networks cheaper than any useful model, on
    onnxruntime's CPU provider at ``size``: one 3x3 convolution (:func:`_one_convolution`) and
    untrained conditioned U-Nets of each ``(width, depth)`` in ``unets`` (``None`` when torch,
    which builds them, is not installed)."""
    import onnxruntime as ort  # optional: onnxruntime (the learn and realtime extras)

    H, W = size
    rng = np.random.default_rng(1)
    options = ort.SessionOptions()
    options.log_severity_level = 3
    session = ort.InferenceSession(_one_convolution(), options, providers=["CPUExecutionProvider"])
    feeds = {"x": rng.random((1, 6, H, W), dtype=np.float32)}
    out: list[tuple[str, float | None]] = [
        ("one 3x3 convolution, 6 to 3 channels", _median_ms(lambda: session.run(None, feeds), repeats))]
    try:
        # torch: only this bench's model export needs it
        from ...learn.export import (
            onnx_bytes,  # on use: start-up time (the CLI imports the studies to build its parser)
        )
        from ...learn.model import (  # on use: start-up time (the CLI imports the studies to build its parser)
            ConditionedUNet,
            UNetConfig,
        )
    except ImportError:                                    # torch: the learn extra
        return out + [(f"U-Net width {w}, depth {d} (untrained)", None) for w, d in unets]
    image = {"image": rng.random((1, 3, H, W), dtype=np.float32),
             "precorrected": rng.random((1, 3, H, W), dtype=np.float32), "eye": np.zeros((1, 4), np.float32)}
    for w, d in unets:
        net = ConditionedUNet(UNetConfig(width=w, depth=d)).eval()
        s = ort.InferenceSession(onnx_bytes(net), options, providers=["CPUExecutionProvider"])
        out.append((f"U-Net width {w}, depth {d} (untrained)", _median_ms(lambda: s.run(None, image), repeats)))
    return out


def run_learned_bench(model_path: str | Path, out: Path = Path("docs/benchmarks.md"), card: Path | None = None,
                      images: Sequence[str] = HELD_OUT_IMAGES, eyes: int = 6, size: int = 256, repeats: int = 5,
                      write: bool = True, progress: bool = True,
                      speed_sizes: Sequence[tuple[int, int]] = ((512, 512), (1920, 1832)),
                      plot: Path | None = Path("docs/learned_heldout.png"),
                      floor_unets: Sequence[tuple[int, int]] = FLOOR_UNETS,
                      tradeoff: Path | None = Path("docs/learned_tradeoff.png"),
                      fista_steps: Sequence[int] = FISTA_STEPS) -> dict[str, Any]:
    """Measure the model (see the module docstring); returns the figures and the Markdown.

    Pictures, written with ``write`` (``None``: not drawn): ``plot``, what the first held-out
    eye sees of each held-out image under every method (:func:`_plot_seen`); ``tradeoff``, the
    share of the gap closed against ms at the first speed size for ``wiener``, ``fista_steps``
    FISTA steps alone, the model and ``fast`` (:func:`_plot_tradeoff`)."""

    model = LearnedModel(model_path, providers=("CPUExecutionProvider",))
    trained_on = set(json.loads(model.metadata.get("vrcorrect.train", "{}")).get("images", []))
    if trained_on & set(images):
        raise ValidationError("images", sorted(trained_on & set(images)),
                              f"images the model {Path(model_path).name} was not trained on (it saw "
                              f"{', '.join(sorted(trained_on))})")
    display = get_display(model.display["name"])
    eye_list = held_out_eyes(model.ranges, eyes)
    rows, cases, pictures = [], [], []
    bar = tqdm(total=len(eye_list) * len(images), desc="bench learned", unit="case",
               disable=None if progress else True, file=sys.stderr)
    for e in eye_list:
        kernel = build_kernel(e, display)
        reference = build_reference_kernel(e, display) if model.reference == "glasses" else None
        bound = model.for_eye(e, display, kernel, reference)
        plan = gradient_plan(kernel, (size, size))
        for name in images:
            target = decode(display, _held_out_image(name, size))
            p = make_problem(target, kernel, reference)
            none = objective(target, p)
            fast = solve(p, Method.FAST)
            wien = solve(p, Method.WIENER)
            target_chw = np.ascontiguousarray(np.moveaxis(target, 2, 0))
            learned = np.ascontiguousarray(np.moveaxis(bound.infer(target_chw), 0, 2))
            obj = objective(learned, p)
            pre = np.ascontiguousarray(np.moveaxis(bound.precorrected(target_chw), 0, 2))
            obj_pre = objective(pre, p)

            seen: dict[str, np.ndarray] = {}
            jods: dict[str, float] = {}

            def flip(img: np.ndarray, method: str) -> float:
                """FLIP of what the eye sees (its JOD kept in ``jods``)."""
                scores, views = evaluate_seen(img, target, kernel, display, target_lms=p.target_lms)
                jods[f"jod_{method}"] = scores.jod
                if e is eye_list[0]:                        # the picture's cases
                    seen[method] = views["seen_srgb"]
                    seen["target"] = views["target_srgb"]
                return scores.flip

            gap = none - fast.objective
            closed = (none - obj) / gap if gap > 0 else float("nan")
            closed_pre = (none - obj_pre) / gap if gap > 0 else float("nan")
            case = {"image": name, "sphere_D": e.sphere_D, "cylinder_D": e.cylinder_D, "axis_deg": e.axis_deg,
                    "pupil_mm": e.pupil_diameter_mm, "objective_none": none, "objective_wiener": wien.objective,
                    "objective_learned": obj, "objective_fast": fast.objective, "gap_closed": closed,
                    "objective_precorrected": obj_pre, "gap_closed_precorrected": closed_pre,
                    "flip_none": flip(target, "none"), "flip_wiener": flip(wien.image, "wiener"),
                    "flip_learned": flip(learned, "learned"), "flip_precorrected": flip(pre, "precorrected"),
                    "flip_fast": flip(fast.image, "fast")}
            case["gap_closed_wiener"] = (none - wien.objective) / gap if gap > 0 else float("nan")
            for k in fista_steps:
                xk = projected_gradient(p, k, plan)
                case[f"gap_closed_fista{k}"] = (none - objective(xk, p)) / gap if gap > 0 else float("nan")
                case[f"flip_fista{k}"] = flip(xk, f"fista{k}")
            case.update(jods)
            cases.append(case)
            if seen:
                pictures.append((case, seen))
            rows.append([name, f"{e.sphere_D:+.2f} / {e.cylinder_D:+.2f} x {e.axis_deg:.0f}",
                         f"{e.pupil_diameter_mm:.1f}", f"{none:.3e}", f"{wien.objective / none:.3f}",
                         f"{obj_pre / none:.3f}", f"{obj / none:.3f}", f"{fast.objective / none:.3f}",
                         f"{100 * closed:.0f} %", f"{case['flip_none']:.3f}", f"{case['flip_wiener']:.3f}",
                         f"{case['flip_precorrected']:.3f}", f"{case['flip_learned']:.3f}", f"{case['flip_fast']:.3f}",
                         f"{case['jod_none']:.2f}", f"{case['jod_wiener']:.2f}", f"{case['jod_learned']:.2f}",
                         f"{case['jod_fast']:.2f}"])
            bar.update(1)
    bar.close()

    def mean(key: str) -> float:
        return float(np.mean([c[key] for c in cases]))

    summary = {k: mean(k) for k in ("gap_closed", "gap_closed_precorrected", "flip_precorrected", "flip_none",
                                    "flip_wiener", "flip_learned", "flip_fast", "gap_closed_wiener",
                                    "jod_none", "jod_wiener", "jod_learned", "jod_fast", "jod_precorrected",
                                    *(f"{m}_fista{k}" for k in fista_steps for m in ("gap_closed", "flip", "jod")))}
    summary["objective_ratio_learned"] = float(np.mean([c["objective_learned"] / c["objective_none"] for c in cases]))
    summary["objective_ratio_wiener"] = float(np.mean([c["objective_wiener"] / c["objective_none"] for c in cases]))
    summary["objective_ratio_fast"] = float(np.mean([c["objective_fast"] / c["objective_none"] for c in cases]))
    summary["learned_below_wiener"] = sum(c["objective_learned"] < c["objective_wiener"] for c in cases)
    summary["cases"] = len(cases)

    # speed: one held-out eye, the first image
    e = eye_list[0]
    kernel = build_kernel(e, display)
    reference = build_reference_kernel(e, display) if model.reference == "glasses" else None
    bound = model.for_eye(e, display, kernel, reference)
    speed: dict[str, Any] = {"sizes": [f"{w}x{h}" for h, w in speed_sizes]}
    for i, hw in enumerate(speed_sizes):
        label = f"{hw[1]}x{hw[0]}"
        img = _held_out_image(images[0], max(hw))[:hw[0], :hw[1]]
        x = np.ascontiguousarray(np.moveaxis(decode(display, img), 2, 0))
        pre, grad = bound.inputs(x)
        feeds = {"image": x[None], "precorrected": pre[None], "eye": bound.features}
        if grad is not None:
            feeds["gradient"] = grad[None]
        n = repeats if i == 0 else max(2, repeats // 2)
        speed[label] = {"network_ms": _median_ms(lambda: model.session.run(None, feeds), n),
                        "pipeline_ms": _median_ms(lambda: bound.infer(x), n)}
    h0, w0 = speed_sizes[0]                                  # fast at the first size, same image and eye
    img = _held_out_image(images[0], max(h0, w0))[:h0, :w0]
    p = make_problem(decode(display, img), kernel, reference)
    fast_s = [solve(p, Method.FAST).seconds for _ in range(max(3, repeats // 2))]
    speed["wiener_ms"] = 1e3 * statistics.median([solve(p, Method.WIENER).seconds for _ in range(max(3, repeats // 2))])
    plan = gradient_plan(kernel, (h0, w0))
    speed["fista_ms"] = {k: _median_ms(lambda: projected_gradient(p, k, plan), max(3, repeats // 2))
                         for k in fista_steps}
    first = speed[speed["sizes"][0]]
    speed["fast_ms"] = 1e3 * statistics.median(fast_s)
    speed["speedup_network"] = speed["fast_ms"] / first["network_ms"]
    speed["speedup_pipeline"] = speed["fast_ms"] / first["pipeline_ms"]
    speed["floor"] = speed_floor(speed_sizes[0], repeats, floor_unets)

    speed["fista_steps"] = list(fista_steps)
    pictures_written = {"plot": plot, "tradeoff": tradeoff} if write else {}
    body = _markdown(model, display, eye_list, images, size, rows, summary, speed, pictures_written, out)
    if write:
        if plot is not None:
            _plot_seen(pictures, display, plot)
        if tradeoff is not None:
            _plot_tradeoff(summary, speed, tradeoff)
        write_section(out, "learned", body)
        if card is not None:
            card_md = _markdown(model, display, eye_list, images, size, rows, summary, speed, pictures_written,
                                card)
            write_text_atomic(card, _card(model, summary, speed, card_md), force=True)
    return {"cases": cases, "summary": summary, "speed": speed, "markdown": body}


def _plot_seen(pictures: list[tuple[dict, dict[str, np.ndarray]]], display, path: Path) -> None:
    """One row per held-out image (first held-out eye): the target as the eye sees it with
    glasses, then what it sees of each method's displayed image, with FLIP and objective."""
    plt = pyplot()
    columns = [("target", "target (glasses on)"), ("none", "uncorrected"), ("wiener", "wiener"),
               ("precorrected", "pre-correction alone"), ("learned", "learned"), ("fast", "fast")]
    fig, axes = plt.subplots(len(pictures), len(columns), figsize=(2.3 * len(columns), 2.9 * len(pictures)),
                             squeeze=False)
    for row, (case, seen) in zip(axes, pictures):
        for ax, (key, title) in zip(row, columns):
            ax.imshow(np.clip(seen[key], 0.0, 1.0), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if key == "target":
                ax.set_title(f"{case['image']}: {title}", fontsize=8)
            else:
                ratio = case[f"objective_{key}"] / case["objective_none"]
                ax.set_title(f"{title}\nFLIP {case[f'flip_{key}']:.3f}, objective x{ratio:.2f}", fontsize=8)
    case = pictures[0][0]
    fig.suptitle(f"What the eye sees on {display.name}: held-out eye {case['sphere_D']:+.2f} / "
                 f"{case['cylinder_D']:+.2f} x {case['axis_deg']:.0f}, pupil {case['pupil_mm']:.1f} mm "
                 "(objective relative to uncorrected)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def _plot_tradeoff(s: dict[str, Any], speed: dict[str, Any], path: Path) -> None:
    """Share of the gap closed (held-out mean) against ms at the first speed size: ``wiener``,
    the FISTA-step curve, the model's whole pass and ``fast``; the 80 % and 100x targets dashed."""
    plt = pyplot()
    label = speed["sizes"][0]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ks = speed["fista_steps"]
    ax.plot([speed["fista_ms"][k] for k in ks], [100 * s[f"gap_closed_fista{k}"] for k in ks], "o-",
            color="tab:purple", label="FISTA steps alone (no network)")
    for k in ks:
        ax.annotate(f"{k}", (speed["fista_ms"][k], 100 * s[f"gap_closed_fista{k}"]), fontsize=7,
                    xytext=(3, -9), textcoords="offset points")
    points = [("wiener", speed["wiener_ms"], s["gap_closed_wiener"], "tab:green"),
              ("learned (whole pass)", speed[label]["pipeline_ms"], s["gap_closed"], "tab:red"),
              ("fast", speed["fast_ms"], 1.0, "tab:blue")]
    for name, ms, gap, colour in points:
        ax.scatter(ms, 100 * gap, color=colour, s=40, zorder=3, label=name)
    ax.axhline(80, color="grey", ls="--", lw=0.8)
    ax.axvline(speed["fast_ms"] / 100, color="grey", ls=":", lw=0.8)
    ax.set_xscale("log")
    ax.text(0.01, 81, "80 % target", fontsize=7, transform=ax.get_yaxis_transform())
    ax.text(speed["fast_ms"] / 100 * 1.05, 0.03, "100x faster than fast", fontsize=7, rotation=90,
            transform=ax.get_xaxis_transform())
    ax.set_xlabel(f"ms per {label} image (CPU, median)")
    ax.set_ylabel("gap to fast closed, % (held-out mean)")
    ax.set_title("Learned correction: speed against accuracy on held-out images and eyes", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _tradeoff_lines(s: dict[str, Any], speed: dict[str, Any]) -> list[str]:
    """The speed-accuracy table: FISTA steps alone against wiener, the model and fast."""
    label = speed["sizes"][0]
    rows = [["wiener (its filters designed in each call)", f"{speed['wiener_ms']:.0f}",
             f"{100 * s['gap_closed_wiener']:.0f} %", f"{s['jod_wiener']:.2f}", f"{s['flip_wiener']:.3f}"]]
    rows += [[f"{k} FISTA step{'s' if k != 1 else ''}, no network", f"{speed['fista_ms'][k]:.0f}",
              f"{100 * s[f'gap_closed_fista{k}']:.0f} %", f"{s[f'jod_fista{k}']:.2f}", f"{s[f'flip_fista{k}']:.3f}"]
             for k in speed["fista_steps"]]
    rows.append(["learned (its input and the network)", f"{speed[label]['pipeline_ms']:.0f}",
                 f"{100 * s['gap_closed']:.0f} %", f"{s['jod_learned']:.2f}", f"{s['flip_learned']:.3f}"])
    rows.append(["fast", f"{speed['fast_ms']:.0f}", "100 %", f"{s['jod_fast']:.2f}", f"{s['flip_fast']:.3f}"])
    return ["", f"Speed against accuracy, same run: ms at {label} (median), and held-out means of the share of "
            f"the gap closed, of JOD (uncorrected {s['jod_none']:.2f}; higher is better) and of FLIP (uncorrected "
            f"{s['flip_none']:.3f}). The learned pass and the FISTA steps "
            "reuse the eye's kernel spectrum, as a renderer does from frame to frame; `wiener` and `fast` start "
            "from the kernel:", "",
            markdown_table(["method", f"ms at {label}", "gap closed", "JOD ↑", "FLIP ↓"], rows)]


def _floor_lines(speed: dict[str, Any]) -> list[str]:
    """The speed floor as Markdown lines: what 100x faster than ``fast`` leaves room for."""
    label = speed["sizes"][0]
    budget = speed["fast_ms"] / 100
    rows = [[name, "not measured (torch not installed)" if ms is None else f"{ms:.1f}",
             "" if ms is None else _times(speed["fast_ms"] / ms)] for name, ms in speed["floor"]]
    rows.insert(0, ["this model, network alone", f"{speed[label]['network_ms']:.1f}",
                    _times(speed["speedup_network"])])
    conv = speed["floor"][0][1]
    smallest = min((ms for name, ms in speed["floor"][1:] if ms is not None), default=None)
    if conv > budget:
        verdict = (f"One 3x3 convolution alone takes {conv:.1f} ms, {conv / budget:.1f}x that budget: no "
                   "convolutional network at full resolution meets the 100x target on this machine; it needs a GPU.")
    else:
        verdict = (f"One 3x3 convolution takes {conv:.1f} ms, within that budget, but a network that can correct "
                   "is many of them" + (f" (the smallest U-Net above: {smallest:.1f} ms)" if smallest else "")
                   + "; the 100x target needs a GPU.")
    first_step = speed.get("fista_ms", {}).get(1)
    if first_step is not None:
        verdict += (f" The model's input is FISTA steps: one (two FFT convolutions) takes {first_step:.0f} ms "
                    f"here, {first_step / budget:.1f}x the budget.")
    return [
        "",
        f"What 100x faster than `fast` leaves at {label} on this CPU: {budget:.1f} ms for the whole pass. "
        f"Cheaper networks, same run (onnxruntime, CPU provider, median of runs):",
        "",
        markdown_table(["network", f"ms at {label}", "against `fast`"], rows),
        "",
        verdict,
    ]


def _markdown(model, display, eyes, images, size, rows, s, speed, pictures: dict[str, Path | None] | None = None,
              out: Path | None = None) -> str:
    pictures = pictures or {}
    links = [f"![{alt}]({_relative(pictures[key], out)})" for key, alt in
             (("tradeoff", "Speed against accuracy on held-out data"),
              ("plot", "What the eye sees in two held-out cases")) if pictures.get(key) is not None]
    meta = model.metadata
    verdict_gap = "meets" if s["gap_closed"] >= 0.8 else "does NOT meet"
    verdict_w = ("beats" if s["flip_learned"] < s["flip_wiener"] and s["objective_ratio_learned"] < s[
        "objective_ratio_wiener"] else "does NOT beat")
    verdict_speed = "meets" if speed["speedup_pipeline"] >= 100 else "does NOT meet"
    lines = [
        "## Learned correction (held-out images and eyes)",
        "",
        f"Machine: {machine_description()}. onnxruntime CPU provider; no GPU in this session.",
        f"Model `{Path(model.path).name}` ({meta.get('vrcorrect.precision', 'fp32')}, "
        f"{Path(model.path).stat().st_size / 1e6:.1f} MB), trained for {display.name} "
        f"({display.pixels_per_degree:.1f} px/deg) over {model.ranges.describe()}. "
        f"Held out: images {', '.join(images)} (not in the training folder) at {size}x{size}; "
        f"{len(eyes)} eyes drawn from those ranges with seed {EYE_SEED} (training drew its own).",
        "",
        f"- gap closed (uncorrected to `fast`), mean over {s['cases']} cases: **{100 * s['gap_closed']:.0f} %** "
        f"({verdict_gap} the 80 % target); its input pre-correction alone "
        f"({_precorrection_text(meta)}) closes {100 * s['gap_closed_precorrected']:.0f} %",
        f"- objective / uncorrected, mean: wiener {s['objective_ratio_wiener']:.3f}, learned "
        f"{s['objective_ratio_learned']:.3f}, fast {s['objective_ratio_fast']:.3f}; learned below wiener in "
        f"{s['learned_below_wiener']} of {s['cases']} cases",
        f"- JOD of what the eye sees (ColorVideoVDP, higher is better), mean: uncorrected {s['jod_none']:.2f}, "
        f"wiener {s['jod_wiener']:.2f}, learned {s['jod_learned']:.2f}, fast {s['jod_fast']:.2f}; pre-correction "
        f"alone {s['jod_precorrected']:.2f}",
        f"- FLIP of what the eye sees, mean: uncorrected {s['flip_none']:.3f}, wiener {s['flip_wiener']:.3f}, "
        f"learned {s['flip_learned']:.3f}, fast {s['flip_fast']:.3f}; pre-correction alone "
        f"{s['flip_precorrected']:.3f} (learned {verdict_w} wiener on FLIP and objective)",
        f"- speed at {speed['sizes'][0]}: network {speed[speed['sizes'][0]]['network_ms']:.1f} ms, whole learned "
        f"pass (with its pre-correction) {speed[speed['sizes'][0]]['pipeline_ms']:.1f} ms, `fast` "
        f"{speed['fast_ms']:.0f} ms: **{_times(speed['speedup_pipeline'])}** ({_times(speed['speedup_network'])} "
        f"for the network alone; {verdict_speed} the 100x target)",
        *[f"- {label}{' (one headset eye)' if label == '1832x1920' else ''}: network "
          f"{speed[label]['network_ms']:.0f} ms, whole pass {speed[label]['pipeline_ms']:.0f} ms"
          for label in speed["sizes"][1:]],
        *_tradeoff_lines(s, speed),
        *_floor_lines(speed),
        *[line for link in links for line in ("", link)],
        "",
        markdown_table(["image", "eye S / C x axis", "pupil mm", "objective uncorrected", "wiener / unc.",
                        "pre-correction / unc.", "learned / unc.", "fast / unc.", "gap closed", "FLIP unc.",
                        "FLIP wiener", "FLIP pre-correction", "FLIP learned", "FLIP fast", "JOD unc.",
                        "JOD wiener", "JOD learned", "JOD fast"], rows),
    ]
    return "\n".join(lines) + "\n"


def _relative(path: Path, document: Path | None) -> str:
    """``path`` as a link from ``document``'s folder (POSIX separators)."""
    base = Path(document).resolve().parent if document is not None else Path.cwd()
    return Path(os.path.relpath(Path(path).resolve(), base)).as_posix()


def _times(ratio: float) -> str:
    """``fast``'s time over the learned one's, in words: ``12x faster`` or ``0.74x, slower``."""
    if ratio >= 10:
        return f"{ratio:.0f}x faster"
    return f"{ratio:.1f}x faster" if ratio >= 1 else f"{ratio:.2f}x, slower"


def _precorrection_text(meta: dict[str, str]) -> str:
    steps = int(meta.get("vrcorrect.precorrection_steps", "0"))
    if steps > 0:
        return f"{steps} accelerated projected-gradient steps on the eye's objective"
    return f"the clipped `wiener` inverse at regulariser {meta.get('vrcorrect.precorrection_mu_rel')}"


def _training_lines(train: dict[str, Any]) -> list[str]:
    """The card's account of the data set and the training run (from the model's metadata)."""
    if not train:
        return ["- (the model's metadata does not say)"]
    cfg = train.get("config", {})
    net = cfg.get("model", {})
    samples, per_eye = train.get("dataset_samples"), train.get("crops_per_eye", 1)
    eyes = f"{-(-int(samples) // int(per_eye))} eyes" if samples and per_eye else "eyes"
    images = ", ".join(train.get("images", [])) or "(not recorded)"
    w = cfg.get("target_weight", 0.2)
    schedule = cfg.get("lr_schedule", "constant")
    if schedule == "cosine" and cfg.get("steps") and train.get("step") != cfg.get("steps"):
        schedule = f"cosine over {cfg.get('steps')} steps, stopped at step {train.get('step')}"
    init = train.get("init")
    tuned = []
    if init:
        icfg = init.get("train_config", {})
        tuned = [f"- fine-tuned (`vrcorrect train --init`) from a run of {init.get('step')} steps "
                 f"(learning rate {icfg.get('learning_rate')}, {icfg.get('lr_schedule', 'constant')}; loss weight of "
                 f"the distance to `fast` {icfg.get('target_weight')})"]
    return tuned + [
        f"- data: {samples} random {train.get('crop_px')}x{train.get('crop_px')} crops of {images}; "
        f"{eyes} drawn uniformly over the ranges ({per_eye} crops each; seed {train.get('dataset_seed')}); "
        f"each crop's target is `fast`'s solution (tolerance {train.get('fast_tolerance')}) for its eye",
        f"- network: U-Net width {net.get('width')}, depth {net.get('depth')}, FiLM hidden {net.get('film_hidden')}, "
        f"output added to the {net.get('base', 'image')} input",
        f"- training: {train.get('step')} Adam steps, batch {cfg.get('batch_size')}, learning rate "
        f"{cfg.get('learning_rate')} ({schedule}), seed {cfg.get('seed')}; loss "
        f"{1 - w:g} x objective / uncorrected objective + {w:g} x distance to `fast` / uncorrected distance",
    ]


def _card(model, summary, speed, bench_md: str) -> str:
    meta = model.metadata
    train = json.loads(meta.get("vrcorrect.train", "{}") or "{}")
    return "\n".join([
        f"# Model card: `{Path(model.path).name}`",
        "",
        "The learned correction of vrcorrect: one conditioned U-Net for every eye in its range "
        "(see docs/learned.md).",
        "",
        "## What it is",
        f"- inputs: `image` and `precorrected` ({_precorrection_text(meta)}), float32 (N, 3, H, W) linear "
        "display RGB; `eye` "
        "(N, 4): power vector M, J0, J45 and pupil, scaled by the training ranges"
        + ("; `gradient` (N, 3, H, W): the projected-gradient step at the pre-correction"
           if "gradient" in meta.get("vrcorrect.inputs", "") else "") + "; output: the displayed image",
        f"- display: {model.display.get('name')}; target: "
        + ("what the eye sees with glasses on" if model.reference == "glasses" else "the ideal image (A t)"),
        f"- ranges (anything outside is refused): {model.ranges.describe()}",
        f"- format {meta.get('vrcorrect.format')}, opset {meta.get('vrcorrect.opset')}, precision "
        f"{meta.get('vrcorrect.precision', 'fp32')}, vrcorrect {meta.get('vrcorrect.version')}",
        "",
        "## Data and training",
        *_training_lines(train),
        "",
        "## What the network itself adds",
        "",
        f"Over its own pre-correction input, on the held-out cases below: gap closed "
        f"{100 * summary['gap_closed']:.0f} % against {100 * summary['gap_closed_precorrected']:.0f} % for the input "
        f"alone ({100 * (summary['gap_closed'] - summary['gap_closed_precorrected']):+.1f} points); FLIP "
        f"{summary['flip_learned']:.3f} against {summary['flip_precorrected']:.3f}. The rest of the gain over no "
        "correction comes from the projected-gradient steps that make its input.",
        "",
        "## Measured (held-out images and eyes; `vrcorrect bench learned`)",
        "",
        bench_md.split("\n", 2)[2],
    ]) + "\n"
