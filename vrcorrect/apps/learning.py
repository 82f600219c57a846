"""``vrcorrect dataset`` and ``vrcorrect train``: the learned model's data set and training.

Argument parsing only at import (no torch); each command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import os
import pickle
from pathlib import Path

from ..plumbing.errors import InputError, ValidationError
from ..plumbing.images import bundled_images, folder_images
from .progress import Progress


def _presets() -> tuple[str, ...]:
    from ..specs.display import preset_names  # light: the presets' names

    return preset_names()


def _pair(field: str, values: list[float] | None, default: tuple[float, float]) -> tuple[float, float]:
    if values is None:
        return default
    lo, hi = values
    if lo > hi:
        raise ValidationError(field, f"{lo:g} {hi:g}", "LOW HIGH with LOW <= HIGH")
    return (lo, hi)


def cmd_dataset(args: argparse.Namespace) -> int:
    from ..learn.conditioning import SamplingRanges  # on use: start-up time (apps/__init__)
    from ..learn.dataset import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
        HELD_OUT_IMAGES,
        DatasetConfig,
        build_dataset,
        check_ray,
    )

    d = SamplingRanges()
    ranges = SamplingRanges(sphere_D=_pair("--sphere-D", args.sphere_D, d.sphere_D),
                            cylinder_D=_pair("--cylinder-D", args.cylinder_D, d.cylinder_D),
                            axis_deg=_pair("--axis-deg", args.axis_deg, d.axis_deg),
                            pupil_diameter_mm=_pair("--pupil-mm", args.pupil_mm, d.pupil_diameter_mm))
    config = DatasetConfig(samples=args.samples, crop_px=args.crop_px, seed=args.seed, ranges=ranges,
                           display=args.display, samples_per_shard=args.samples_per_shard,
                           wavelength_step_nm=args.wavelength_step_nm, crops_per_eye=args.crops_per_eye,
                           precorrection_steps=args.precorrection_steps)
    check_ray(args.ray)             # Ray installed? before loading any image
    if args.crop_px > args.image_px:
        raise ValidationError("--crop-px", args.crop_px, f"at most --image-px ({args.image_px})")
    if args.images:
        images = folder_images(args.images, args.image_px)
    else:                            # the benchmark's held-out images stay out of the training data
        images = [(n, im) for n, im in bundled_images(args.image_px) if n not in HELD_OUT_IMAGES]
    workers = args.workers if args.workers is not None else max(1, os.cpu_count() or 1)
    report = build_dataset(args.out, images, config, workers=workers, force=args.force, ray_address=args.ray)
    print(f"data set {report.out_dir}: {report.samples} samples in {config.shards} shards "
          f"({report.computed_shards} computed{f' on Ray ({args.ray})' if args.ray else ''}, "
          f"{report.skipped_shards} already there) in {report.seconds:.1f} s")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from ..learn.model import UNetConfig  # on use: start-up time (apps/__init__)
    from ..learn.train import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
        TrainConfig,
        train,
    )

    config = TrainConfig(steps=args.steps, batch_size=args.batch_size, learning_rate=args.learning_rate,
                         target_weight=args.target_weight, lr_schedule=args.lr_schedule, seed=args.seed,
                         checkpoint_every=args.checkpoint_every,
                         model=UNetConfig(width=args.width, depth=args.depth, film_hidden=args.film_hidden,
                                          base=args.base, gradient_input=args.gradient_input))
    report = train(args.dataset, args.out, config, resume=args.resume, force=args.force, device=args.device,
                   init=args.init)
    loss = "" if report.last_loss is None else f"; loss {report.first_loss:.4g} -> {report.last_loss:.4g}"
    print(f"trained steps {report.start_step}..{report.steps} in {report.seconds:.1f} s{loss}; "
          f"checkpoint {Path(report.run_dir) / 'checkpoint.pt'}, log {Path(report.run_dir) / 'log.csv'}")
    return 0


def cmd_train_unrolled(args: argparse.Namespace) -> int:
    from ..learn.dataset import HELD_OUT_IMAGES, check_ray  # on use: start-up time (apps/__init__)
    from ..learn.unrolled_export import (
        export_unrolled,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )
    from ..learn.unrolled_train import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
        CHECKPOINT,
        UnrolledTrainConfig,
        build_fast_bank,
        build_pool,
        train_unrolled,
    )
    from ..plumbing.fileio import (
        check_writable,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    check_ray(args.ray)                                             # Ray installed? before any work
    config = UnrolledTrainConfig(stages=args.stages, prior_width=args.prior_width, displays=tuple(args.displays),
                                 eyes_per_display=args.eyes_per_display, crop_px=args.crop_px, batch=args.batch_size,
                                 steps=args.steps, minutes=args.minutes, seed=args.seed,
                                 fast_weight=args.fast_weight, fast_bank=args.fast_bank, box_floor=args.box_floor,
                                 cap_share=args.cap_share)
    out = Path(args.out)
    if out.exists() and not out.is_dir():                         # all before minutes of kernels
        raise InputError(f"{out}: exists and is not a folder (-o names the run folder)")
    if args.resume and args.force:
        raise ValidationError("--resume", "with --force", "one of them: --resume continues RUN's checkpoint, --force "
                              "starts RUN over")
    if out.is_dir() and not args.resume:
        if (out / CHECKPOINT).exists() and not args.force:
            raise InputError(f"{out} holds a training checkpoint ({CHECKPOINT}): pass --resume to continue it, or "
                             "--force to start over")
        for name in ("unrolled.pt", "log.csv", "report.json", "unrolled.onnx"):
            check_writable(out / name, force=args.force)
    images = dict(bundled_images(args.image_px))
    train_images = [im for n, im in images.items() if n not in HELD_OUT_IMAGES]
    held_out = [im for n, im in images.items() if n in HELD_OUT_IMAGES]
    if args.crop_px > args.image_px:
        raise ValidationError("--crop-px", args.crop_px, f"at most --image-px ({args.image_px})")
    out.mkdir(parents=True, exist_ok=True)                          # runs/default as the README writes it
    print(f"unroll: run folder {out}; {len(config.displays)} display(s) x {config.eyes_per_display} training eyes, "
          f"{config.steps} steps of {config.batch} crops of {config.crop_px} px (or {config.minutes:g} minutes); the "
          f"training's checkpoint, {out / CHECKPOINT}, every minute (--resume continues it)", flush=True)
    workers = max(1, os.cpu_count() or 1)
    saved_pool = out / "pool.pickle"                                # the kernels, kept for --resume
    pool = _load_pickle(saved_pool) if args.resume else None
    if pool is None:
        with Progress("unroll: kernels", "eye") as bar:
            pool = build_pool(config, bar.update, workers=workers, ray_address=args.ray)
        _save_pickle(saved_pool, pool)
    bank = None
    if config.fast_weight > 0:
        saved_bank = out / "bank.pickle"
        bank = _load_pickle(saved_bank) if args.resume else None
        if bank is None:
            with Progress("unroll: fast's solutions", "crop", config.fast_bank) as bar:
                bank = build_fast_bank(config, pool, train_images, workers=workers, progress=bar.update)
            _save_pickle(saved_bank, bank)
    from ..studies.bench import (
        machine_description,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    about = {"image_px": args.image_px, "images": sorted(n for n in images if n not in HELD_OUT_IMAGES),
             "machine": machine_description()}
    with Progress("unroll: training", "step", config.steps) as bar:
        def step(n: int, loss: float) -> None:
            bar.update(n, note=f"loss {loss:.3f}")

        report = train_unrolled(out, config, train_images, held_out, pool=pool, progress=step, bank=bank, about=about,
                                resume=args.resume)
    exported = export_unrolled(out / "unrolled.pt", out / "unrolled.onnx", force=True)
    s = report["share_of_fast_gain"]
    print(f"trained {report['steps']} steps in {report['seconds']:.0f} s ({report['parameters']} parameters); "
          f"held-out eyes and images ({report['held_out']['cases']} cases, {len(config.displays)} displays): "
          f"share of fast's objective gain, median (min): learned {s['learned']['median']:.0%} "
          f"({s['learned']['min']:.0%}), its untrained twin {s['twin']['median']:.0%} ({s['twin']['min']:.0%}); "
          f"{out / 'unrolled.pt'}, {out / 'log.csv'}, {out / 'report.json'}; {exported.path} (onnxruntime equals "
          f"torch to {exported.max_abs_error:.1e}: vrcorrect correct --method learned --model {exported.path})")
    return 0


def _load_pickle(path: Path):
    """What :func:`_save_pickle` wrote for a run (its own kernels or bank), or None."""

    try:
        with open(path, "rb") as f:
            return pickle.load(f)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError):
        return None


def _save_pickle(path: Path, value) -> None:

    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
    tmp.replace(path)


def add_parser(sub) -> None:
    """Register ``dataset`` and ``train`` on the top-level sub-parsers."""
    p = sub.add_parser("dataset", help="build (or resume) the learned model's training data set",
                       description="Random crops of images x prescriptions sampled over the ranges, each "
                                   "corrected by the fast method; .npz shards + manifest.json in OUT. Re-running "
                                   "the same command resumes: finished shards are skipped.")
    p.add_argument("out", metavar="OUT", help="data set folder")
    p.add_argument("--images", metavar="FOLDER", help="PNG/JPEG folder (default: the bundled images but "
                   "rocket and retina, which vrcorrect bench learned holds out)")
    p.add_argument("--image-px", type=int, default=256, help="images are centre-cropped and resized to this (256)")
    p.add_argument("--samples", type=int, default=1000, help="number of samples (1000)")
    p.add_argument("--crop-px", type=int, default=128, help="side of the random crops (128)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (0)")
    p.add_argument("--display", default="quest2", metavar="PRESET", help="display preset or profile (quest2)")
    p.add_argument("--sphere-D", type=float, nargs=2, metavar=("LOW", "HIGH"), help="sphere range (-6 6)")
    p.add_argument("--cylinder-D", type=float, nargs=2, metavar=("LOW", "HIGH"),
                   help="minus-form cylinder range (-3 0)")
    p.add_argument("--axis-deg", type=float, nargs=2, metavar=("LOW", "HIGH"), help="axis range (0 180)")
    p.add_argument("--pupil-mm", type=float, nargs=2, metavar=("LOW", "HIGH"), help="pupil range (2 6)")
    p.add_argument("--samples-per-shard", type=int, default=32, help="samples per .npz shard (32)")
    p.add_argument("--crops-per-eye", type=int, default=1,
                   help="consecutive samples sharing one sampled eye (kernels built once per eye; default 1)")
    p.add_argument("--precorrection-steps", type=int, default=3,
                   help="projected-gradient steps of the model's pre-correction input (3; 0: the clipped "
                        "regularised inverse)")
    p.add_argument("--wavelength-step-nm", type=int, choices=(80, 40, 20, 10, 5, 1),
                   help="force the kernels' wavelength step (default: chosen per eye)")
    p.add_argument("--workers", type=int,
                   help="local processes, or the CPUs of --ray local (default: one per CPU core)")
    p.add_argument("--ray", metavar="ADDRESS",
                   help="one Ray task per shard on the Ray cluster at ADDRESS (auto, HOST:PORT, ray://HOST:10001; "
                        "local: a one-node Ray started here); every node needs vrcorrect installed, this "
                        "process writes the shards (no shared filesystem needed); the extra 'ray'")
    p.add_argument("--force", action="store_true", help="rebuild a folder that holds a data set with other settings")
    p.set_defaults(func=cmd_dataset)

    p = sub.add_parser("train", help="train the conditioned U-Net on a data set (torch)",
                       description="Adam on the LMS objective through each sample's eye kernel (relative to "
                                   "uncorrected) plus a pull towards fast's solution; checkpoint.pt, log.csv and "
                                   "train.json in OUT. --resume continues an interrupted run with the same batches.")
    p.add_argument("dataset", metavar="DATASET", help="data set folder (vrcorrect dataset)")
    p.add_argument("-o", "--out", required=True, metavar="RUN", help="run folder")
    p.add_argument("--steps", type=int, default=20000, help="total optimiser steps (20000)")
    p.add_argument("--batch-size", type=int, default=8, help="samples per step (8)")
    p.add_argument("--learning-rate", type=float, default=1e-3, help="Adam step size (1e-3)")
    p.add_argument("--lr-schedule", choices=("constant", "cosine"), default="constant",
                   help="learning rate: constant, or cosine down to 1 %% of it at --steps (constant)")
    p.add_argument("--target-weight", type=float, default=0.2,
                   help="weight of the distance to fast's solution, 0-1 (0.2; 0: objective only)")
    p.add_argument("--seed", type=int, default=0, help="seed of the weights and the batch order (0)")
    p.add_argument("--width", type=int, default=16, help="U-Net channels at full resolution (16)")
    p.add_argument("--depth", type=int, default=3, help="U-Net down-samplings (3)")
    p.add_argument("--film-hidden", type=int, default=32, help="hidden units of the FiLM MLP (32; 0: no FiLM)")
    p.add_argument("--base", choices=("precorrected", "image"), default="precorrected",
                   help="what the network's output is added to (precorrected: it starts as the pre-correction)")
    p.add_argument("--gradient-input", action="store_true",
                   help="also feed the network the projected-gradient step at the pre-correction (3 channels)")
    p.add_argument("--checkpoint-every", type=int, default=500, help="steps between checkpoints (500)")
    p.add_argument("--device", help="torch device (default: cuda when available, else cpu)")
    p.add_argument("--resume", action="store_true", help="continue from RUN/checkpoint.pt")
    p.add_argument("--init", metavar="CHECKPOINT.pt",
                   help="start from another run's weights (fine-tuning: same model settings and ranges; "
                        "fresh optimiser, step 0)")
    p.add_argument("--force", action="store_true", help="start again although RUN holds a checkpoint")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("unroll", help="train the learned correction: fast's ADMM unrolled, for every display "
                                      "(torch; the defaults make the shipped models/default.onnx)",
                       description="Build kernels for eyes drawn over the prescription ranges on each display, "
                                   "then train fast's ADMM unrolled into stages, with eye-dependent stage settings "
                                   "(retina penalty, relaxation, box weight) and optionally a learned prior, on the "
                                   "LMS objective of random crops; report the share of fast's objective gain it "
                                   "and its untrained twin close on held-out eyes and images. unrolled.pt, "
                                   "log.csv, report.json and the ONNX export unrolled.onnx (for vrcorrect correct "
                                   "--method learned --model, --backend onnx --model, --cold-start) in RUN (made "
                                   "if missing). The defaults took about 6 minutes on 2 idle CPU cores, and over 40 "
                                   "on 2 busy ones: the run shows its progress on standard error (a line every few "
                                   "seconds when it is not a terminal) and writes RUN/checkpoint.pt every minute; "
                                   "--resume continues a stopped run.")
    p.add_argument("-o", "--out", required=True, metavar="RUN", help="run folder")
    p.add_argument("--displays", nargs="+", default=list(_presets()), metavar="PRESET",
                   help="display presets (default: all)")
    p.add_argument("--eyes-per-display", type=int, default=5, help="training eyes per display (5)")
    p.add_argument("--stages", type=int, default=8, help="ADMM stages after fast's start, two FFT round trips "
                                                               "each (8)")
    p.add_argument("--prior-width", type=int, default=0,
                   help="channels of a prior network between the stages (0, the default: none, only the eye's "
                        "stage settings are learned; 16 was tried and costs FLIP on photographs)")
    p.add_argument("--crop-px", type=int, default=256, help="side of the training crops (256, the size the bench "
                   "judges; 64 is the least at which fast's start solves a half-resolution level first)")
    p.add_argument("--image-px", type=int, default=320, help="images are centre-cropped and resized to this (320)")
    p.add_argument("--batch-size", type=int, default=4, help="crops per step (4)")
    p.add_argument("--steps", type=int, default=200, help="optimiser steps (200)")
    p.add_argument("--minutes", type=float, default=60.0, help="stop training after this long, whatever the steps "
                   "(60; with the defaults a whole run took about 6 minutes on 2 idle cores)")
    p.add_argument("--seed", type=int, default=0, help="seed of the eyes, crops and weights (0)")
    p.add_argument("--fast-weight", type=float, default=0.0, metavar="W",
                   help="add W times a pull towards fast's solution to the objective's loss (0: none); the crops "
                        "then come from a bank whose fast solutions are solved before training")
    p.add_argument("--fast-bank", type=int, default=64, metavar="N",
                   help="with --fast-weight: training crops in the bank, each with its eye and fast's solution (64)")
    p.add_argument("--box-floor", type=float, default=0.07, metavar="B",
                   help="the least box weight a stage may learn, as a fraction of ||K||^2 (0.07; from 0.001 to 1): "
                        "below it one held-out myope's photograph lost all of fast's JOD gain at a near-equal "
                        "objective (docs/learned.md)")
    p.add_argument("--cap-share", type=float, default=0.0, metavar="S",
                   help="the share of training crops whose box is a robust design's light cap (each primary at most "
                        "twice the target's light plus 0.02), not [0, 1] (0; from 0 to 1)")
    p.add_argument("--ray", metavar="ADDRESS",
                   help="build the eyes' kernels as Ray tasks on the cluster at ADDRESS (auto, HOST:PORT, "
                        "ray://HOST:10001, or local: a one-node Ray on this machine's CPUs); default: local "
                        "processes; the extra 'ray'")
    p.add_argument("--resume", action="store_true",
                   help="continue RUN's training from its checkpoint (written every minute; its kernels too)")
    p.add_argument("--force", action="store_true", help="overwrite RUN's earlier files (a checkpoint: start over)")
    p.set_defaults(func=cmd_train_unrolled)
