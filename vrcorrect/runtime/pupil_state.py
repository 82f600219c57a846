"""A corrector's viewing pupil with ``pupil="auto"``: :class:`PupilState` measures each frame's light
on the GPU, follows the pupil with it (:class:`~vrcorrect.runtime.pupil_bank.PupilFollower`) and
switches the :class:`~vrcorrect.runtime.corrector.Corrector` between the designs of its bank
(:class:`~vrcorrect.runtime.pupil_bank.PupilBank`), built off the render thread.

With ``band="auto"`` (where :func:`~vrcorrect.runtime.eye_model.band_switches`) it also chooses the
robust band by the picture, as ``vrcorrect correct --band auto`` does: every :data:`LOOK_EVERY` frames
the GPU takes a strided look at the frame's luminance (:class:`~vrcorrect.runtime.strategies.base.PageLook`,
at most :data:`~vrcorrect.physics.page.REALTIME_LOOK_SIDE` a side), read :data:`LOOK_LATE` frames later
and judged on this thread (:func:`~vrcorrect.physics.page.luminance_verdict`, a few ms); after
:data:`BAND_HOLD` verdicts in a row that differ from the band in use, the bank designs that band at
the pupil's entry and the corrector switches to it as it switches pupils: the iteration goes on from
its state, and the light cap (a uniform, ``light_cap.glsl``) follows the design.  The bank's designs
are keyed by ``(pupil, band)``.

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING, Callable, Mapping

from ..specs.prescription import EyeRx
from . import eye_cache
from .eye_model import EyeModel, band_switches, build_eye_model, initial_pupil_mm
from .pupil_bank import PupilBank, PupilFollower
from .strategies.base import LuminanceMeter, PageLook
from .strategies.spectra import bank_spectra

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from .corrector import Corrector

__all__ = ["PupilState", "BandFollower", "LOOK_EVERY", "LOOK_LATE", "BAND_HOLD"]

LOOK_EVERY = 10
"""``band="auto"``: frames between two looks at the picture (a ninth of a second at 90 Hz)."""
LOOK_LATE = 2
"""Frames after a look that it is read (the GPU has done it by then: nothing waits)."""
BAND_HOLD = 2
"""Verdicts in a row that a band must get before the bank switches to it (a cross-fade or a single
odd frame does not flip the band)."""


class BandFollower:
    """When to look at the picture and which band its verdicts ask for (``band="auto"``; no GPU: the
    real-time path's :class:`PupilState` and ``bench robust``'s twin both follow the band with it).

    Each frame, :meth:`tick` says what to do with it: ``"look"`` (take a look at this frame),
    ``"read"`` (the pending look is :data:`LOOK_LATE` frames old: judge it and give the verdict to
    :meth:`judge`) or None.  A look is taken every :data:`LOOK_EVERY` frames (the first frame's at
    once); :attr:`band` changes after :data:`BAND_HOLD` verdicts in a row that ask for it.  After
    :meth:`cut` the next frame is looked at at once and its verdict alone decides."""

    def __init__(self, band: str = "default", cut: bool = False):
        self.band = band
        """The band the verdicts ask for (``"page"`` or ``"default"``)."""
        self.verdict = None
        """The last verdict (:class:`~vrcorrect.physics.page.PageVerdict`), None before the first."""
        self._said, self._agree = band, BAND_HOLD
        self._frames = self._looked = 0
        self._pending = self._decisive = False
        self._cut = cut

    def cut(self) -> None:
        """A scene cut: the next frame is looked at at once, and its verdict alone decides."""
        self._cut = True

    def tick(self) -> str | None:
        """This frame's part: ``"look"``, ``"read"`` or None (class docstring)."""
        self._frames += 1
        if self._cut:                                      # a pending look is of the last scene: looked past
            self._cut, self._decisive, self._pending, self._looked = False, True, True, self._frames
            return "look"
        if self._pending:
            if self._frames - self._looked >= LOOK_LATE:
                self._pending = False
                return "read"
            return None
        if self._looked == 0 or self._frames - self._looked >= LOOK_EVERY:
            self._pending, self._looked = True, self._frames
            return "look"
        return None

    def judge(self, verdict) -> str:
        """Count the verdict (:class:`~vrcorrect.physics.page.PageVerdict`) of the look just read;
        returns :attr:`band`."""
        from ..physics.page import band_of  # start-up time: the optics load with the first eye

        self.verdict = verdict
        said = "page" if band_of(verdict).page_band else "default"
        self._agree = BAND_HOLD if self._decisive else self._agree + 1 if said == self._said else 1
        self._said, self._decisive = said, False
        if self._agree >= BAND_HOLD:
            self.band = said
        return self.band


class PupilState:
    """A corrector's viewing pupil with ``pupil="auto"`` (:mod:`vrcorrect.runtime.pupil_bank`): the GPU's
    luminance of each frame, the pupil following it, and the bank of designs it switches between."""

    def __init__(self, corrector: "Corrector", first_luminance: float | None, first_band: str | None = None):
        from ..physics.page import REALTIME_LOOK_SIDE  # start-up time: the optics load with the first eye
        from ..physics.perception import luminance_weights  # start-up time (as above)

        self.c = corrector
        self.first_luminance = first_luminance
        weights = luminance_weights(corrector.display)
        self.meter = LuminanceMeter(corrector.gpu, weights)
        self.look: PageLook | None = PageLook(corrector.gpu, weights, REALTIME_LOOK_SIDE) \
            if band_switches(corrector.options) else None
        """``band="auto"``: the GPU's look at the picture (None: the band is the default's)."""
        # a first frame whose band nobody judged (the OpenXR layer's) is a new scene: looked at at once
        self.bands = BandFollower(first_band or "default", cut=first_band is None) if self.look is not None else None
        """``band="auto"``: when to look and the band the verdicts ask for (:attr:`band`)."""
        self.current_band = self.band
        self.kernels: dict = {}                         # shared by every design of this eye (the bank's)
        self.follower: PupilFollower | None = None
        self.bank: PupilBank | None = None
        self.current: float | None = None
        self.switches = 0
        self._last_time: float | None = None
        self.cache_env: Mapping[str, str] | None = None
        """Where the bank's designs are kept between runs (:mod:`~vrcorrect.runtime.eye_cache`'s
        ``designs``, under this environment's cache folder); None: designed again in every run."""

    def _upper(self, eye: EyeRx) -> float | None:
        return eye.higher_order.pupil_diameter_mm if eye.higher_order is not None else None

    def first_entry(self, eye: EyeRx) -> float:
        """The bank entry the first model is designed for (the first frame's light where given)."""

        return initial_pupil_mm(eye, self.c.display, self.c.options, self.first_luminance, self.c.age_years)

    def installed(self, model: EyeModel, switched: bool = False) -> None:
        """A model is in use: a new eye (a new bank, the follower kept) or a bank's switch."""
        upper = self._upper(model.eye)
        if not switched:
            if self.bank is None or self.bank.eye != model.eye:
                if self.bank is not None:
                    self.bank.close()
                    self.kernels = {}                   # a new eye: its own kernels
                self.bank = PupilBank(model.eye, self.c.display, self.c.options, self.c.age_years, self._build,
                                      self.kernels)
            self.bank.put((model.pupil_mm, model.band), model)
            if self.follower is None:
                self.follower = PupilFollower(self.c.display, self.c.age_years, upper, model.pupil_mm)
            self.follower.upper_mm = upper
            self.follower.reach_mm = model.reach_mm          # the new grids' reach (a new eye: its own)
        else:
            self.switches += 1
        self.current, self.current_band = model.pupil_mm, model.band
        if self.follower is not None:
            self.follower.entry_mm = model.pupil_mm

    def _build(self, wanted: tuple[float, str], kernels: dict, grids: tuple, progress=None) -> EyeModel:
        """A bank's design (on its worker) for ``(pupil, band)``: the model and its spectra on the
        strategy's grids."""

        pupil_mm, band = wanted
        base = self.c.model
        key = model = None
        if self.cache_env is not None:
            key = eye_cache.design_key(base.eye, self.c.display, self.c.options, self.c.age_years, pupil_mm,
                                       base.grid_kernel_size, base.reach_mm, band)
            model = eye_cache.load_design(key, self.cache_env)
        if model is None:
            model = build_eye_model(base.eye, self.c.display, self.c.options, pupil_mm=pupil_mm,
                                    age_years=self.c.age_years, kernels=kernels,
                                    grid_kernel_size=base.grid_kernel_size, reach_mm=base.reach_mm, progress=progress,
                                    band=band)
            if key is not None:
                eye_cache.store_design(key, model, self.cache_env)
        self.c.check_eye(model.eye)
        return replace(model, spectra=bank_spectra(model, grids)) if grids else model

    def frame(self, linear: "moderngl.Texture") -> None:
        """Measure this frame's light (and look at it, every :data:`LOOK_EVERY` frames); follow the pupil
        with the frame two back and the band with the verdicts; switch or ask."""
        self.meter.measure(linear)
        self._look(linear)
        lum = self.meter.latest()
        now = time.monotonic()
        dt = self.c.frame_time_s if self.c.frame_time_s is not None else \
            (0.0 if self._last_time is None else now - self._last_time)
        self._last_time = now
        if lum is None or self.follower is None or self.bank is None:
            return
        entry = (self.follower.update(lum, dt), self.band)
        if entry == (self.current, self.current_band):
            return
        model = self.bank.get(entry)
        grids = self._grids()
        if model is None:
            if self.c.frame_time_s is not None:           # a batch render: deterministic, so wait for it
                model = self.bank.build_now(entry, grids)
            else:
                self.bank.request(entry, grids)
                return
        self.c.switch_design(model)

    @property
    def band(self) -> str:
        """The band the picture asks for (the verdicts', :data:`BAND_HOLD` in a row; ``"default"`` where the
        band does not switch); the design in use is :attr:`current_band`'s."""
        return self.bands.band if self.bands is not None else "default"

    @property
    def verdict(self):
        """The last verdict (:class:`~vrcorrect.physics.page.PageVerdict`), None before the first look."""
        return self.bands.verdict if self.bands is not None else None

    def cut(self) -> None:
        """A scene cut (:meth:`~vrcorrect.runtime.corrector.Corrector.reset`): the next frame is looked at
        at once, and its verdict alone decides the band, so that a switch lands among the cold start's
        own changes, :data:`LOOK_LATE` frames after the cut, not on a converged picture later."""
        if self.bands is not None:
            self.bands.cut()

    def _look(self, linear: "moderngl.Texture") -> None:
        """``band="auto"``: take this frame's look, or read the pending one and judge it, as
        :class:`BandFollower` says."""
        if self.look is None or self.bands is None:
            return
        from ..physics.page import luminance_verdict  # start-up time (as above)

        action = self.bands.tick()
        if action == "look":
            self.look.look(linear)
        elif action == "read":
            self.bands.judge(luminance_verdict(self.look.take()))

    def _grids(self) -> tuple:
        """The grids a design's spectra are made on before a switch (the strategy's; none for others)."""
        return self.c.strategy.spectra_grids() if hasattr(self.c.strategy, "spectra_grids") else ()

    def follow_now(self, wait_s: float, stopped: Callable[[], bool] = lambda: False) -> float | None:
        """Switch to the design the frame just corrected asks for, now: read its light (this waits for
        the GPU), have the bank's worker design that pupil (or take it from the bank or the cache) and
        wait for it at most ``wait_s`` (the caller's thread only waits).  For a build's priming, never
        an application's frame: the application's first corrected frames are then the light's design,
        not a mid-grey frame's switched a few seconds later.  Returns the light's design's pupil, now in
        use (switched to, or designed for already), or None (nothing measured, not ready in time,
        refused or ``stopped()``)."""
        lum = self.meter.newest()
        if lum is None or self.follower is None or self.bank is None:
            return None
        pupil = self.follower.update(lum, 0.0)
        entry = (pupil, self.band)
        if entry == (self.current, self.current_band):
            return pupil
        self.bank.request(entry, self._grids())
        deadline = time.monotonic() + wait_s
        while (model := self.bank.get(entry)) is None:
            if entry in self.bank.failed or stopped() or time.monotonic() > deadline:
                return None
            time.sleep(0.01)
        self.c.switch_design(model)
        return pupil

    def status(self) -> str:
        f = self.follower
        if f is None or f.pupil_mm is None or f.estimate is None:
            return f"pupil auto: {self.current:.2f} mm design, no frame measured yet" if self.current else "pupil auto"
        held = f.held_at_reach
        band = f", {self.current_band} band" if self.look is not None else ""
        return (f"pupil {f.pupil_mm:.2f} mm (auto: {f.estimate.luminance_cd_m2:.3g} cd/m^2), design "
                f"{self.current:.2f} mm{' (the grids reach no further)' if held else ''}{band}, "
                f"{self.switches} switch(es)")

    def release(self) -> None:
        self.meter.release()
        if self.look is not None:
            self.look.release()
        if self.bank is not None:
            self.bank.close()
