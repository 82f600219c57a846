"""Training the unrolled correction (:mod:`vrcorrect.learn.unrolled`) on the physics objective, for
every display preset and eyes over a prescription range (issue 25; torch).

By default no paired targets: the loss is the log of the objective of what the eye sees of the model's output
(the LMS error against the target's cone image with glasses) over that of the uncorrected image,
averaged over a batch of random crops, each with its own eye and display. With ``fast_weight``
above zero a pull towards ``fast``'s solution is added (the issue allows it; ``fast`` is the
objective's own optimum, not a judge): the training then draws from a bank of ``fast_bank`` crops
whose ``fast`` solutions are solved once, before the first step (:func:`fast_pull`). ``fast`` is
also the yardstick of :func:`evaluate`, which reports the share of ``fast``'s
objective gain over no correction that the learned model and its unlearned twin (the same stages,
no prior, ``fast``'s settings) close on held-out eyes and held-out images.

The kernels (an eye's cone x primary kernel bank and the same eye with glasses, per display) cost
seconds each; :func:`build_pool` builds them once, in worker processes, and the training draws
crops against them.

The command is ``vrcorrect unroll`` (:mod:`vrcorrect.apps.learning`); the kernels can be built as
Ray tasks (``--ray``); :mod:`vrcorrect.learn.unrolled_export` writes the ONNX model that
:mod:`vrcorrect.runtime.unrolled` runs.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from ..plumbing.errors import ValidationError
from ..plumbing.fileio import write_text_atomic
from ..solvers import solve
from ..solvers.admm import fast_start
from ..solvers.problem import Problem, light_cap
from ..specs.display import decode, get_display, preset_names
from ..specs.vocabulary import Method
from .conditioning import N_UNROLLED_FEATURES, SamplingRanges, unrolled_features
from .dataset import _pad_kernel, _ray_session, check_ray
from .train import objective_per_sample, retina
from .unrolled import UnrolledADMM, UnrolledConfig, kernel_spectra, twin

__all__ = ["UnrolledTrainConfig", "PoolEntry", "build_pool", "train_unrolled", "evaluate", "load_unrolled",
           "fast_solution", "fast_pull", "build_fast_bank"]

@dataclass(frozen=True)
class UnrolledTrainConfig:
    """What a training run does (everything its result depends on, besides the images)."""

    stages: int = 8
    prior_width: int = 16
    displays: tuple[str, ...] = field(default_factory=preset_names)
    eyes_per_display: int = 5
    held_out_eyes_per_display: int = 2
    crop_px: int = 64
    batch: int = 8
    steps: int = 2000
    minutes: float = 90.0
    lr: float = 2e-3
    settings_lr: float = 2e-2
    seed: int = 0
    ranges: SamplingRanges = field(default_factory=SamplingRanges)
    fast_weight: float = 0.0
    fast_bank: int = 64
    box_floor: float = 1e-3
    cap_share: float = 0.0
    """The share of training crops whose box is a robust design's light cap (``upper`` =
    :func:`~vrcorrect.solvers.problem.light_cap` of the crop), not [0, 1]."""

    def __post_init__(self) -> None:
        for name, lo, hi in (("stages", 1, 32), ("prior_width", 0, 256), ("eyes_per_display", 1, 1000),
                             ("held_out_eyes_per_display", 1, 1000), ("crop_px", 16, 512), ("batch", 1, 1024),
                             ("steps", 1, 10_000_000), ("seed", 0, 2**32 - 1), ("fast_bank", 1, 100_000)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
                raise ValidationError(name, value, f"an integer from {lo} to {hi}")
        if not (isinstance(self.minutes, (int, float)) and 0 < self.minutes <= 24 * 60):
            raise ValidationError("minutes", self.minutes, "a number of minutes in (0, 1440]")
        for name in ("lr", "settings_lr"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0 < value < 1):
                raise ValidationError(name, value, "a learning rate in (0, 1)")
        if isinstance(self.fast_weight, bool) or not (isinstance(self.fast_weight, (int, float))
                                                      and 0 <= self.fast_weight <= 1000):
            raise ValidationError("fast_weight", self.fast_weight, "a weight from 0 (no pull towards fast) to 1000")
        if isinstance(self.cap_share, bool) or not (isinstance(self.cap_share, (int, float)) and 0 <= self.cap_share <= 1):
            raise ValidationError("cap_share", self.cap_share, "a share of the crops from 0 (none capped) to 1 (all)")
        UnrolledConfig(stages=self.stages, prior_width=self.prior_width, box_floor=self.box_floor)  # its checks
        if not self.displays:
            raise ValidationError("displays", self.displays, "at least one display preset")
        for name in self.displays:
            get_display(name)                                   # an unknown preset: its own clear error


@dataclass(frozen=True)
class PoolEntry:
    """One eye on one display: its kernel bank, the same eye with glasses, and its features."""

    display: str
    eye: Any                     # EyeRx
    eye_kernel: Any              # EyeKernel: the eye on the display
    reference_kernel: Any        # EyeKernel: the same eye with glasses
    features: np.ndarray         # (N_UNROLLED_FEATURES,) float32: conditioning.unrolled_features

    @property
    def kernel(self) -> np.ndarray:
        """The ``(3, 3, s, s)`` float64 kernel bank."""
        return self.eye_kernel.kernel

    @property
    def reference(self) -> np.ndarray:
        return self.reference_kernel.kernel


def _entry(job: tuple[str, Any, SamplingRanges]) -> PoolEntry:
    from ..physics.kernel import build_kernel, build_reference_kernel  # in the worker: its own start-up

    name, eye, ranges = job
    display = get_display(name)
    k = build_kernel(eye, display)
    r = build_reference_kernel(eye, display)
    return PoolEntry(name, eye, k, r, unrolled_features(eye, k.size, ranges))


def build_pool(config: UnrolledTrainConfig, progress: Callable[[int, int], None] | None = None,
               workers: int = 2, ray_address: str | None = None) -> dict[str, list[PoolEntry]]:
    """Kernels for ``train`` and ``held_out`` eyes on every display of ``config`` (eyes drawn from
    ``config.ranges`` with the run's seed; held-out eyes from a stream of their own), in ``workers``
    local processes or, with ``ray_address`` (``local``, ``auto``, ``HOST:PORT``, ``ray://...``), one
    Ray task per eye (:func:`vrcorrect.learn.dataset.check_ray`'s addresses; a process already
    connected to Ray keeps its connection). The same eyes either way, in the same order."""
    jobs: dict[str, list[tuple[str, Any, SamplingRanges]]] = {"train": [], "held_out": []}
    for split, per, offset in (("train", config.eyes_per_display, 0), ("held_out", config.held_out_eyes_per_display, 1)):
        rng = np.random.default_rng([config.seed, offset])
        for name in config.displays:
            jobs[split] += [(name, config.ranges.sample(rng), config.ranges) for _ in range(per)]
    everything = jobs["train"] + jobs["held_out"]
    results: list[PoolEntry] = []

    def record(entry: PoolEntry) -> None:
        results.append(entry)
        if progress is not None:
            progress(len(results), len(everything))

    if ray_address is not None:
        check_ray(ray_address)
        with _ray_session(ray_address, max(1, workers)) as ray:
            task = ray.remote(_entry)
            for ref in [task.remote(job) for job in everything]:      # in order: the pool's order is the jobs'
                record(ray.get(ref))
    else:
        with ProcessPoolExecutor(max_workers=max(1, workers)) as pool:
            for entry in pool.map(_entry, everything):
                record(entry)
    n = len(jobs["train"])
    return {"train": results[:n], "held_out": results[n:]}


def make_batch(entries: Sequence[PoolEntry], crops: Sequence[np.ndarray], capped: np.ndarray | None = None
               ) -> dict[str, Any]:
    """Tensors for one batch: ``target`` (linear RGB), ``target_lms`` (what the eye sees of it with
    glasses), ``spectrum``, ``gram`` and ``norm2`` (:func:`kernel_spectra`, on
    ``fast``'s grid: the least that does not wrap, three times cheaper here than a
    power-of-two grid, and the model is the same on either), ``kernel`` (padded to one size),
    ``features``, and ``fast``'s start ``z0`` with its duals ``d1``, ``d2``
    (:func:`~vrcorrect.solvers.admm.fast_start`). ``crops`` are sRGB-coded ``(h, w, 3)`` crops, one per entry.
    ``capped`` (bool per crop): those crops' box is a robust design's, under the light cap
    (:func:`~vrcorrect.solvers.problem.light_cap`; the batch's ``upper``, 1 for the others), and
    their start is ``fast``'s under it."""
    shape = crops[0].shape[:2]
    t = np.stack([decode(get_display(e.display), c).astype(np.float32).transpose(2, 0, 1)
                  for e, c in zip(entries, crops)])
    target = torch.from_numpy(t)
    s = max(e.kernel.shape[-1] for e in entries)
    r = max(e.reference.shape[-1] for e in entries)
    kernel = torch.from_numpy(np.stack([_pad_kernel(e.kernel, s) for e in entries]).astype(np.float32))
    reference = torch.from_numpy(np.stack([_pad_kernel(e.reference, r) for e in entries]).astype(np.float32))
    with torch.no_grad():
        target_lms = retina(target, reference)
    spectrum, gram, norm2 = kernel_spectra([e.kernel for e in entries], shape, power_of_two=False)
    features = torch.from_numpy(np.stack([e.features for e in entries]))
    capped = np.zeros(len(entries), bool) if capped is None else np.asarray(capped, bool)
    starts = [fast_start(e.kernel, t[i], target_lms[i].numpy(), capped=bool(capped[i])) for i, e in enumerate(entries)]
    z0, d1, d2 = (torch.from_numpy(np.stack([s[j] for s in starts])) for j in range(3))
    batch = {"target": target, "target_lms": target_lms, "spectrum": spectrum, "gram": gram, "norm2": norm2,
             "kernel": kernel, "features": features, "z0": z0, "d1": d1, "d2": d2}
    if capped.any():
        upper = np.where(capped[:, None, None, None], light_cap(t), np.float32(1.0))
        batch["upper"] = torch.from_numpy(np.ascontiguousarray(upper, np.float32))
    return batch


def run_model(model: UnrolledADMM, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """``model`` on a batch of :func:`make_batch`, from ``fast``'s start (the box's top ``upper``
    where the batch has one)."""
    return model(batch["target_lms"], batch["z0"], batch["spectrum"], batch["gram"], batch["norm2"],
                 features=batch["features"] if model.mlp is not None else None, target=batch["target"],
                 d1=batch["d1"], d2=batch["d2"], upper=batch.get("upper"))


def _crops(images: Sequence[np.ndarray], rng: np.random.Generator, n: int, size: int) -> list[np.ndarray]:
    out = []
    for _ in range(n):
        im = images[int(rng.integers(len(images)))]
        y = int(rng.integers(0, im.shape[0] - size + 1))
        x = int(rng.integers(0, im.shape[1] - size + 1))
        out.append(np.ascontiguousarray(im[y:y + size, x:x + size]))
    return out


def evaluate(model: UnrolledADMM, cases: Sequence[tuple[PoolEntry, np.ndarray]],
             fast_objectives: Sequence[float]) -> dict[str, Any]:
    """The share of ``fast``'s objective gain over no correction each case gets from ``model`` and
    from its twin (``model.config.stages`` stages): medians, minima, the mean share left open (a
    case past ``fast`` counts 0: the issue's halving goal) and per case."""
    shares: dict[str, list[float]] = {"learned": [], "twin": []}
    tw = twin(model.config.stages)
    with torch.no_grad():
        for i, (entry, crop) in enumerate(cases):
            b = make_batch([entry], [crop])
            none = float(objective_per_sample(b["target"], b["kernel"], b["target_lms"])[0])
            gain = none - float(fast_objectives[i])
            for name, m in (("learned", model), ("twin", tw)):
                obj = float(objective_per_sample(run_model(m, b), b["kernel"], b["target_lms"])[0])
                shares[name].append((none - obj) / gain if gain > 0 else float("nan"))
    summary = {name: {"median": float(np.nanmedian(v)), "min": float(np.nanmin(v)),
                      "mean_open": float(np.nanmean(np.maximum(0.0, 1.0 - np.asarray(v)))), "cases": v}
               for name, v in shares.items()}
    return summary


def fast_solution(entry: PoolEntry, crop: np.ndarray, batch: dict[str, torch.Tensor] | None = None) -> np.ndarray:
    """``fast``'s displayed image for ``crop`` seen by ``entry``'s eye, ``(3, h, w)`` float32 linear RGB,
    in the training's own forward model (``batch``: :func:`make_batch` of them, when already made)."""

    b = batch if batch is not None else make_batch([entry], [crop])
    problem = Problem(target=b["target"][0].numpy().transpose(1, 2, 0).copy(), kernel=entry.eye_kernel,
                      target_lms=b["target_lms"][0].numpy().transpose(1, 2, 0).copy(), reference="glasses",
                      reference_kernel=entry.reference_kernel)
    shown = solve(problem, Method.FAST).image.astype(np.float32)
    return np.ascontiguousarray(shown.transpose(2, 0, 1))


def _fast_job(job: tuple[PoolEntry, np.ndarray]) -> np.ndarray:
    return fast_solution(*job)


def fast_objectives(cases: Sequence[tuple[PoolEntry, np.ndarray]]) -> list[float]:
    """``fast``'s objective on each case (the yardstick), in the training's own forward model."""
    out = []
    for entry, crop in cases:
        b = make_batch([entry], [crop])
        x = torch.from_numpy(fast_solution(entry, crop, b))[None]
        out.append(float(objective_per_sample(x, b["kernel"], b["target_lms"])[0]))
    return out


def fast_pull(shown: torch.Tensor, fast: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per sample, the mean squared distance of ``shown`` from ``fast``'s solution over that of the
    target from it (0 at ``fast``, 1 as far from it as showing the target): a scale-free pull."""
    dims = tuple(range(1, shown.ndim))
    return ((shown - fast) ** 2).mean(dim=dims) / ((target - fast) ** 2).mean(dim=dims).clamp_min(1e-10)


def build_fast_bank(config: UnrolledTrainConfig, pool: dict[str, list[PoolEntry]], images: Sequence[np.ndarray],
                    workers: int = 1, progress: Callable[[int, int], None] | None = None
                    ) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """``config.fast_bank`` training crops, each with a training eye and ``fast``'s solution for it:
    ``(eye index in pool["train"], crop, solution)``, drawn with the run's seed, solved in ``workers``
    processes."""
    rng = np.random.default_rng([config.seed, 4])
    eyes = [int(i) for i in rng.integers(len(pool["train"]), size=config.fast_bank)]
    crops = _crops(images, rng, config.fast_bank, config.crop_px)
    jobs = [(pool["train"][i], c) for i, c in zip(eyes, crops)]
    solutions: list[np.ndarray] = []
    with ProcessPoolExecutor(max_workers=workers) if workers > 1 else nullcontext() as ex:
        for x in (ex.map if ex is not None else map)(_fast_job, jobs):
            solutions.append(x)
            if progress is not None:
                progress(len(solutions), len(jobs))
    return list(zip(eyes, crops, solutions))


CHECKPOINT_FORMAT = "vrcorrect-unrolled-checkpoint"   # the trained model (unrolled.pt): save_unrolled, load_unrolled
CHECKPOINT = "checkpoint.pt"
"""The training's state in the run folder, written every :data:`CHECKPOINT_EVERY_S` and at the end."""
CHECKPOINT_EVERY_S = 60.0


def _config_key(config: UnrolledTrainConfig) -> str:
    """What a checkpoint must share with the run that resumes it (everything but the time budget)."""
    fields = {k: v for k, v in config.__dict__.items() if k not in ("minutes", "ranges")}
    return repr(sorted(fields.items())) + repr(config.ranges.as_dict())


def train_unrolled(run_dir: str | Path, config: UnrolledTrainConfig, train_images: Sequence[np.ndarray],
                   held_out_images: Sequence[np.ndarray], pool: dict[str, list[PoolEntry]] | None = None,
                   progress: Callable[[int, float], None] | None = None, held_out_cases: int = 24,
                   bank: list[tuple[int, np.ndarray, np.ndarray]] | None = None,
                   about: dict[str, Any] | None = None, resume: bool = False,
                   checkpoint_every_s: float = CHECKPOINT_EVERY_S) -> dict[str, Any]:
    """Train an :class:`UnrolledADMM` for ``config.steps`` steps or ``config.minutes``, whichever
    ends first (cosine learning rate over the steps), evaluate it against its twin on held-out
    eyes and images, and write ``unrolled.pt``, ``log.csv`` and ``report.json`` in ``run_dir``.
    With ``config.fast_weight`` above zero the crops come from ``bank`` (:func:`build_fast_bank`;
    built here, in this process, when not given). ``about``: more for the report (the images' size,
    the machine).  The training's state (weights, optimiser, schedule, random streams, log) goes to
    ``run_dir/checkpoint.pt`` every ``checkpoint_every_s`` seconds of training and at its end;
    ``resume`` continues from it (the same configuration; the time budget counts the time already
    trained), as if the run had not stopped.  Returns the report."""

    run = Path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng([config.seed, 2])
    pool = pool if pool is not None else build_pool(config)
    held_rng = np.random.default_rng([config.seed, 3])
    cases = [(pool["held_out"][i % len(pool["held_out"])], c)
             for i, c in enumerate(_crops(held_out_images, held_rng, held_out_cases, config.crop_px))]
    fast_obj = fast_objectives(cases)
    if config.fast_weight > 0 and bank is None:
        bank = build_fast_bank(config, pool, train_images)
    model = UnrolledADMM(UnrolledConfig(stages=config.stages, prior_width=config.prior_width,
                                        features=N_UNROLLED_FEATURES, box_floor=config.box_floor))
    # the stage settings are a few log-scale numbers a stage: a step of 2e-3 would take 1,000 steps
    # to move the box weight by e; the prior's weights take the usual rate
    settings = [model.stage_base] + (list(model.mlp.parameters()) if model.mlp is not None else [])
    groups = [{"params": settings, "lr": config.settings_lr}]
    if model.prior is not None:
        groups.append({"params": list(model.prior.parameters()), "lr": config.lr})
    optimiser = torch.optim.Adam(groups)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda s: 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(s / config.steps, 1.0))))
    log = io.StringIO()
    writer = csv.writer(log)
    step = 0
    trained_s = 0.0                                 # seconds trained before this process (a resumed run)
    checkpoint = run / CHECKPOINT
    if resume and checkpoint.is_file():
        state = torch.load(checkpoint, map_location="cpu", weights_only=False)
        if not isinstance(state, dict) or state.get("format") != "vrcorrect-unrolled-training":
            raise ValidationError("--resume", str(checkpoint), "a checkpoint written by vrcorrect unroll")
        if state["config"] != _config_key(config):
            raise ValidationError("--resume", str(checkpoint), "a checkpoint of the same configuration (the options "
                                  "but --minutes as the run that wrote it)")
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        schedule.load_state_dict(state["schedule"])
        rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        step, trained_s = int(state["step"]), float(state["seconds"])
        log.write(state["log"])
    else:
        writer.writerow(["step", "loss", "lr", "seconds"])

    def save_checkpoint(seconds: float) -> None:
        state = {"format": "vrcorrect-unrolled-training", "config": _config_key(config), "step": step,
                 "seconds": seconds, "model": model.state_dict(), "optimiser": optimiser.state_dict(),
                 "schedule": schedule.state_dict(), "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                 "log": log.getvalue()}
        tmp = checkpoint.with_name(checkpoint.name + ".tmp")
        torch.save(state, tmp)
        tmp.replace(checkpoint)

    t0 = time.perf_counter() - trained_s
    saved = time.perf_counter()
    while step < config.steps and time.perf_counter() - t0 < 60.0 * config.minutes:
        if config.fast_weight > 0:
            drawn = [bank[int(i)] for i in rng.integers(len(bank), size=config.batch)]
            b = make_batch([pool["train"][e] for e, _, _ in drawn], [c for _, c, _ in drawn])
        else:
            idx = rng.integers(len(pool["train"]), size=config.batch)
            capped = rng.random(config.batch) < config.cap_share if config.cap_share > 0 else None
            b = make_batch([pool["train"][i] for i in idx], _crops(train_images, rng, config.batch, config.crop_px),
                           capped)
        shown = run_model(model, b)
        obj = objective_per_sample(shown, b["kernel"], b["target_lms"])
        base = objective_per_sample(b["target"], b["kernel"], b["target_lms"])
        loss = torch.log(obj / base.clamp_min(1e-12)).mean()
        if config.fast_weight > 0:
            fast = torch.from_numpy(np.stack([x for _, _, x in drawn]))
            loss = loss + config.fast_weight * fast_pull(shown, fast, b["target"]).mean()
        optimiser.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimiser.step()
        schedule.step()
        step += 1
        writer.writerow([step, f"{loss.item():.5f}", f"{schedule.get_last_lr()[0]:.3e}",
                         f"{time.perf_counter() - t0:.1f}"])
        if time.perf_counter() - saved >= checkpoint_every_s:
            save_checkpoint(time.perf_counter() - t0)
            saved = time.perf_counter()
        if progress is not None:
            progress(step, loss.item())
    seconds = time.perf_counter() - t0
    save_checkpoint(seconds)
    result = evaluate(model, cases, fast_obj)
    report = {"config": {**{k: v for k, v in config.__dict__.items() if k != "ranges"},
                         "displays": list(config.displays), "ranges": config.ranges.as_dict()},
              **(about or {}),
              "steps": step, "seconds": seconds, "parameters": sum(p.numel() for p in model.parameters()),
              "held_out": {"cases": len(cases), "eyes": len(pool["held_out"]),
                           "displays": sorted({e.display for e in pool["held_out"]})},
              "share_of_fast_gain": {k: {"median": v["median"], "min": v["min"], "mean_open": v["mean_open"]}
                                     for k, v in result.items()},
              "per_case": [{"display": e.display, "learned": result["learned"]["cases"][i],
                            "twin": result["twin"]["cases"][i]} for i, (e, _) in enumerate(cases)]}
    save_unrolled(model, run / "unrolled.pt", report["config"])
    write_text_atomic(run / "log.csv", log.getvalue(), force=True)
    write_text_atomic(run / "report.json", json.dumps(report, indent=2) + "\n", force=True)
    return report


def save_unrolled(model: UnrolledADMM, path: str | Path, train: dict | None) -> None:
    """Save ``model`` as :func:`load_unrolled` reads it (``train``: the training configuration, as the
    report's ``config``)."""
    torch.save({"format": CHECKPOINT_FORMAT, "config": model.config.as_dict(),
                "state_dict": model.state_dict(), "train": train}, path)


def load_unrolled(path: str | Path) -> UnrolledADMM:
    """A model saved by :func:`train_unrolled` (:func:`save_unrolled`)."""
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise ValidationError("checkpoint", str(path), "a file written by train_unrolled (unrolled.pt)")
    model = UnrolledADMM(UnrolledConfig(**ckpt["config"]))
    model.load_state_dict(ckpt["state_dict"])
    return model


