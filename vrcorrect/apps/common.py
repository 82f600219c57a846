"""What the command modules share: the eye, display and kernel options every modelling command
takes, the kernel build with its progress bar, the input's notes, and the memory check.

The physics is imported inside the functions that use it: every ``vrcorrect`` run builds the whole
argument parser (imports every command module), and ``vrcorrect --help`` or a mistyped path should
not wait seconds for scipy, colour-science and the kernels.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np
from tqdm import tqdm

from ..plumbing.errors import ValidationError
from ..specs.prescription import bundled_sample_path, load_prescription
from ..specs.vocabulary import Eye, names

if TYPE_CHECKING:
    from ..physics.kernel import EyeKernel, KernelOptions
    from ..specs.display import DisplayProfile
    from ..specs.prescription import EyeRx


def kernel_progress(desc: str) -> Callable[[int, int], None]:
    """A tqdm progress callback for kernel builds (silent when stderr is not a terminal)."""
    bar = tqdm(desc=desc, unit="PSF", disable=None, leave=False, file=sys.stderr)

    def update(done: int, total: int) -> None:
        bar.update(1)

    update.close = bar.close  # type: ignore[attr-defined]
    return update


def rx_path(args: argparse.Namespace, say: bool = True) -> Path:
    """The prescription a command models: ``--rx``, else the bundled sample, which it says on one line
    (standard output; ``say=False``: the command says it itself with :func:`say_sample_rx` once its
    other arguments passed): a user who forgot ``--rx`` is not corrected for someone else's eyes
    silently."""
    if getattr(args, "rx", None):
        return Path(args.rx)
    if say:
        say_sample_rx(args)
    return bundled_sample_path()


def say_sample_rx(args: argparse.Namespace) -> None:
    """The line saying the bundled sample prescription is modelled (nothing when ``--rx`` was given)."""
    if getattr(args, "rx", None):
        return
    from ..specs.vocabulary import Eye  # on use: start-up time (apps/__init__: the parser loads no layer below)

    path = bundled_sample_path()
    try:
        rx = load_prescription(path)
        eyes = "; ".join(f"{side} {_eye_text(rx.eye(side))}" for side in Eye)     # the prescription's order
    except Exception:  # noqa: BLE001  (the line is a courtesy: the command reads the file itself)
        eyes = "the bundled example"
    # on standard output, with what the command reports: an error stays the one line on standard error
    print(f"vrcorrect: using the sample prescription {path} ({eyes}); pass --rx YOUR_RX.json for yours "
          "(vrcorrect rx new writes a template)", flush=True)


def check_not_input(args: argparse.Namespace) -> None:
    """``-o`` must not be the input (a file, or a clip's folder): a command never writes over its own
    input, ``--force`` or not."""
    source, out = Path(args.input), Path(args.output)
    same = source.resolve() == out.resolve()
    if not same and source.exists() and out.exists():
        try:
            same = source.samefile(out)
        except OSError:
            same = False
    if same:
        raise ValidationError("--output", str(out), f"another path than the input {source}: vrcorrect never writes "
                              "over its input, not even with --force")


def small_image_note(width: int, height: int, kernel_px: int, what: str) -> str | None:
    """A note when the image is smaller than the eye's blur kernel (``kernel_px`` wide): what the result
    means then."""
    if width >= kernel_px and height >= kernel_px:
        return None
    return (f"the image ({width}x{height} px) is smaller than this eye's blur on this display (a {kernel_px}x"
            f"{kernel_px} px kernel): the eye sees it spread into the black around it, and {what} works only inside "
            "the image, so it can recover little; the result says little about a picture of ordinary size")


def _eye_text(e: EyeRx) -> str:
    return f"{e.sphere_D:+.2f}/{e.cylinder_D:+.2f}x{e.axis_deg:g}"


def load_eye(args: argparse.Namespace) -> tuple[Path, EyeRx]:
    path, eye, _ = load_eye_and_age(args)
    return path, eye


def load_eye_and_age(args: argparse.Namespace) -> tuple[Path, "EyeRx", float | None]:
    """The ``--rx`` file's ``--eye`` and the prescription's ``age_years`` (None where it gives none); a
    note on standard error when that eye's accommodation comes from the age."""
    path = rx_path(args)
    rx = load_prescription(path)
    eye = rx.eye(args.eye)
    if args.eye in rx.accommodation_from_age:
        print_notes([f"the {args.eye} eye states no accommodation_D: {eye.accommodation_D:.2f} D, the amplitude "
                     f"expected at age {rx.age_years:g} (Hofstetter's mean, 18.5 - 0.3 x age); state accommodation_D "
                     f"to set it (0 for an eye that cannot focus)"])
    return path, eye, rx.age_years


def kernel_options(args: argparse.Namespace) -> KernelOptions:
    from ..physics.kernel import KernelOptions  # noqa: F811  (the run-time class; the one above is for hints)
    from ..physics.options import (
        OpticsOptions,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    distance = None
    if getattr(args, "distance_m", None) is not None:
        distance = math.inf if args.distance_m in ("inf", "infinity") else _positive_float("--distance-m", args.distance_m)
    optics = OpticsOptions(chromatic_aberration=not args.no_lca, viewing_distance_m=distance,
                           reference_wavelength_nm=args.reference_wavelength_nm)
    return KernelOptions(energy_fraction=args.energy_fraction, wavelength_tolerance=args.wavelength_tolerance,
                         wavelength_step_nm=args.wavelength_step_nm, optics=optics)


def _positive_float(field: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValidationError(field, text, "a number of metres or 'inf'") from None
    return value


def build_eye_kernel(args: argparse.Namespace, eye: EyeRx, display: DisplayProfile) -> EyeKernel:
    from ..physics.kernel import build_kernel  # on use: start-up time (apps/__init__)

    bar = kernel_progress("building eye kernel")
    try:
        return build_kernel(eye, display, kernel_options(args), progress=bar)
    finally:
        bar.close()


def kernel_decisions(kernel: EyeKernel) -> list[str]:
    """The decisions that shaped ``kernel``, in words (``--explain``, the reports' ``kernel_decisions``,
    ``psf``'s sidecar)."""
    from ..physics.kernel_report import explain  # on use: start-up time (apps/__init__)

    return explain(kernel.report)


def add_model_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rx", metavar="RX.json", help="prescription file (default: the bundled sample)")
    p.add_argument("--eye", choices=names(Eye), default=Eye.RIGHT.value, help="which eye (default right)")
    p.add_argument("--display", default="quest2", metavar="PRESET",
                   help="display preset or profile .json (default quest2; list: vrcorrect displays)")
    g = p.add_argument_group("model")
    g.add_argument("--no-lca", action="store_true", help="leave out the eye's longitudinal chromatic aberration")
    g.add_argument("--distance-m", metavar="M",
                   help="viewing distance in metres, or 'inf' for the paper's setting (default: the display's)")
    g.add_argument("--reference-wavelength-nm", type=float, default=555.0,
                   help="wavelength at which the prescription holds (default 555)")
    g.add_argument("--energy-fraction", type=float, default=0.995,
                   help="fraction of PSF energy the kernel keeps (default 0.995)")
    g.add_argument("--wavelength-tolerance", type=float, default=1 / 255,
                   help="accepted error of the wavelength step against 1 nm (default 1/255)")
    g.add_argument("--wavelength-step-nm", type=int, choices=(80, 40, 20, 10, 5, 1),
                   help="force a wavelength step instead of choosing one")


PUPIL_HELP = ("the viewing pupil: auto (default: from the display's light, Watson & Yellott's formula on the "
              "image's mean luminance, the display's peak luminance and field of view, and the prescription's "
              "age_years), rx (the prescription's pupil_diameter_mm), or a diameter in mm from 2 to 7.5")
ROBUST_HELP = ("on (default): design the correction for the eyes the estimate leaves open (sphere -0.25 to +0.25 D "
               "at a pupil 7 %% below the estimate, where an error costs least) and add to each pixel at most twice "
               "its own light plus 2 %% of white (the light cap: no halo lifts a dark ground), so that it stays "
               "better than none when the eye is not exactly as modelled; off: for the one eye (pupil and sphere "
               "as given), in the box [0, 1]")
BAND_HELP = ("with --robust on, the band of eyes the correction is designed over: auto (default): by the picture, a "
             "page of dark text or lines on white paper gets the page band (the sphere hedged towards the sharper eye "
             "only, a pupil 4 %% above the estimate, no light cap: it keeps more of a page's sharpness), anything else "
             "the default band; default: the default band for every picture")
REALTIME_BAND_HELP = ("; in real time the GPU looks at the picture every few frames and the correction switches band as "
                      "it switches pupils (with --pupil auto and --filter admm over the whole view; otherwise the "
                      "default band)")


def parse_pupil(text: Any, field: str = "--pupil") -> str | float:
    """``--pupil``: ``"auto"``, ``"rx"`` or a diameter in :data:`~vrcorrect.physics.pupil.PUPIL_RANGE_MM`."""
    if isinstance(text, str) and text.strip().lower() in ("auto", "rx"):
        return text.strip().lower()
    from ..physics.pupil import check_pupil_mm  # on use: start-up time (module docstring)

    return check_pupil_mm(text, field)


FOVEA_HELP = ("correct only a window of this radius in degrees of visual angle around the gaze (a square of half-side "
              "DEG times the display's pixels per degree; the rest of the view is shown as it is), or off: the whole "
              "view (default)")
GAZE_HELP = "where the eye looks, degrees from the view's centre, x right and y up (default 0,0: the centre)"
PERIPHERY_HELP = ("what the view shows outside the window: quarter (default; a correction of the whole view at a "
                  "quarter of the resolution, 2 iterations a frame), half (at half the resolution, 1 iteration: "
                  "nearer the full field, about twice the bytes) or target (the view as it came: the cheapest, "
                  "and on a headset the periphery still sees the blur)")


def parse_fovea(text: Any, field: str = "--fovea") -> float | None:
    """``--fovea``: ``off`` (None) or a window radius in degrees
    (:data:`~vrcorrect.runtime.strategies.foveated.MIN_FOVEA_DEG` to ``MAX_FOVEA_DEG``)."""
    from ..runtime.strategies.foveated import MAX_FOVEA_DEG, MIN_FOVEA_DEG  # on use: start-up time

    if text is None or (isinstance(text, str) and text.strip().lower() == "off"):
        return None
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = float("nan")
    if not (math.isfinite(value) and MIN_FOVEA_DEG <= value <= MAX_FOVEA_DEG):
        raise ValidationError(field, text, f"off or a radius in degrees from {MIN_FOVEA_DEG:g} to {MAX_FOVEA_DEG:g}")
    return value


def parse_gaze(text: Any, field: str = "--gaze") -> tuple[float, float]:
    """``--gaze X,Y``: degrees from the view's centre, each from -90 to 90."""
    try:
        x, y = (float(v) for v in str(text).split(","))
    except ValueError:
        x = y = float("nan")
    if not all(math.isfinite(v) and -90.0 <= v <= 90.0 for v in (x, y)):
        raise ValidationError(field, text, "X,Y: two numbers of degrees from the view's centre, each from -90 to 90 "
                              "(x right, y up), e.g. 5,-3")
    return x, y


def add_pupil_options(p: argparse.ArgumentParser, robust: bool = True, band: bool = False) -> None:
    """``--pupil`` (and ``--robust``, and ``--band``): the eye as it is (``correct``, ``simulate``; the
    real-time commands take them with their filter options)."""
    g = p.add_argument_group("the eye as it is")
    g.add_argument("--pupil", default="auto", metavar="auto|rx|MM", help=PUPIL_HELP)
    if robust:
        g.add_argument("--robust", choices=("on", "off"), default="on", help=ROBUST_HELP)
    if band:
        g.add_argument("--band", choices=("auto", "default"), default="auto", help=BAND_HELP)


#: The methods ``--band auto`` designs a page on white paper over the page band for: the solvers of
#: the objective, whose solutions the page band was judged on.  ``wiener`` and ``learned`` keep the
#: default band (the shipped learned model fell to -0.07 JOD below none under the page band on two
#: of six rendered pages on desktop, docs/realtime.md).
PAGE_BAND_METHODS = ("fast", "paper", "conventional")


def picture_band(args: argparse.Namespace, display: "DisplayProfile", image_linear: np.ndarray):
    """The band ``--band`` designs ``image_linear`` over (:func:`~vrcorrect.physics.page.choose_band`),
    and a line saying why; ``(None, None)`` (the default band, nothing to say) with ``--robust off`` or
    ``--band default``, or where the command has no ``--band``; the default band and a line saying so
    for a page on white paper where the method is not one of :data:`PAGE_BAND_METHODS`."""
    if getattr(args, "robust", "on") != "on" or getattr(args, "band", "default") != "auto":
        return None, None
    from ..physics.page import choose_band  # on use: start-up time (module docstring)
    from ..physics.robust import RobustBand  # on use: start-up time (module docstring)

    choice = choose_band(image_linear, display)
    method = str(getattr(args, "method", "fast"))
    if choice.page_band and method not in PAGE_BAND_METHODS:
        return RobustBand(), (f"the picture is {choice.verdict.describe()}, but --method {method} keeps the default band "
                      f"(the page band is for {', '.join(PAGE_BAND_METHODS)})")
    return choice.band, choice.describe()


def viewing_pupil(args: argparse.Namespace, eye: "EyeRx", display: "DisplayProfile", image_linear: np.ndarray,
                  age_years: float | None, design: bool = True) -> tuple[float, list[str]]:
    """The pupil ``--pupil`` asks for, and lines saying where it came from (``auto``: the light of
    ``image_linear`` on ``display``, clamped with a note where it must be, then the nearest of the pupil
    bank's entries, :data:`~vrcorrect.runtime.pupil_bank.BANK_PUPILS_MM`, as the real-time path designs
    for, so that a still, a clip's frame and a rendered frame of the same light agree; ``design=False``:
    the light's own pupil, the pupil the eye sees through, for ``simulate``)."""
    kernel_options(args)                            # every model option checked before a line is printed
    choice = parse_pupil(args.pupil)
    upper = eye.higher_order.pupil_diameter_mm if eye.higher_order is not None else None
    if choice == "rx":
        return eye.pupil_diameter_mm, [f"pupil {eye.pupil_diameter_mm:g} mm (the prescription's; --pupil rx)"]
    if choice != "auto":
        lines = [f"pupil {choice:g} mm (--pupil)"]
        if upper is not None and choice > upper:
            raise ValidationError("--pupil", choice, f"at most {upper:g} mm, the pupil the prescription's "
                                                     "higher-order terms were measured at")
        return float(choice), lines
    from ..physics.perception import luminance_weights  # on use: start-up time (module docstring)
    from ..physics.pupil import (
        pupil_from_light,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    h, w = image_linear.shape[:2]
    mean = float(np.mean(np.asarray(image_linear, np.float64) @ luminance_weights(display)))
    from ..runtime.pupil_bank import (
        nearest_bank_pupil,  # on use: start-up time (apps/__init__: the parser loads no layer below)
    )

    estimate = pupil_from_light(mean, display, age_years, image_size=(w, h), upper_mm=upper,
                                upper_why="the pupil the higher-order terms were measured at")
    if not design:
        return estimate.diameter_mm, [estimate.describe() + " (--pupil auto)", *estimate.notes]
    entry = nearest_bank_pupil(estimate.diameter_mm, upper)
    return entry, [estimate.describe() + f" (--pupil auto): designed for {entry:.2f} mm, the nearest of the pupils "
                   "the real-time path keeps designs for", *estimate.notes]


class PupilPerFrame:
    """``--pupil`` for each source frame of a clip: the pupil its light gives (:func:`viewing_pupil`),
    its lines said when the pupil changes, and what ``build(pupil_mm)`` makes for it, made once per
    pupil (``seconds``: the time those builds took).  With ``bands``, also the band ``--band`` gives
    the frame (:func:`picture_band`), said when it changes: ``build(pupil_mm, band)``, made once per
    pupil and band."""

    def __init__(self, args: argparse.Namespace, eye: "EyeRx", display: "DisplayProfile", age_years: float | None,
                 build: Callable[..., Any], design: bool = True, bands: bool = False):
        self.args, self.eye, self.display, self.age_years = args, eye, display, age_years
        self.build, self.design, self.bands = build, design, bands
        self.built: dict[Any, Any] = {}
        self.said: float | None = None
        self.said_band: Any = None
        self.seconds = 0.0

    def __call__(self, image_linear: np.ndarray, where: str = "") -> tuple[float, Any]:

        pupil, lines = viewing_pupil(self.args, self.eye, self.display, image_linear, self.age_years,
                                     design=self.design)
        band, band_line = picture_band(self.args, self.display, image_linear) if self.bands else (None, None)
        if pupil != self.said:
            for line in lines:
                print(f"vrcorrect: {line}{where}", flush=True)   # stdout: an error stays the one line on stderr
            self.said = pupil
        if band_line is not None and band != self.said_band:
            print(f"vrcorrect: {band_line}{where}", flush=True)
            self.said_band = band
        key = (pupil, band) if self.bands else pupil
        if key not in self.built:
            t0 = time.perf_counter()
            self.built[key] = self.build(pupil, band) if self.bands else self.build(pupil)
            self.seconds += time.perf_counter() - t0
        return pupil, self.built[key]


def build_design(args: argparse.Namespace, eye: "EyeRx", display: "DisplayProfile", pupil_mm: float,
                 reference: str, robust: bool | None = None, band=None):
    """The correction's design (:func:`vrcorrect.physics.robust.design_eye`) with a progress bar:
    robust as ``--robust`` says (or ``robust``), over ``band`` (None: the default band), for
    ``pupil_mm``, ``reference`` glasses or ideal."""
    from ..physics.robust import design_eye  # on use: start-up time (module docstring)

    robust = (getattr(args, "robust", "on") == "on") if robust is None else robust
    bar = tqdm(desc="building the eye's kernels" + (" (the robust band)" if robust else ""), unit="kernel",
               disable=None, leave=False, file=sys.stderr)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        return design_eye(eye, display, pupil_mm, robust=robust, reference=reference, band=band,
                          options=kernel_options(args), progress=progress)
    finally:
        bar.close()


def print_notes(notes: Sequence[str]) -> None:
    for note in notes:
        print(f"vrcorrect: note: {note}", file=sys.stderr)


def available_memory_bytes() -> float | None:
    """Memory available to a new allocation now (Linux ``MemAvailable``), or None where unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        return None
    return None


def check_memory(method: str, height: int, width: int) -> None:
    """Refuse, before any work, an image whose correction would not fit in memory (one line)."""
    from ..solvers import PEAK_MEMORY, peak_memory_bytes  # on use: start-up time (apps/__init__)

    available = available_memory_bytes()
    need = peak_memory_bytes(method, height, width)
    if available is None or need <= 0.9 * available:
        return
    fixed, per_pixel = PEAK_MEMORY[method]
    side = int(math.sqrt(max(0.9 * available - fixed, 0.0) / per_pixel))
    raise ValidationError("input", f"{width}x{height} pixels",
                          f"an image that fits in memory: {method} needs about {need / 2**30:.1f} GiB for it "
                          f"(about {per_pixel:.0f} bytes a pixel), {available / 2**30:.1f} GiB is available now; "
                          f"up to about {side}x{side} here")


def finite_json(value: Any, where: str, notes: list[str]) -> Any:
    """``value`` with every non-finite float replaced by ``None`` (JSON has no Infinity or NaN),
    each replacement explained in ``notes``: ``"metrics.psnr: null (inf: ...)"``."""
    if isinstance(value, dict):
        return {k: finite_json(v, f"{where}.{k}" if where else str(k), notes) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v, f"{where}[{i}]", notes) for i, v in enumerate(value)]
    if isinstance(value, (float, np.floating)) and not math.isfinite(float(value)):
        why = ("the two images are identical, so the error is zero" if where.endswith("psnr") and value > 0
               else "not a finite number")
        notes.append(f"{where}: null ({float(value)}: {why})")
        return None
    return value
