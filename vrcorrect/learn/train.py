"""Training the conditioned U-Net on a data set of :mod:`vrcorrect.learn.dataset` (torch).

Loss, per sample ``b`` of a batch, averaged over the batch::

    loss_b = (1 - w) * J(x_b) / J(t_b)  +  w * |x_b - f_b|^2 / |t_b - f_b|^2

* ``J`` is the objective every correction method minimises (:func:`vrcorrect.solvers.objective`):
  the mean squared error between the retinal cone image of the displayed image ``x`` -
  the sample's own kernel ``K[lms, primary]`` applied by FFT as a linear convolution with
  the panel black outside the crop, exactly ``fast``'s forward model - and the glasses-on
  cone image ``target_lms``.  Dividing by the uncorrected crop's objective ``J(t_b)`` makes
  every eye count alike (a -6 D eye's raw objective is far larger than a -0.5 D eye's): the
  ratio is 1 for no correction and ``fast`` reaches below it.  Denominators are floored at
  :data:`DENOMINATOR_FLOOR` (an eye in focus has an uncorrected objective of 0).
* The second term is the distance to ``fast``'s solution ``f_b``, relative to the
  uncorrected image's distance to it (1 at the start).  It is a guide, not the goal:
  the objective alone has many near-equivalent minimisers in frequencies the eye removes,
  and pulling towards ``fast``'s choice among them keeps the output free of high-frequency
  noise the eye cannot see but a healthy eye (or the metric FLIP) would.  ``w`` (default
  0.2) is ``target_weight``; 0 trains on the objective alone.

Batches are a pure function of ``(seed, step)``: each epoch visits the shards in an order
drawn from ``(seed, epoch)`` and the samples of each shard in an order drawn from
``(seed, epoch, shard)``; so a run resumed from its checkpoint sees the same batches as
one never interrupted.  Adam; the learning rate is constant, or (``lr_schedule="cosine"``)
falls along a half cosine from ``learning_rate`` at step 0 to 1 % of it at ``steps`` - a run
resumed under that schedule must keep its ``steps``, since they shape the curve.

Fine-tuning (``init``): a new run may start from another run's weights - for example one
trained with another ``target_weight`` - with a fresh optimiser and step 0; the sizes must
match, the data set must have the same ranges and display, and the checkpoint records
where the weights came from (its run's step and settings), so an export can say so.

Run folder: ``checkpoint.pt`` (model, optimiser, step, configurations, the data set's
ranges and display; written atomically every ``checkpoint_every`` steps and at the end),
``log.csv`` (``step,loss,objective_ratio,distance_ratio,lr,seconds``), ``train.json``
(settings).
"""

from __future__ import annotations

import csv
import io
import json
import math
import sys
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from .. import __version__
from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import write_text_atomic, write_with
from .dataset import load_shard, read_manifest
from .model import ConditionedUNet, UNetConfig

CHECKPOINT = "checkpoint.pt"
LOG = "log.csv"
SETTINGS = "train.json"
LOG_COLUMNS = ("step", "loss", "objective_ratio", "distance_ratio", "lr", "seconds")
#: Learning-rate schedules.
LR_SCHEDULES = ("constant", "cosine")
#: Where the cosine schedule ends, relative to ``learning_rate``.
COSINE_FINAL = 0.01
CHECKPOINT_FORMAT = "vrcorrect-learned-checkpoint"
#: Floor of the loss's denominators (objective and squared distance units): an eye in focus has an
#: uncorrected objective of 0, which must not turn a tiny deviation into a huge loss.
DENOMINATOR_FLOOR = 1e-6


@dataclass(frozen=True)
class TrainConfig:
    """Training settings (a resumed run must have the same ones, ``steps`` aside).

    Attributes
    ----------
    steps
        Total optimiser steps.
    batch_size
        Samples per step (at most the data set's size is used).
    learning_rate
        Adam's step size.
    target_weight
        ``w`` of the loss (0 to 1): weight of the distance to ``fast``'s solution.
    lr_schedule
        ``"constant"`` (default) or ``"cosine"`` (down to 1 % of ``learning_rate`` at ``steps``).
    seed
        Seed of the initial weights and of the batch order.
    checkpoint_every
        Steps between checkpoints (one is always written at the end).
    model
        The U-Net's size.
    """

    steps: int = 20000
    batch_size: int = 8
    learning_rate: float = 1e-3
    target_weight: float = 0.2
    lr_schedule: str = "constant"
    seed: int = 0
    checkpoint_every: int = 500
    model: UNetConfig = field(default_factory=UNetConfig)

    def __post_init__(self) -> None:
        for name, lo, hi in (("steps", 1, 100_000_000), ("batch_size", 1, 4096), ("checkpoint_every", 1, 100_000_000)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValidationError(name, v, f"an integer from {lo} to {hi}")
        if not (0.0 < self.learning_rate < 1.0):
            raise ValidationError("learning_rate", self.learning_rate, "a number in (0, 1)")
        if not (0.0 <= self.target_weight <= 1.0):
            raise ValidationError("target_weight", self.target_weight, "a number from 0 to 1")
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValidationError("lr_schedule", self.lr_schedule, " or ".join(LR_SCHEDULES))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValidationError("seed", self.seed, "a non-negative integer")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def learning_rate_at(self, step: int) -> float:
        """The learning rate of optimiser step ``step`` (0-based)."""
        if self.lr_schedule == "constant":
            return self.learning_rate
        final = COSINE_FINAL * self.learning_rate
        progress = min(step, self.steps) / self.steps
        return final + (self.learning_rate - final) * 0.5 * (1.0 + math.cos(math.pi * progress))

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> "TrainConfig":
        d = {k: v for k, v in doc.items() if k in cls.__dataclass_fields__}
        d["model"] = UNetConfig.from_dict(d.get("model", {}))
        return cls(**d)


# --------------------------------------------------------------------------
# Forward model in torch (the objective of vrcorrect.solvers, batched)
# --------------------------------------------------------------------------

def retina(x: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Retinal cone image: ``y[b, k] = sum_c K[b, k, c] * x[b, c]``, linear convolution by FFT,
    zero (a black panel) outside the image, cropped to the image.

    Parameters
    ----------
    x
        ``(N, 3, H, W)`` linear display RGB.
    kernel
        ``(N, 3 cones, 3 primaries, S, S)``, ``S`` odd, centred.

    Returns
    -------
    torch.Tensor
        ``(N, 3, H, W)`` cone responses.
    """
    H, W = x.shape[-2:]
    S = kernel.shape[-1]
    r = S // 2
    P = (H + S - 1, W + S - 1)
    X = torch.fft.rfft2(x, s=P)
    Kf = torch.fft.rfft2(kernel, s=P)
    y = torch.fft.irfft2(torch.einsum("bkcyx,bcyx->bkyx", Kf, X), s=P)
    return y[..., r:r + H, r:r + W]


def objective_per_sample(x: torch.Tensor, kernel: torch.Tensor, target_lms: torch.Tensor) -> torch.Tensor:
    """:func:`vrcorrect.solvers.objective` of each sample, ``(N,)``."""
    d = retina(x, kernel) - target_lms
    return (d * d).mean(dim=(1, 2, 3))


def gradient_step(x: torch.Tensor, kernel: torch.Tensor, target_lms: torch.Tensor) -> torch.Tensor:
    """``K^H (K x - t) / ||K||^2`` per sample (the model's optional gradient input), by autograd of
    the objective: the same quantity :func:`vrcorrect.solvers.fista.gradient_step` computes in numpy."""
    with torch.enable_grad():
        xg = x.detach().requires_grad_(True)
        d = retina(xg, kernel) - target_lms
        (g,) = torch.autograd.grad(0.5 * (d * d).sum(), xg)
    lipschitz = torch.linalg.matrix_norm(kernel.sum(dim=(-2, -1)).double(), ord=2) ** 2
    return (g / lipschitz.to(g.dtype)[:, None, None, None]).detach()


def forward_batch(model: ConditionedUNet, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """The model's output on a batch (its gradient input computed here when it takes one)."""
    if model.config.gradient_input:
        g = gradient_step(batch["precorrected"], batch["kernel"], batch["target_lms"])
        return model(batch["target"], batch["precorrected"], batch["features"], g)
    return model(batch["target"], batch["precorrected"], batch["features"])


def loss_terms(x: torch.Tensor, batch: dict[str, torch.Tensor], target_weight: float
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(loss, objective_ratio, distance_ratio)``, the last two per sample (see the module docstring)."""
    obj = objective_per_sample(x, batch["kernel"], batch["target_lms"])
    ratio = obj / batch["objective_uncorrected"].clamp_min(DENOMINATOR_FLOOR)
    dist = ((x - batch["fast"]) ** 2).mean(dim=(1, 2, 3))
    dist0 = ((batch["target"] - batch["fast"]) ** 2).mean(dim=(1, 2, 3))
    dratio = dist / dist0.clamp_min(DENOMINATOR_FLOOR)
    loss = ((1.0 - target_weight) * ratio + target_weight * dratio).mean()
    return loss, ratio, dratio


# --------------------------------------------------------------------------
# Batches: a pure function of (seed, step)
# --------------------------------------------------------------------------

class ShardedSamples:
    """The samples of a data set folder, read shard by shard (a few shards kept in memory)."""

    def __init__(self, dataset_dir: str | Path, cache_shards: int = 4):
        self.dir = Path(dataset_dir)
        self.manifest = read_manifest(self.dir)
        entries = sorted(self.manifest["shards"], key=lambda e: e["shard"])
        if not entries:
            raise InputError(f"{self.dir}: the data set has no finished shard yet")
        expected = -(-self.manifest["config"]["samples"] // self.manifest["config"]["samples_per_shard"])
        self.complete = len(entries) == expected
        self.entries = entries
        self.sizes = [len(e["samples"]) for e in entries]
        self.total = sum(self.sizes)
        self._cache: OrderedDict[int, dict[str, np.ndarray]] = OrderedDict()
        self._cache_shards = cache_shards
        self._order_key: tuple[int, int] | None = None
        self._order: list[tuple[int, int]] = []

    def shard(self, i: int) -> dict[str, np.ndarray]:
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        data = load_shard(self.dir, self.entries[i])
        self._cache[i] = data
        if len(self._cache) > self._cache_shards:
            self._cache.popitem(last=False)
        return data

    def epoch_order(self, seed: int, epoch: int) -> list[tuple[int, int]]:
        """``(shard, position)`` pairs of one epoch (the last epoch's order is kept)."""
        if self._order_key == (seed, epoch):
            return self._order
        rng = np.random.default_rng([seed, epoch])
        order = []
        for s in rng.permutation(len(self.entries)):
            within = np.random.default_rng([seed, epoch, int(s)]).permutation(self.sizes[s])
            order += [(int(s), int(j)) for j in within]
        self._order_key, self._order = (seed, epoch), order
        return order

    def batch(self, seed: int, step: int, batch_size: int) -> dict[str, np.ndarray]:
        """The batch of optimiser step ``step`` (0-based)."""
        B = min(batch_size, self.total)
        per_epoch = self.total // B
        epoch, k = divmod(step, per_epoch)
        picks = self.epoch_order(seed, epoch)[k * B:(k + 1) * B]
        rows = [(self.shard(s), j) for s, j in picks]
        S = max(int(d["kernel"].shape[-1]) for d, _ in rows)

        def kern(d: dict, j: int) -> np.ndarray:
            p = (S - d["kernel"].shape[-1]) // 2
            return np.pad(d["kernel"][j], ((0, 0), (0, 0), (p, p), (p, p)))

        out = {key: np.stack([d[key][j] for d, j in rows])
               for key in ("target", "precorrected", "fast", "target_lms", "features", "objective_uncorrected")}
        out["kernel"] = np.stack([kern(d, j) for d, j in rows])
        return out


def _tensors(batch: dict[str, np.ndarray], device: str) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(v, dtype=torch.float32, device=device) for k, v in batch.items()}


# --------------------------------------------------------------------------
# Checkpoints and the run folder
# --------------------------------------------------------------------------

def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """A checkpoint written by :func:`train` (``InputError`` if it is not one)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such checkpoint")
    try:
        ckpt = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:                              # torch raises several types here
        raise InputError(f"{p}: not a readable checkpoint ({type(exc).__name__}: {exc})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{p}: not a vrcorrect learned-model checkpoint")
    return ckpt


def model_from_checkpoint(ckpt: dict[str, Any]) -> ConditionedUNet:
    """The trained model of a checkpoint, in eval mode."""
    model = ConditionedUNet(UNetConfig.from_dict(ckpt["train_config"]["model"]))
    model.load_state_dict(ckpt["model"])
    return model.eval()


def _save_checkpoint(run_dir: Path, model, optimiser, step: int, config: TrainConfig, data: ShardedSamples,
                     init: dict[str, Any] | None = None) -> None:
    m = data.manifest
    ckpt = {"format": CHECKPOINT_FORMAT, "step": step, "model": model.state_dict(), "init": init,
            "optimizer": optimiser.state_dict(), "train_config": config.as_dict(),
            "dataset": {"path": str(data.dir), "samples": data.total, "config": m["config"],
                        "display": m["display"], "reference": m.get("reference", "glasses"),
                        "images": [{"name": i["name"]} for i in m.get("images", [])]},
            "vrcorrect_version": __version__}

    def write(tmp: Path) -> None:
        torch.save(ckpt, tmp)

    write_with(run_dir / CHECKPOINT, write, force=True)


def _read_log(path: Path, up_to_step: int) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        return [row for row in csv.DictReader(f) if int(row["step"]) <= up_to_step]


def _log_text(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=LOG_COLUMNS, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


@dataclass(frozen=True)
class TrainReport:
    """What :func:`train` did."""

    run_dir: Path
    start_step: int
    steps: int
    first_loss: float | None
    last_loss: float | None
    seconds: float


def _init_from(path: str | Path, config: TrainConfig, data: ShardedSamples) -> tuple[dict, dict[str, Any]]:
    """The weights of another run's checkpoint to start from, and what to record about them."""
    ckpt = load_checkpoint(path)
    theirs = UNetConfig.from_dict(ckpt["train_config"]["model"])
    if theirs != config.model:
        raise ValidationError("--init", str(path), f"a checkpoint of the same model settings ({config.model}); "
                              f"it has {theirs}")
    mine = data.manifest
    for key in ("ranges", "precorrection_steps", "precorrection_mu_rel"):
        if ckpt["dataset"]["config"].get(key) != mine["config"].get(key):
            raise ValidationError("--init", str(path), f"a checkpoint trained with the data set's {key} "
                                  f"({mine['config'].get(key)}); it has {ckpt['dataset']['config'].get(key)}")
    if ckpt["dataset"]["display"] != mine["display"]:
        raise ValidationError("--init", str(path), f"a checkpoint trained for the data set's display "
                              f"({mine['display'].get('name')})")
    record = {"path": str(path), "step": int(ckpt["step"]), "train_config": ckpt["train_config"],
              "init": ckpt.get("init")}
    return ckpt["model"], record


def train(dataset_dir: str | Path, run_dir: str | Path, config: TrainConfig, resume: bool = False,
          force: bool = False, device: str | None = None, progress: bool = True,
          init: str | Path | None = None) -> TrainReport:
    """Train (or continue training) a model; see the module docstring.

    Parameters
    ----------
    dataset_dir
        A data set folder (:func:`vrcorrect.learn.dataset.build_dataset`).
    run_dir
        Folder for the checkpoint, log and settings (created if missing).
    config
        Training settings.
    resume
        Continue from ``run_dir/checkpoint.pt`` (same settings; ``steps`` may grow).
        Without a checkpoint there, training starts from step 0.
    force
        Start again from step 0 even though ``run_dir`` holds a checkpoint (it is replaced).
    init
        Start from this checkpoint's weights (fine-tuning; see the module docstring).  Not with
        ``resume``, which continues this run's own checkpoint.
    device
        torch device (default: ``cuda`` when available, else ``cpu``).
    progress
        Show a tqdm bar on stderr.

    Returns
    -------
    TrainReport
    """
    run = Path(run_dir)
    if run.exists() and not run.is_dir():
        raise InputError(f"{run}: is not a folder")
    ckpt_path = run / CHECKPOINT
    if ckpt_path.exists() and not resume and not force:
        raise InputError(f"{ckpt_path}: a training run is already here; pass --resume to continue it "
                         "or --force to start again")
    if init is not None and resume:
        raise ValidationError("--init", str(init), "not with --resume (which continues this run's own checkpoint)")
    data = ShardedSamples(dataset_dir)
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    torch.manual_seed(config.seed)
    model = ConditionedUNet(config.model).to(device)
    init_record = None
    if init is not None:
        weights, init_record = _init_from(init, config, data)
        model.load_state_dict(weights)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    start = 0
    if resume and ckpt_path.exists():
        ckpt = load_checkpoint(ckpt_path)
        old = TrainConfig.from_dict(ckpt["train_config"])
        if {**old.as_dict(), "steps": 0, "checkpoint_every": 0} != {**config.as_dict(), "steps": 0,
                                                                    "checkpoint_every": 0}:
            raise InputError(f"{ckpt_path}: was trained with other settings ({old}); resume with the same "
                             "ones, or --force to start again")
        if config.lr_schedule == "cosine" and old.steps != config.steps:
            raise InputError(f"{ckpt_path}: was trained for --steps {old.steps} under the cosine schedule, whose "
                             f"curve the step count shapes; resume with --steps {old.steps}")
        if ckpt["dataset"]["config"] != data.manifest["config"]:
            raise InputError(f"{ckpt_path}: was trained on a different data set than {data.dir}")
        model.load_state_dict(ckpt["model"])
        optimiser.load_state_dict(ckpt["optimizer"])
        start = int(ckpt["step"])
        init_record = ckpt.get("init")
    run.mkdir(parents=True, exist_ok=True)
    settings = {"dataset": str(data.dir), "dataset_complete": data.complete, "samples": data.total,
                "device": device, "train_config": config.as_dict(), "init": init_record}
    write_text_atomic(run / SETTINGS, json.dumps(settings, indent=1) + "\n", force=True)
    rows: list[dict[str, Any]] = _read_log(run / LOG, start) if start else []
    write_text_atomic(run / LOG, _log_text(rows), force=True)
    model.train()
    first = last = None
    t0 = time.perf_counter()
    bar = tqdm(total=config.steps, initial=start, desc="train", unit="step",
               disable=None if progress else True, file=sys.stderr)
    try:
        with open(run / LOG, "a", newline="", encoding="utf-8") as log:
            writer = csv.DictWriter(log, fieldnames=LOG_COLUMNS, lineterminator="\n")
            for step in range(start, config.steps):
                batch = _tensors(data.batch(config.seed, step, config.batch_size), device)
                lr = config.learning_rate_at(step)
                for group in optimiser.param_groups:
                    group["lr"] = lr
                x = forward_batch(model, batch)
                loss, ratio, dratio = loss_terms(x, batch, config.target_weight)
                optimiser.zero_grad(set_to_none=True)
                loss.backward()
                optimiser.step()
                value = float(loss.detach())
                if not math.isfinite(value):
                    raise InputError(f"training diverged at step {step + 1} (loss {value}); "
                                     "lower --learning-rate")
                first = value if first is None else first
                last = value
                writer.writerow({"step": step + 1, "loss": f"{value:.6g}",
                                 "objective_ratio": f"{float(ratio.detach().mean()):.6g}",
                                 "distance_ratio": f"{float(dratio.detach().mean()):.6g}", "lr": f"{lr:.6g}",
                                 "seconds": f"{time.perf_counter() - t0:.3f}"})
                log.flush()
                bar.update(1)
                bar.set_postfix(loss=f"{value:.4f}", refresh=False)
                if (step + 1) % config.checkpoint_every == 0 or step + 1 == config.steps:
                    _save_checkpoint(run, model, optimiser, step + 1, config, data, init_record)
    finally:
        bar.close()
    return TrainReport(run_dir=run, start_step=start, steps=config.steps, first_loss=first, last_loss=last,
                       seconds=time.perf_counter() - t0)
