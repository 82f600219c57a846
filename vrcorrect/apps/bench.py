"""``vrcorrect bench WHAT``: run one benchmark of :mod:`vrcorrect.studies.bench`, print its table and
write it into its own section of the benchmarks file (``--out``; by default the checkout's
``docs/benchmarks.md``, and only inside the checkout: :func:`~vrcorrect.studies.bench.default_out`).

Each bench is imported only when it runs: it brings its own stack (GL, onnxruntime, torch, the
metrics)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import check_readable, check_writable
from ..runtime.model_path import DEFAULT_MODEL
from ..specs.vocabulary import Eye, Periphery, names
from ..studies.bench import BENCHMARKS_FILE, default_out
from .common import GAZE_HELP, PERIPHERY_HELP, load_eye_and_age, parse_fovea, parse_gaze, rx_path


def _json_out(args: argparse.Namespace) -> Path | None:
    """``--json``'s path, checked before minutes of work: a ``.json`` name, not overwriting a file
    without ``--force``."""
    if not args.json:
        return None
    if Path(args.json).suffix.lower() != ".json":
        raise ValidationError("--json", args.json, "a path ending in .json")
    check_writable(Path(args.json), force=args.force)
    return Path(args.json)


def _robust_eye(args) -> dict:
    """``bench robust --rx``: the ``--eye`` of that prescription (default right) and its age, checked
    before minutes of work, with every refusal of ``--rx``/``--eye`` here; without ``--rx`` the bench's
    own eye.  The video parts keep the bench's eye, so not with --video; the repository's benchmarks
    keep the bench eye's figures, so only with --no-write or --out."""
    if args.eye is not None and not (args.what == "robust" and args.rx):
        raise ValidationError("--eye", args.eye, "only with bench robust --rx (which eye of the prescription to sweep)")
    if args.what != "robust" or not args.rx:
        return {}
    if args.video:
        raise ValidationError("--rx", args.rx, "bench robust --rx sweeps the still cases only; run --video without --rx")
    if not args.no_write and args.out is None:
        raise ValidationError("--rx", args.rx, "with --no-write or --out FILE.md: the repository's benchmarks "
                              "keep the bench's own eye's figures")
    args.eye = args.eye or "right"
    _, eye, age = load_eye_and_age(args)
    return {"eye": eye, "age_years": age}


def _robust_image(path: str) -> str:
    """An ``--image`` of ``bench robust``, checked before minutes of work: a readable picture file."""
    from ..studies.bench.robust import (
        IMAGE_SUFFIXES,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    if Path(path).suffix.lower() not in IMAGE_SUFFIXES:
        raise ValidationError("--image", path, "a picture file ending in " + ", ".join(IMAGE_SUFFIXES))
    check_readable(path)
    return path


def cmd_bench(args: argparse.Namespace) -> int:
    if args.image and args.what != "robust":
        raise ValidationError("--image", args.image[0], f"only with bench robust (not bench {args.what})")
    if args.image and not args.no_write and args.out is None:
        raise ValidationError("--image", args.image[0], "with --no-write or --out FILE.md: the repository's "
                              "benchmarks keep the held-out images' figures")
    robust_eye = _robust_eye(args)
    # --out before any work: the repository's file only inside the repository, else named by the user
    if args.out is None:
        args.out = str(BENCHMARKS_FILE if args.no_write else default_out())    # --no-write: names only
    if not args.no_write:
        check_writable(Path(args.out), force=True)                             # the section is replaced
    if args.what == "kernel":
        from ..studies.bench.kernel import (
            run_kernel_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        print(run_kernel_bench(repeats=args.repeats, out=Path(args.out), write=not args.no_write))
    elif args.what == "solvers":
        from ..studies.bench.solvers import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
            RESOLUTIONS,
            run_solver_bench,
        )

        res = args.resolutions or list(RESOLUTIONS)
        for r in res:
            if r not in RESOLUTIONS:
                raise ValidationError("--resolutions", r, "some of " + ", ".join(RESOLUTIONS))
        print(run_solver_bench(out=Path(args.out), plot=Path(args.out).with_name("solver_tradeoff.png"),
                               resolutions=res, repeats=args.repeats, write=not args.no_write))
    elif args.what == "render":
        from ..studies.bench.render import (
            run_render_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        print(run_render_bench(repeats=args.repeats, out=Path(args.out), write=not args.no_write))
    elif args.what == "xr":
        from ..studies.bench.xr import (
            run_xr_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        print(run_xr_bench(repeats=args.repeats, out=Path(args.out), write=not args.no_write))
    elif args.what == "cost":
        from ..studies.bench.cost import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
            METHODS,
            parse_size,
            run_cost_bench,
        )
        from ..studies.bench.peer import (  # on use: start-up time (apps/__init__: the parser loads no layer below)
            NO_DEVICE,
            PEERS,
        )

        size = parse_size(args.size)
        fovea = [] if args.fovea is None else [r for r in (parse_fovea(v) for v in args.fovea.split(",")) if r is not None]
        if args.peer is not None and args.peer not in PEERS:
            raise ValidationError("--peer", args.peer, "one of " + ", ".join(PEERS))
        report = run_cost_bench(size, args.display, str(rx_path(args)), out=Path(args.out), write=not args.no_write,
                                json_out=_json_out(args), dry_run=args.dry_run,
                                force=args.force, frames=1 if args.frames is None else args.frames,
                                methods=METHODS[:1] if args.default_only else METHODS, peer=args.peer,
                                fovea=fovea, gaze_deg=parse_gaze(args.gaze), periphery=args.periphery)
        print(report["markdown"])
        if report.get("peer", {}).get("status") == NO_DEVICE:
            print(NO_DEVICE)
    elif args.what == "workgroups":
        from ..studies.bench.cost import (
            parse_size,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )
        from ..studies.bench.workgroups import (
            run_workgroup_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        size = parse_size(args.size)
        report = run_workgroup_bench(size, args.display, str(rx_path(args)), frames=20 if args.frames is None else args.frames,
                                     out=Path(args.out), write=not args.no_write, json_out=_json_out(args),
                                     force=args.force)
        print(report["markdown"])
    elif args.what == "halfres":
        from ..studies.bench.halfres import (
            run_halfres_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        report = run_halfres_bench(video=args.video, out=Path(args.out), write=not args.no_write,
                                   json_out=_json_out(args), force=args.force)
        print(report["markdown"])
    elif args.what == "robust":
        from ..studies.bench.robust import (
            run_robust_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        images = {"images": [_robust_image(path) for path in args.image]} if args.image else {}
        report = run_robust_bench(out=Path(args.out), write=not args.no_write,
                                  plot=Path(args.out).with_name("robust_sweep.png"), json_out=_json_out(args),
                                  force=args.force, video=args.video, **images, **robust_eye)
        print(report["markdown"])
    elif args.what == "fovea":
        from ..studies.bench.fovea import (
            run_fovea_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        quick = {"images": ("rocket",), "iterations": (2,), "radii": (15.0,), "view": 640,
                 "video_clips": ("text",), "video_frames": 10} if args.quick else {}
        report = run_fovea_bench(out=Path(args.out), write=not args.no_write,
                                 plot=Path(args.out).with_name("fovea_tradeoff.png"), json_out=_json_out(args),
                                 force=args.force, video=args.video, **quick)
        print(report["markdown"])
    elif args.what == "layer":
        from ..studies.bench.layer import (
            run_layer_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        print(run_layer_bench(repeats=args.repeats, out=Path(args.out), write=not args.no_write))
    elif args.what == "realtime":
        from ..studies.bench.realtime import (
            run_realtime_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        print(run_realtime_bench(out=Path(args.out), write=not args.no_write, quick=args.quick))
    elif args.what in ("learned", "unrolled"):
        from ..runtime.unrolled import (
            is_unrolled_model,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        path = Path(args.model) if args.model else DEFAULT_MODEL
        if not path.is_file():
            raise InputError(f"{path}: no such model; pass --model PATH (an unrolled model: vrcorrect unroll -o RUN "
                             "writes RUN/unrolled.onnx)")
        if is_unrolled_model(path):                       # today's format or an older one it runs
            from ..studies.bench.unrolled import (
                run_unrolled_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
            )

            args.eyes = 2 if args.eyes is None else args.eyes
            if args.eyes < 1:
                raise ValidationError("--eyes", args.eyes, "at least 1")
            print(run_unrolled_bench(path, out=Path(args.out), eyes=args.eyes, write=not args.no_write,
                                     card=Path(args.card) if args.card else None)["markdown"])
            return 0
        if args.what == "unrolled":
            raise InputError(f"{path}: not an unrolled model (vrcorrect unroll -o RUN writes RUN/unrolled.onnx)")
        from ..studies.bench.learned import (
            run_learned_bench,  # on use: start-up time (apps/__init__: the parser loads no layer below)
        )

        args.eyes = 6 if args.eyes is None else args.eyes
        if args.eyes < 1:
            raise ValidationError("--eyes", args.eyes, "at least 1")
        print(run_learned_bench(path, out=Path(args.out), card=Path(args.card) if args.card else None,
                                eyes=args.eyes, repeats=max(args.repeats, 3), write=not args.no_write,
                                plot=Path(args.out).with_name("learned_heldout.png"),
                                tradeoff=Path(args.out).with_name("learned_tradeoff.png"))["markdown"])
    else:
        raise ValidationError("bench", args.what, "kernel, solvers, render, realtime, cost, workgroups, halfres, "
                              "robust, fovea, xr, layer, learned or unrolled")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmarks: print a table and write docs/benchmarks.md",
                       description="Measure one thing (kernel builds, solvers, render, realtime, cost, the work-group "
                                   "shapes of its passes, a half-resolution solve by eye (halfres), a correction "
                                   "against the eye as it is (robust), a correction where the eye looks (fovea), xr, "
                                   "layer, learned or unrolled), print its "
                                   "table, and write "
                                   "it into its own section of the benchmarks file (--out), naming the machine it ran "
                                   "on.")
    p.add_argument("what", choices=("kernel", "solvers", "render", "realtime", "cost", "workgroups", "halfres",
                                    "robust", "fovea", "xr", "layer", "learned", "unrolled"),
                   help="what to measure")
    p.add_argument("--repeats", type=int, default=3, help="timed runs per case (median reported)")
    p.add_argument("--resolutions", nargs="+", metavar="R",
                   help="solvers: image sizes to sweep (256 512 1024 1832x1920; default all)")
    p.add_argument("--out", metavar="FILE.md",
                   help="benchmarks file to update (default: the repository's docs/benchmarks.md, when run inside "
                        "the vrcorrect checkout; required anywhere else unless --no-write)")
    p.add_argument("--no-write", action="store_true", help="print only")
    p.add_argument("--model", metavar="MODEL.onnx", help="learned, unrolled: the model (default "
                   "models/default.onnx); an unrolled model is measured as `unrolled` under either name, an older "
                   "U-Net model by the older learned bench")
    p.add_argument("--card", metavar="CARD.md", help="learned, unrolled: also write the model card there")
    p.add_argument("--eyes", type=int, help="learned, unrolled: held-out eyes (the U-Net bench: default 6; an "
                   "unrolled model: on each display, default 2)")
    p.add_argument("--quick", action="store_true", help="realtime: fewer frames and sizes (a smoke run); fovea: the "
                   "rocket only, at 15 degrees and 2 iterations, on a 640 px view (with --video, the text clip, 10 "
                   "frames)")
    p.add_argument("--video", action="store_true",
                   help="halfres: also play the held-out clips through a half-resolution real-time twin for one "
                        "strong eye, judged as video (some 15 minutes more on 2 cores); robust: also the motion suite's "
                        "video shares with the robust design and a dark clip cut to a bright one with the pupil "
                        "following the light; fovea: also two held-out clips (text, cut: pictures and words the project "
                        "never tuned on) at a 15 degree window, judged as video (FovVideoVDP) and by FLIP")
    p.add_argument("--size", default="1832x1920", metavar="WxH",
                   help="cost, workgroups: each eye's image size (default 1832x1920, a Quest 2 eye)")
    p.add_argument("--json", metavar="OUT.json", help="cost, workgroups, halfres, robust: also write the figures as JSON "
                   "there")
    p.add_argument("--display", default="quest2",
                   help="cost, workgroups: display preset or profile (default quest2)")
    p.add_argument("--rx", metavar="RX.json", help="cost, workgroups: prescription (default: the bundled sample); "
                   "robust: sweep an eye of this prescription (--eye, default right), at its age, instead of the "
                   "bench's -2.00/-1.00 x 120 (not with --video)")
    p.add_argument("--eye", choices=names(Eye), default=None,
                   help="robust --rx: which eye of the prescription to sweep (default right)")
    p.add_argument("--dry-run", action="store_true",
                   help="cost: count the passes without running them (seconds instead of minutes on a software "
                        "renderer; no times)")
    p.add_argument("--frames", type=int, metavar="N",
                   help="cost: time N changing and N cold frames per eye and method, and report the median "
                        "(default 1; a GPU measurement wants more, e.g. 50); workgroups: N of each per setting, "
                        "interleaved (default 20)")
    p.add_argument("--peer", metavar="NAME",
                   help="cost: also time the default frame written plainly in NAME (torch: torch on cuFFT) in the "
                        "same run on the same GPU, with its ratio to the GLSL frame; where torch sees no CUDA device "
                        "it prints 'no CUDA device: peer not run'")
    p.add_argument("--fovea", metavar="DEG[,DEG...]",
                   help="cost: also count the default frame foveated at each radius (degrees of visual angle: "
                        "the correction solved on a window around the gaze, the rest of the view shown as it is)")
    p.add_argument("--gaze", default="0,0", metavar="X,Y", help="cost: where the eye looks for --fovea, " + GAZE_HELP)
    p.add_argument("--periphery", choices=names(Periphery), default=None,
                   help="cost: with --fovea, " + PERIPHERY_HELP)
    p.add_argument("--default-only", action="store_true",
                   help="cost: count and time the default method only (not single precision, FISTA and the "
                        "one-pass inverse beside it)")
    p.add_argument("--image", action="append", default=[], metavar="PATH",
                   help="robust: judge on this picture instead of the held-out images (repeatable; PNG, JPEG, TIFF or "
                        "BMP, centre-cropped and scaled to 256 px), e.g. pages of your own; with --no-write or "
                        "--out elsewhere, so that the repository's figures stay the held-out images'")
    p.add_argument("--force", action="store_true", help="cost, workgroups, halfres, robust: overwrite --json's file")
    p.set_defaults(func=cmd_bench)
