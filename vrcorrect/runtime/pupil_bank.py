"""The viewing pupil followed in real time: the frame's light to a pupil, and a bank of designs to
switch between (``pupil="auto"``, :class:`~vrcorrect.runtime.eye_model.CorrectorOptions`).

* **The light.**  The GPU reduces each decoded frame to its mean relative luminance
  (:class:`~vrcorrect.runtime.strategies.base.LuminanceMeter`); the corrector reads it two frames late
  (nothing waits for the GPU).
* **The pupil** (:class:`PupilFollower`): Watson & Yellott's unified formula gives the light-adapted
  pupil of that luminance on the display (:func:`~vrcorrect.physics.pupil.pupil_from_light`), and the
  pupil moves towards it with its own dynamics (:class:`~vrcorrect.physics.pupil.PupilDynamics`:
  it constricts within about 0.4 s and dilates over seconds).
* **The bank** (:class:`PupilBank`): designs for the pupils of :data:`BANK_PUPILS_MM`, a step of
  ``1.25^(1/3)`` (about 7.7 %) from 2 to 7.5 mm, so that the robust design's pupil (one step below the
  entry, :data:`~vrcorrect.physics.robust.DESIGN_PUPIL_FACTOR`) is the entry below and a band of pupils
  ``x0.8``/``x1.25`` lands on entries three steps away: neighbouring designs share their kernels.  An
  entry is designed on the bank's own worker thread when first asked for (never on the render thread),
  with its spectra on the grids the corrector uses, and kept; the follower's pupil picks the nearest
  entry with hysteresis (:data:`HYSTERESIS`: a quarter of a step past the midpoint), the current design
  stays while the next is built, and the switch itself only uploads the new spectra: the iteration
  goes on from its state, so the picture moves to the new design over a few frames instead of
  jumping (``tests/test_pupil.py`` holds that).  Where the corrector keeps its designs
  (:meth:`~vrcorrect.runtime.corrector.Corrector.keep_pupil_designs`: the OpenXR layer) the worker
  takes a design from the cache (:func:`~vrcorrect.runtime.eye_cache.load_design`) before designing
  it, and keeps what it designs; the layer's priming asks for the light's design at once and waits
  for it (:meth:`~vrcorrect.runtime.pupil_state.PupilState.follow_now`).  Every design's grid holds the kernel of the bank's
  widest reachable design (:func:`bank_grid_kernel_size`), so a switch keeps the grids.
* **The band** (``band="auto"``): the bank's designs are keyed by ``(pupil, band)`` where the band is
  chosen by the picture too (:mod:`~vrcorrect.runtime.pupil_state`); such a bank sizes its grids with
  :func:`band_slack` more, so that the other band's designs fit them.
* **The reach** (:func:`bank_reach_mm`): the grids hold designs up to :data:`BANK_REACH_STEPS` entries
  above the first design, not up to 7.5 mm.  A pupil beyond the reach is designed for at the reach (a
  smaller pupil than the eye's: less correction, never the over-correction a too-large design gives
  through a smaller pupil), and the corrector's pupil status says so.  Grids sized for 7.5 mm cost
  what the kernel costs, every frame: for the OpenXR layer test's right eye (-4.00/-2.00, quest2, a
  robust design at 3.125 mm) a 96x64 view's grid held a 107 px kernel, 288x320 (15 times the view),
  and 216x240 with the reach (71 px); on llvmpipe the layer's frame of both eyes fell from 0.37-0.41 s
  to 0.24-0.30 s.

Layer 5: numpy; never torch.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from dataclasses import dataclass
from typing import Callable, Hashable

import numpy as np

from ..plumbing.errors import VrcorrectError
from ..specs.display import DisplayProfile, decode
from ..specs.prescription import EyeRx

__all__ = ["BANK_STEP", "BANK_PUPILS_MM", "BANK_REACH_STEPS", "HYSTERESIS", "GRID_MARGIN", "bank_pupils",
           "bank_grid_kernel_size", "band_slack", "codes_band", "codes_light_and_band", "bank_reach_mm", "nearest_bank_pupil", "PupilFollower", "PupilBank"]

log = logging.getLogger(__name__)

BANK_STEP = 1.25 ** (1.0 / 3.0)
"""The ratio of neighbouring pupils in the bank (the robust design's pupil is one step below an entry;
x1.25 is three steps)."""


def bank_pupils() -> tuple[float, ...]:
    from ..physics.pupil import PUPIL_RANGE_MM  # start-up time: the optics load with the first eye

    lo, hi = PUPIL_RANGE_MM
    n = int(math.floor(math.log(hi / lo) / math.log(BANK_STEP) + 1e-9))
    pupils = [round(lo * BANK_STEP ** k, 4) for k in range(n + 1)]
    if pupils[-1] < hi - 1e-6:
        pupils.append(hi)
    return tuple(pupils)


BANK_PUPILS_MM: tuple[float, ...] = (2.0, 2.1544, 2.3208, 2.5, 2.693, 2.901, 3.125, 3.3663, 3.6262, 3.9063, 4.2079,
                                     4.5328, 4.8828, 5.2599, 5.666, 6.1035, 6.5748, 7.0825, 7.5)
"""The bank's pupils (mm): ``2 x BANK_STEP^k`` up to 7.5 mm, and 7.5 (``tests/test_pupil.py`` holds it
to :data:`BANK_STEP` and :data:`~vrcorrect.physics.pupil.PUPIL_RANGE_MM`)."""
HYSTERESIS = 0.25
"""A switch to the next entry waits until the pupil is this fraction of a step past the midpoint."""


GRID_MARGIN = 1.0
"""The grids' room for a design's kernel beyond the linear extrapolation (:func:`bank_grid_kernel_size`):
none, since the extrapolation over-estimates (measured from 3.9 to 8 mm pupils, -2.25 and -5 D, quest2
and desktop: the kernels grew 1.5 to 1.8 times for a 2.05 times larger pupil)."""


BANK_REACH_STEPS = 6
"""How many bank entries above the first design the grids reach (``1.25^2``, about 1.56 times its
pupil): a headset's light gives 2.7-3.4 mm (Watson & Yellott 2012), a range of three steps, so six
reach it from any start within it, and a dark scene's 4.9 mm from a 3.1 mm start."""


def bank_reach_mm(entry_mm: float) -> float:
    """The largest bank entry the grids of a bank first designed at ``entry_mm`` hold
    (:data:`BANK_REACH_STEPS` entries above it, at most the bank's last)."""
    index = min(range(len(BANK_PUPILS_MM)), key=lambda i: abs(math.log(entry_mm / BANK_PUPILS_MM[i])))
    return BANK_PUPILS_MM[min(index + BANK_REACH_STEPS, len(BANK_PUPILS_MM) - 1)]


def band_slack(design) -> float:
    """How much wider the other band's widest kernel may be than a robust design's over its own band, at
    the same pupil (a bank with ``band="auto"`` switches between the default band and the page band,
    :data:`~vrcorrect.physics.page.PAGE_BAND`, oriented for this eye): the ratio of the bands' widest
    blur, each member's pupil factor times its worst meridian's residual defocus at the display (a
    defocus blur's width grows with both; below 0.25 D counts as 0.25 D, where diffraction sets the
    width); at least 1, at most 2; 1 for a design that is not robust."""
    from ..physics.page import PAGE_BAND  # start-up time: the optics load with the first eye
    from ..physics.robust import RobustBand, oriented_band  # start-up time (as above)

    if not getattr(design, "robust", False):
        return 1.0
    band = getattr(design, "band", None) or RobustBand()           # None: the default band
    residual = design.nominal.report.focus.residual
    m, j = residual.M_D, math.hypot(residual.J0_D, residual.J45_D)

    def blur(b: RobustBand) -> float:
        b = oriented_band(b, m)
        return max(f * max(abs(m + o) + j, 0.25) for f in b.pupil_factors for o in b.sphere_offsets_D)

    return min(max(max(blur(RobustBand()), blur(PAGE_BAND)) / blur(band), 1.0), 2.0)


def bank_grid_kernel_size(design, reach_mm: float | None = None, slack: float = 1.0) -> int:
    """The kernel size every grid of a bank holds, so that a switch keeps the grids: the widest member
    kernel of ``design`` (:class:`~vrcorrect.physics.robust.Design`) extrapolated linearly in the pupil
    (a defocus blur's width grows with it) to the design of the bank's reach ``reach_mm``
    (:func:`bank_reach_mm`; None: the bank's largest pupil), with :data:`GRID_MARGIN` room and
    ``slack`` more (:func:`band_slack`: a bank that may switch to the other band), doubled for the effective kernels' window where the design is robust.  A later design that still does not
    fit is installed anew (a cold start) instead of switched."""
    from ..physics.robust import MAX_MEMBER_PUPIL_MM, RobustBand  # start-up time: the optics load with the first eye

    members = design.members or ()
    widest = max([m.kernel_size for m in members] + [design.nominal.size])
    pupil = max([m.pupil_mm for m in members] + [design.pupil_mm])
    reach = max(BANK_PUPILS_MM) if reach_mm is None else reach_mm
    own = getattr(design, "band", None) or RobustBand()
    top = min(reach * (max(own.pupil_factors) if design.robust else 1.0), MAX_MEMBER_PUPIL_MM)
    size = int(math.ceil(widest * max(top / pupil, 1.0) * GRID_MARGIN * slack)) | 1
    return 2 * size + 1 if design.robust else size


def nearest_bank_pupil(pupil_mm: float, upper_mm: float | None = None) -> float:
    """The bank entry nearest ``pupil_mm`` (in ratio), at most ``upper_mm`` where one is given (the
    pupil higher-order terms were measured at; below the bank's least entry it is itself)."""
    choices = [p for p in BANK_PUPILS_MM if upper_mm is None or p <= upper_mm + 1e-9]
    if not choices:
        return float(upper_mm)
    return min(choices, key=lambda p: abs(math.log(pupil_mm / p)))


class PupilFollower:
    """The frames' light to a pupil (module docstring) and the bank entry it asks for.

    ``update(mean_relative_luminance, dt_s)`` returns the entry to design for: the current one until
    the dynamic pupil is nearer another by :data:`HYSTERESIS` of a step, and never above ``reach_mm``
    (the grids' reach, :func:`bank_reach_mm`; None: no limit but ``upper_mm``)."""

    def __init__(self, display: DisplayProfile, age_years: float | None = None, upper_mm: float | None = None,
                 entry_mm: float | None = None, reach_mm: float | None = None):
        from ..physics.pupil import PupilDynamics  # start-up time (as above)

        self.display, self.age_years, self.upper_mm, self.reach_mm = display, age_years, upper_mm, reach_mm
        self.dynamics = PupilDynamics()
        self.entry_mm = entry_mm
        self.estimate = None
        self.notes: tuple[str, ...] = ()
        self.held_at_reach = False
        """Whether the last update's pupil lay beyond the reach, so the entry asked for is the reach's."""

    @property
    def pupil_mm(self) -> float | None:
        """The pupil now (after its dynamics), None before the first measurement."""
        return self.dynamics.diameter_mm

    def update(self, mean_relative_luminance: float, dt_s: float) -> float:
        from ..physics.pupil import pupil_from_light  # start-up time (as above)

        self.estimate = pupil_from_light(max(float(mean_relative_luminance), 0.0), self.display, self.age_years,
                                         upper_mm=self.upper_mm, upper_why="the pupil the higher-order terms were "
                                                                           "measured at")
        self.notes = self.estimate.notes
        pupil = self.dynamics.update(self.estimate.diameter_mm, dt_s)
        nearest = nearest_bank_pupil(pupil, self.upper_mm)
        self.held_at_reach = self.reach_mm is not None and nearest > self.reach_mm + 1e-9
        if self.held_at_reach:
            nearest = self.reach_mm
            self.notes += (f"designed for {self.reach_mm:.2f} mm, the grids' reach, not the {pupil:.2f} mm pupil "
                           "(less correction, never an over-correction)",)
        if self.entry_mm is None:
            self.entry_mm = nearest
        elif nearest != self.entry_mm:
            step = math.log(BANK_STEP)
            gap = abs(math.log(pupil / self.entry_mm)) - abs(math.log(pupil / nearest))
            if gap >= 2.0 * HYSTERESIS * step:
                self.entry_mm = nearest
        return self.entry_mm


class _Closed(Exception):
    """Raised from a design's progress on the worker of a bank that closed."""


@dataclass(frozen=True)
class _Job:
    key: Hashable
    grids: tuple


def _named(key: Hashable) -> str:
    """A design's key in a log line: ``3.13 mm``, or ``3.13 mm, page band`` for ``(pupil, band)``."""
    if isinstance(key, tuple):
        return f"{key[0]:.2f} mm, {key[1]} band"
    return f"{key:.2f} mm"


class PupilBank:
    """Designs for one eye at the bank's pupils, built on a worker thread of the bank's own.

    A design's key is its pupil, or ``(pupil_mm, band)`` where the band is chosen too
    (:class:`~vrcorrect.runtime.pupil_state.PupilState`).
    ``build(key, kernels, grids, progress)`` designs one (:func:`~vrcorrect.runtime.eye_model.build_eye_model`)
    with its spectra on the strategy's grids; :meth:`request` asks for one without waiting, :meth:`get`
    returns it once built (None before).  Designs share one cache of kernels (``kernels``: the first
    design's too).
    A design that fails (an eye the model's range refuses) is remembered as failed, with its message.
    """

    def __init__(self, eye: EyeRx, display: DisplayProfile, options, age_years: float | None,
                 build: Callable[..., object], kernels: dict | None = None):
        self.eye, self.display, self.options, self.age_years = eye, display, options, age_years
        self._build = build
        self.kernels: dict = {} if kernels is None else kernels
        self._models: dict[Hashable, object] = {}
        self.failed: dict[Hashable, str] = {}
        self._lock = threading.Lock()
        self._jobs: queue.Queue[_Job | None] = queue.Queue()
        self._queued: set[Hashable] = set()
        self._worker: threading.Thread | None = None
        self._closing = threading.Event()

    def get(self, key: Hashable):
        with self._lock:
            return self._models.get(key)

    def put(self, key: Hashable, model) -> None:
        """Keep a design built elsewhere (the first, built before the first frame)."""
        with self._lock:
            self._models[key] = model

    def build_now(self, key: Hashable, grids: tuple = ()):
        """Design ``key`` on the caller's thread (a batch render that must not run ahead of it)."""
        model = self.get(key)
        if model is None:
            model = self._build(key, self.kernels, grids, None)
            self.put(key, model)
        return model

    def request(self, key: Hashable, grids: tuple = ()) -> None:
        """Have the worker design ``key`` (nothing if it is built, queued or failed)."""
        with self._lock:
            if key in self._models or key in self._queued or key in self.failed:
                return
            self._queued.add(key)
            if self._worker is None:
                # not a daemon: at exit the interpreter must not tear down a thread that is inside
                # a C extension (scipy's FFT), which aborts the process; close() waits for it.
                self._worker = threading.Thread(target=self._run, name="vrcorrect-pupil-bank", daemon=False)
                self._worker.start()
        self._jobs.put(_Job(key, tuple(grids)))

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            try:
                model = self._build(job.key, self.kernels, job.grids, self._check)
                with self._lock:
                    self._models[job.key] = model
            except _Closed:
                return
            except VrcorrectError as exc:
                with self._lock:
                    self.failed[job.key] = str(exc)
                log.warning("pupil bank: no design for %s: %s", _named(job.key), exc)
            except Exception as exc:                     # a worker must not die silently
                with self._lock:
                    self.failed[job.key] = repr(exc)
                log.exception("pupil bank: the design for %s failed", _named(job.key))
            finally:
                with self._lock:
                    self._queued.discard(job.key)

    def wait_idle(self, timeout_s: float = 600.0) -> None:
        """Wait until every queued design is built (tests, batch renders)."""

        end = time.monotonic() + timeout_s
        while True:
            with self._lock:
                if not self._queued:
                    return
            if time.monotonic() > end:
                raise TimeoutError("pupil bank: designs still queued")
            time.sleep(0.01)

    def _check(self, done: int, total: int) -> None:
        """A design's progress on the worker: stop it (between two kernels) once the bank closes."""
        if self._closing.is_set():
            raise _Closed

    def close(self) -> None:
        """Drop the designs still queued, stop the one in progress at its next kernel and wait for it."""
        worker, self._worker = self._worker, None
        if worker is None:
            return
        self._closing.set()
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                break
            if job is not None:
                with self._lock:
                    self._queued.discard(job.key)
        self._jobs.put(None)
        if worker is not threading.current_thread():
            worker.join()


def relative_luminance_of(image_linear: np.ndarray, display: DisplayProfile) -> float:
    """The mean relative luminance (white = 1) of an ``(H, W, 3)`` linear image on ``display``
    (:func:`~vrcorrect.physics.perception.luminance_weights`): what the GPU's meter measures."""
    from ..physics.perception import luminance_weights  # start-up time (as above)

    return float(np.mean(np.asarray(image_linear, np.float64) @ luminance_weights(display)))


def _codes_linear(codes: np.ndarray, display: DisplayProfile) -> np.ndarray:
    """A frame's code values (8-bit, or floats held in [0, 1]; ``(H, W, 3+)``, the alpha left out) as
    linear display RGB."""
    pixels = np.asarray(codes)[..., :3]
    unit = (pixels.astype(np.float32) / 255.0 if pixels.dtype == np.uint8
            else np.clip(pixels.astype(np.float32), 0.0, 1.0))
    return decode(display, unit)


def codes_luminance(codes: np.ndarray, display: DisplayProfile) -> float:
    """:func:`relative_luminance_of` a frame given as code values: 8-bit, or floats in [0, 1] (held
    there), ``(H, W, 3+)`` (the alpha, if any, left out): what a window's or a render's first frame
    is measured as before its first design."""
    return relative_luminance_of(_codes_linear(codes, display), display)


def codes_band(codes: np.ndarray, display: DisplayProfile) -> str:
    """The band a frame given as code values (as :func:`codes_luminance`) is designed over with
    ``band="auto"``: ``"page"`` for a page on white paper, else ``"default"``
    (:func:`~vrcorrect.physics.page.choose_band`, looked at as the real-time path looks)."""
    return _band_of_linear(_codes_linear(codes, display), display)


def codes_light_and_band(codes: np.ndarray, display: DisplayProfile, band: bool) -> tuple[float, str | None]:
    """A first frame's light (:func:`codes_luminance`) and, with ``band`` (``band="auto"``), its band
    (:func:`codes_band`; else None), from one decoding of its codes."""
    linear = _codes_linear(codes, display)
    return relative_luminance_of(linear, display), _band_of_linear(linear, display) if band else None


def _band_of_linear(linear: np.ndarray, display: DisplayProfile) -> str:
    from ..physics.page import REALTIME_LOOK_SIDE, choose_band  # start-up time (as above)

    return "page" if choose_band(linear, display, REALTIME_LOOK_SIDE).page_band else "default"
