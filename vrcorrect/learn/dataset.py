"""The learned model's data set: image crops, sampled eyes, and ``fast``'s corrections of them.

Sample ``i`` of a data set is a pure function of ``(config, images, i)``: a generator seeded
with ``(seed, i)`` picks the image, the crop's corner and the eye (uniform over
:class:`~vrcorrect.learn.conditioning.SamplingRanges`), so the same seed gives the same
data set whatever the number of workers or the order the shards finish in.  For each
sample the builder computes, on the crop (linear display RGB, the panel black around it):

* the eye's kernel and its glasses-on reference kernel (:func:`vrcorrect.physics.kernel.build_kernel`,
  :func:`vrcorrect.physics.kernel.build_reference_kernel`);
* ``target_lms``, the retinal cone image with glasses (the objective's target);
* ``precorrected``, the model's extra input (:func:`~vrcorrect.learn.conditioning.precorrect`);
* ``fast``, the ``fast`` method's correction (``solve(problem, "fast")``), and the objective
  of the uncorrected crop and of ``fast``.

On disk (``OUT/``): ``shard_00000.npz`` ... each holding ``samples_per_shard`` samples, and
``manifest.json`` (settings, display, image names and hashes, and per sample its image,
crop, prescription, power vector and objectives).  A shard is written atomically and then
recorded in the manifest, so an interrupted build resumes by computing only the shards the
manifest does not list.  Shards are built on local processes
(:class:`concurrent.futures.ProcessPoolExecutor`) or, with ``ray_address``, as one Ray task per
missing shard (Ray is the optional extra ``ray``; imported only then).  A Ray task returns its
shard's arrays and manifest entry and the driver writes the file and records it, exactly as the
local path does: the cluster needs no shared filesystem, only the same vrcorrect installed on
every node, and a build started on Ray resumes locally and the other way round.

Shard arrays (``n`` samples, crop ``h x w``, ``S`` the largest kernel in the shard):
``index (n,)`` int64, ``target``/``precorrected``/``fast``/``target_lms`` ``(n, 3, h, w)``
float32, ``eye (n, 4)`` float32 raw ``(M_D, J0_D, J45_D, pupil_mm)``, ``features (n, 4)``
float32 (:func:`~vrcorrect.learn.conditioning.eye_features`), ``kernel (n, 3, 3, S, S)``
float32 (each centred, zero-padded to ``S``), ``kernel_px (n,)``, ``objective_uncorrected``,
``objective_fast (n,)`` float64.

Layer 4: images arrive as arrays (the command line loads bundled or folder images).
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import sys
import time
import uuid
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
from tqdm import tqdm

from .. import __version__
from ..physics.kernel import KernelOptions, build_kernel, build_reference_kernel
from ..plumbing.errors import InputError, ValidationError, VrcorrectError
from ..plumbing.fileio import write_text_atomic, write_with
from ..solvers import make_problem, objective, solve
from ..specs.display import decode, get_display
from ..specs.prescription import EyeRx
from .conditioning import PRECORRECTION_MU_REL, PRECORRECTION_STEPS, SamplingRanges, eye_features, precorrect

#: Images kept out of the default data set: ``vrcorrect bench learned`` scores models on them.
HELD_OUT_IMAGES = ("rocket", "retina")
FORMAT = "vrcorrect-dataset"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"


@dataclass(frozen=True)
class DatasetConfig:
    """How a data set is built (everything a sample depends on, besides the images).

    Attributes
    ----------
    samples
        Number of samples (>= 1).
    crop_px
        Side of the square crops, pixels (16 to 1024).
    seed
        Seed of every random choice.
    ranges
        Prescriptions sampled.
    display
        Display preset name or profile path the kernels are built for.
    samples_per_shard
        Samples per ``.npz`` file (the unit of work and of resumption).
    fast_tolerance
        ``fast``'s relative stopping tolerance.
    precorrection_mu_rel
        Regulariser of the ``precorrected`` channels (relative to ``||K||^2``) when
        ``precorrection_steps`` is 0.
    precorrection_steps
        Projected-gradient steps of the ``precorrected`` channels (0 to 100; 0: the clipped
        regularised inverse; a manifest without this field was built with 0).
    wavelength_step_nm
        Force the kernels' wavelength step (None: the kernel builder chooses; 40 or 80 is
        much quicker for tiny test sets).
    crops_per_eye
        Consecutive samples that share one sampled eye (each with its own image and crop):
        an eye's kernels cost seconds to build, a crop's ``fast`` solve a fraction of that,
        so a data set of many crops per eye is many times cheaper for the same sample count.
    """

    samples: int = 1000
    crop_px: int = 128
    seed: int = 0
    ranges: SamplingRanges = field(default_factory=SamplingRanges)
    display: str = "quest2"
    samples_per_shard: int = 32
    fast_tolerance: float = 1e-2
    precorrection_mu_rel: float = PRECORRECTION_MU_REL
    precorrection_steps: int = PRECORRECTION_STEPS
    wavelength_step_nm: int | None = None
    crops_per_eye: int = 1

    def __post_init__(self) -> None:
        for name, lo, hi in (("samples", 1, 10_000_000), ("crop_px", 16, 1024), ("samples_per_shard", 1, 100_000),
                             ("crops_per_eye", 1, 10_000), ("precorrection_steps", 0, 100)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise ValidationError(name, v, f"an integer from {lo} to {hi}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValidationError("seed", self.seed, "a non-negative integer")
        if not isinstance(self.ranges, SamplingRanges):
            raise ValidationError("ranges", self.ranges, "a SamplingRanges")
        if not (0.0 <= self.fast_tolerance < 1.0):
            raise ValidationError("fast_tolerance", self.fast_tolerance, "a number from 0 to 1")
        if not self.precorrection_mu_rel > 0:
            raise ValidationError("precorrection_mu_rel", self.precorrection_mu_rel, "a positive number")

    @property
    def shards(self) -> int:
        return -(-self.samples // self.samples_per_shard)

    def shard_indices(self, shard: int) -> range:
        return range(shard * self.samples_per_shard, min(self.samples, (shard + 1) * self.samples_per_shard))

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["ranges"] = self.ranges.as_dict()
        return d

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> "DatasetConfig":
        d = dict(doc)
        d["ranges"] = SamplingRanges.from_dict(d.get("ranges", {}))
        d.setdefault("precorrection_steps", 0)             # manifests from before the field: the inverse
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


@dataclass(frozen=True)
class SampleSpec:
    """Where sample ``index`` comes from (before any optics)."""

    index: int
    image: int
    y: int
    x: int
    sphere_D: float
    cylinder_D: float
    axis_deg: float
    pupil_diameter_mm: float


def sample_spec(config: DatasetConfig, image_shapes: Sequence[tuple[int, int]], index: int) -> SampleSpec:
    """The image, crop corner and eye of sample ``index`` (a pure function of its arguments; the
    eye is drawn per group of ``crops_per_eye`` consecutive samples)."""
    rng = np.random.default_rng([int(config.seed), int(index)])
    k = int(rng.integers(len(image_shapes)))
    h, w = image_shapes[k]
    y = int(rng.integers(h - config.crop_px + 1))
    x = int(rng.integers(w - config.crop_px + 1))
    if config.crops_per_eye > 1:
        rng = np.random.default_rng([int(config.seed), int(index) // config.crops_per_eye, 1])
    eye = config.ranges.sample(rng)
    return SampleSpec(index=int(index), image=k, y=y, x=x, sphere_D=eye.sphere_D, cylinder_D=eye.cylinder_D,
                      axis_deg=eye.axis_deg, pupil_diameter_mm=eye.pupil_diameter_mm)


def image_digest(image: np.ndarray) -> str:
    """A short content hash of an image (detects a changed image set on resume)."""
    a = np.ascontiguousarray(image, dtype=np.float32)
    return hashlib.sha1(a.tobytes() + str(a.shape).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------
# One shard (runs in a worker process, or in this one with workers=1)
# --------------------------------------------------------------------------

_WORKER: dict[str, Any] = {}


def _init_worker(images: Sequence[np.ndarray], display: Any, threads: int | None) -> None:
    """Set this process up to compute samples: ``display`` a preset name, profile path or
    :class:`~vrcorrect.specs.display.DisplayProfile`; ``images`` sRGB code values."""
    if threads is not None:
        os.environ["OMP_NUM_THREADS"] = str(threads)
        try:
            import torch  # optional: torch (the solve and learn extras)

            torch.set_num_threads(threads)
        except ImportError:  # pragma: no cover - torch is needed by fast anyway
            pass
    _WORKER["display"] = get_display(display) if isinstance(display, (str, os.PathLike)) else display
    _WORKER.pop("kernels", None)                 # built for another build's display
    # images are sRGB code values; the model works in linear light

    _WORKER["images"] = [decode(_WORKER["display"], im).astype(np.float32) for im in images]


def _compute_sample(config: DatasetConfig, spec: SampleSpec) -> dict[str, Any]:
    display = _WORKER["display"]
    image = _WORKER["images"][spec.image]
    c = config.crop_px
    crop = np.ascontiguousarray(image[spec.y:spec.y + c, spec.x:spec.x + c])
    eye = EyeRx(spec.sphere_D, spec.cylinder_D, spec.axis_deg, spec.pupil_diameter_mm)
    options = KernelOptions(wavelength_step_nm=config.wavelength_step_nm)
    t0 = time.perf_counter()
    cached = _WORKER.get("kernels")
    if cached is not None and cached[0] == (eye, options):           # the previous sample's eye
        kernel, reference = cached[1:]
    else:
        kernel = build_kernel(eye, display, options)
        reference = build_reference_kernel(eye, display, options)
        _WORKER["kernels"] = ((eye, options), kernel, reference)
    problem = make_problem(crop, kernel, reference)
    fast = solve(problem, "fast", tolerance=config.fast_tolerance)
    pv = eye.power_vector()
    return {
        "spec": spec, "target": crop, "target_lms": problem.target_lms,
        "precorrected": precorrect(crop, kernel, reference, config.precorrection_mu_rel, config.precorrection_steps),
        "fast": fast.image, "kernel": kernel.kernel.astype(np.float32),
        "eye": np.array([pv.M_D, pv.J0_D, pv.J45_D, eye.pupil_diameter_mm], np.float32),
        "features": eye_features(eye, config.ranges),
        "objective_uncorrected": objective(crop, problem), "objective_fast": fast.objective,
        "fast_iterations": fast.iterations, "seconds": time.perf_counter() - t0,
    }


def _pad_kernel(k: np.ndarray, size: int) -> np.ndarray:
    p = (size - k.shape[-1]) // 2
    return np.pad(k, ((0, 0), (0, 0), (p, p), (p, p)))


def _compute_shard(config: DatasetConfig, shard: int,
                   specs: list[SampleSpec]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One shard's arrays and its manifest entry (nothing written)."""
    rows = [_compute_sample(config, s) for s in specs]
    S = max(r["kernel"].shape[-1] for r in rows)
    chw = lambda key: np.stack([np.moveaxis(r[key], 2, 0) for r in rows]).astype(np.float32)  # noqa: E731
    arrays = {
        "index": np.array([r["spec"].index for r in rows], np.int64),
        "target": chw("target"), "precorrected": chw("precorrected"), "fast": chw("fast"),
        "target_lms": chw("target_lms"),
        "eye": np.stack([r["eye"] for r in rows]), "features": np.stack([r["features"] for r in rows]),
        "kernel": np.stack([_pad_kernel(r["kernel"], S) for r in rows]),
        "kernel_px": np.array([r["kernel"].shape[-1] for r in rows], np.int64),
        "objective_uncorrected": np.array([r["objective_uncorrected"] for r in rows], np.float64),
        "objective_fast": np.array([r["objective_fast"] for r in rows], np.float64),
    }
    samples = []
    for r in rows:
        s = r["spec"]
        M, J0, J45, _ = (float(v) for v in r["eye"])
        samples.append({**asdict(s), "M_D": M, "J0_D": J0, "J45_D": J45, "kernel_px": int(r["kernel"].shape[-1]),
                        "objective_uncorrected": float(r["objective_uncorrected"]),
                        "objective_fast": float(r["objective_fast"]), "fast_iterations": int(r["fast_iterations"]),
                        "seconds": round(float(r["seconds"]), 3)})
    return arrays, {"shard": shard, "file": f"shard_{shard:05d}.npz", "samples": samples}


def _write_shard(out_dir: str | Path, name: str, arrays: dict[str, np.ndarray]) -> None:
    """Write one shard's arrays atomically (``OUT/name``)."""
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)

    write_with(Path(out_dir) / name, write, force=True)


def _build_shard(config: DatasetConfig, out_dir: str, shard: int, specs: list[SampleSpec]) -> dict[str, Any]:
    """Compute and write one shard; returns its manifest entry."""
    arrays, entry = _compute_shard(config, shard, specs)
    _write_shard(out_dir, entry["file"], arrays)
    return entry


def _ray_shard(source: str, data: tuple[list[np.ndarray], Any], config: DatasetConfig, shard: int,
               specs: list[SampleSpec]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A Ray task: one shard's arrays and manifest entry (the driver writes them).

    ``data`` is ``(images, display)`` from the object store; a Ray worker process runs many
    tasks, so it decodes the images once per build (``source`` names the build)."""
    if _WORKER.get("source") != source:
        images, display = data
        _init_worker(images, display, None)          # Ray sets the task's threads (OMP_NUM_THREADS)
        _WORKER["source"] = source
    return _compute_shard(config, shard, specs)


# --------------------------------------------------------------------------
# The builder
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class BuildReport:
    """What :func:`build_dataset` did."""

    out_dir: Path
    computed_shards: int
    skipped_shards: int
    samples: int
    seconds: float


def read_manifest(out_dir: str | Path) -> dict[str, Any]:
    """The data set's manifest (``InputError`` if missing or unreadable)."""
    path = Path(out_dir) / MANIFEST
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no data set manifest here (build one with: vrcorrect dataset OUT)") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: unreadable manifest ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"{path}: not a vrcorrect data set manifest")
    return doc


def _new_manifest(config: DatasetConfig, display, names: Sequence[str], images: Sequence[np.ndarray]) -> dict:
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "vrcorrect_version": __version__,
            "config": config.as_dict(),
            "display": {"name": display.name, "title": display.title,
                        "pixels_per_degree": display.pixels_per_degree, "distance_m": display.distance_m},
            "images": [{"name": n, "shape": list(im.shape), "sha1": image_digest(im)} for n, im in zip(names, images)],
            "reference": "glasses", "solver": "fast", "shards": []}


def _same_settings(old: dict, new: dict) -> str | None:
    for key in ("config", "images", "display"):
        if old.get(key) != new.get(key):
            return key
    return None


RAY_INSTALL = "pip install -e '.[ray]'"
RAY_ADDRESSES = "local (a one-node Ray started here), auto, HOST:PORT or ray://HOST:10001"


def _import_ray(ray_address: str) -> Any:
    try:
        import ray  # optional: ray (vrcorrect dataset --ray only)
    except ImportError:
        raise InputError(f"--ray {ray_address}: Ray is not installed; install vrcorrect's optional extra "
                         f"'ray' (in the vrcorrect folder): {RAY_INSTALL}") from None
    return ray


def check_ray(ray_address: str | None) -> None:
    """Check that building on Ray at ``ray_address`` can be tried (None: local processes, nothing
    to check): the address is a non-empty string and Ray is installed (:class:`InputError` naming
    the extra to install).  Connecting happens in :func:`build_dataset`."""
    if ray_address is None:
        return
    if not isinstance(ray_address, str) or not ray_address.strip():
        raise ValidationError("ray_address", ray_address, RAY_ADDRESSES)
    _import_ray(ray_address)


@contextmanager
def _ray_session(ray_address: str, num_cpus: int) -> Iterator[Any]:
    """Ray connected to ``ray_address`` (``local``: start a one-node Ray with ``num_cpus`` CPUs);
    disconnected again afterwards.  A process already connected to Ray (``ray.init`` called by
    the caller) keeps its connection, whatever the address."""
    ray = _import_ray(ray_address)
    if ray.is_initialized():
        yield ray
        return
    try:
        if ray_address.strip().lower() == "local":
            ray.init(address="local", num_cpus=num_cpus, include_dashboard=False)   # not RAY_ADDRESS's
        else:
            ray.init(address=ray_address.strip())
    except Exception as exc:  # ConnectionError, ValueError, RuntimeError, TimeoutError: all "cannot connect"
        ray.shutdown()
        what = "cannot start a local Ray" if ray_address.strip().lower() == "local" else "cannot connect to Ray"
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"--ray {ray_address}: {what} ({detail}); expected {RAY_ADDRESSES}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _build_on_ray(ray: Any, images: list[np.ndarray], display: Any, config: DatasetConfig, out: Path,
                  todo: list[int], jobs: dict[int, list[SampleSpec]], record: Callable[[dict], None]) -> None:
    """One Ray task per shard in ``todo``; the driver writes each shard as it arrives and records it.

    The images and the display profile go into the object store once; at most two tasks per
    cluster CPU are in flight, so finished shards do not pile up in the object store."""
    task = ray.remote(_ray_shard)                      # one CPU per task (Ray's default)
    data = ray.put((images, display))
    source = uuid.uuid4().hex
    window = max(2, 2 * int(ray.cluster_resources().get("CPU", 1)))
    queue = iter(todo)
    pending: dict[Any, int] = {}

    def submit() -> None:
        k = next(queue, None)
        if k is not None:
            pending[task.remote(source, data, config, k, jobs[k])] = k

    try:
        for _ in range(window):
            submit()
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            del pending[ref]
            try:
                arrays, entry = ray.get(ref)
            except ray.exceptions.RayTaskError as exc:
                if isinstance(exc.cause, VrcorrectError):  # a user error inside the task: its own message
                    raise exc.cause from None
                raise
            submit()
            _write_shard(out, entry["file"], arrays)
            record(entry)
    finally:
        for ref in pending:                            # interrupted or failed: stop the rest
            try:
                ray.cancel(ref)
            except Exception:  # pragma: no cover - best effort
                pass


def build_dataset(out_dir: str | Path, images: Sequence[tuple[str, np.ndarray]], config: DatasetConfig,
                  workers: int = 1, force: bool = False, ray_address: str | None = None,
                  progress: bool = True, on_shard: Callable[[int], None] | None = None) -> BuildReport:
    """Build (or resume) a data set in ``out_dir``.

    Parameters
    ----------
    out_dir
        Folder for the shards and ``manifest.json`` (created if missing).
    images
        ``(name, image)`` pairs; images ``(H, W, 3)`` sRGB code values in [0, 1], each at least
        ``crop_px`` on both sides.
    config
        Build settings.
    workers
        Local processes (1: this process, no pool); with ``ray_address="local"`` the CPUs of the
        one-node Ray started here; ignored on a Ray cluster.
    force
        Start again when ``out_dir`` holds a data set built with other settings (its shards
        are overwritten); without it such a folder is refused.
    ray_address
        None: local processes.  Otherwise one Ray task per missing shard on the Ray at this
        address: ``"local"`` starts a one-node Ray here, ``"auto"``, ``"HOST:PORT"`` or
        ``"ray://HOST:10001"`` connect to a cluster whose nodes have this vrcorrect installed
        (no shared filesystem needed: the shards come back to this process, which writes them).
        If this process is already connected to Ray, that connection is used.  Needs the extra
        ``ray`` (:class:`InputError` naming it otherwise, or naming the address if Ray cannot
        be reached there).  The result equals a local build's.
    progress
        Show a tqdm bar (samples) on stderr.
    on_shard
        Called with each shard's number after it is written (tests use it).

    Returns
    -------
    BuildReport
    """
    check_ray(ray_address)
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 256:
        raise ValidationError("workers", workers, "an integer from 1 to 256")
    if not images:
        raise ValidationError("images", "none", "at least one image")
    names = [n for n, _ in images]
    arrays = [np.ascontiguousarray(im, dtype=np.float32) for _, im in images]
    for n, im in zip(names, arrays):
        if im.ndim != 3 or im.shape[2] != 3 or min(im.shape[:2]) < config.crop_px:
            raise ValidationError(f"images[{n}]", f"shape {im.shape}",
                                  f"(H, W, 3) with H and W at least the crop size {config.crop_px}")
    display = get_display(config.display)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: is not a folder")
    manifest = _new_manifest(config, display, names, arrays)
    if (out / MANIFEST).exists():
        old = read_manifest(out)
        differs = _same_settings(old, manifest)
        if differs is None:
            manifest = old
        elif not force:
            raise InputError(f"{out}: holds a data set built with other settings ({differs} differ); "
                             "use another folder, or --force to rebuild it here")
    done = {e["shard"] for e in manifest["shards"] if (out / e["file"]).is_file()}
    manifest["shards"] = [e for e in manifest["shards"] if e["shard"] in done]
    todo = [k for k in range(config.shards) if k not in done]
    shapes = [im.shape[:2] for im in arrays]
    jobs = {k: [sample_spec(config, shapes, i) for i in config.shard_indices(k)] for k in todo}


    with ExitStack() as stack:
        # connect first: an unreachable cluster leaves no new folder behind
        ray = stack.enter_context(_ray_session(ray_address, workers)) if ray_address is not None and todo else None
        out.mkdir(parents=True, exist_ok=True)
        n_done = sum(len(config.shard_indices(k)) for k in done)
        bar = stack.enter_context(tqdm(total=config.samples, initial=n_done, desc="dataset", unit="sample",
                                       disable=None if progress else True, file=sys.stderr))
        t0 = time.perf_counter()

        def record(entry: dict) -> None:
            manifest["shards"] = sorted(manifest["shards"] + [entry], key=lambda e: e["shard"])
            write_text_atomic(out / MANIFEST, json.dumps(manifest, indent=1) + "\n", force=True)
            bar.update(len(entry["samples"]))
            if on_shard is not None:
                on_shard(entry["shard"])

        if not (out / MANIFEST).exists() or manifest["shards"] == []:
            write_text_atomic(out / MANIFEST, json.dumps(manifest, indent=1) + "\n", force=True)
        if ray is not None:
            _build_on_ray(ray, arrays, display, config, out, todo, jobs, record)
        elif workers == 1 or len(todo) <= 1:
            _init_worker(arrays, config.display, None)
            for k in todo:
                record(_build_shard(config, str(out), k, jobs[k]))
        else:
            threads = max(1, (os.cpu_count() or 1) // workers)
            # spawn, not fork: a forked child of a process whose torch/OpenMP threads have run can hang
            with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=_init_worker, initargs=(arrays, config.display, threads)) as pool:
                futures = [pool.submit(_build_shard, config, str(out), k, jobs[k]) for k in todo]
                for fut in as_completed(futures):
                    record(fut.result())
    return BuildReport(out_dir=out, computed_shards=len(todo), skipped_shards=len(done),
                       samples=config.samples, seconds=time.perf_counter() - t0)


def load_shard(out_dir: str | Path, entry: dict[str, Any]) -> dict[str, np.ndarray]:
    """All arrays of one shard (``entry`` from the manifest's ``shards``)."""
    path = Path(out_dir) / entry["file"]
    try:
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: unreadable shard ({exc})") from None
