"""A corrector's viewing pupil with ``pupil="auto"``: :class:`PupilState` measures each frame's light
on the GPU, follows the pupil with it (:class:`~vrcorrect.runtime.pupil_bank.PupilFollower`) and
switches the :class:`~vrcorrect.runtime.corrector.Corrector` between the designs of its bank
(:class:`~vrcorrect.runtime.pupil_bank.PupilBank`), built off the render thread.

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING, Callable, Mapping

from ..specs.prescription import EyeRx
from . import eye_cache
from .eye_model import EyeModel, build_eye_model, initial_pupil_mm
from .pupil_bank import PupilBank, PupilFollower
from .strategies.admm import bank_spectra
from .strategies.base import LuminanceMeter

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from .corrector import Corrector

__all__ = ["PupilState"]


class PupilState:
    """A corrector's viewing pupil with ``pupil="auto"`` (:mod:`vrcorrect.runtime.pupil_bank`): the GPU's
    luminance of each frame, the pupil following it, and the bank of designs it switches between."""

    def __init__(self, corrector: "Corrector", first_luminance: float | None):
        from ..physics.perception import luminance_weights  # start-up time: the optics load with the first eye

        self.c = corrector
        self.first_luminance = first_luminance
        self.meter = LuminanceMeter(corrector.gpu, luminance_weights(corrector.display))
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
            self.bank.put(model.pupil_mm, model)
            if self.follower is None:
                self.follower = PupilFollower(self.c.display, self.c.age_years, upper, model.pupil_mm)
            self.follower.upper_mm = upper
            self.follower.reach_mm = model.reach_mm          # the new grids' reach (a new eye: its own)
        else:
            self.switches += 1
        self.current = model.pupil_mm
        if self.follower is not None:
            self.follower.entry_mm = model.pupil_mm

    def _build(self, pupil_mm: float, kernels: dict, grids: tuple, progress=None) -> EyeModel:
        """A bank's design (on its worker): the model and its spectra on the strategy's grids."""

        base = self.c.model
        key = model = None
        if self.cache_env is not None:
            key = eye_cache.design_key(base.eye, self.c.display, self.c.options, self.c.age_years, pupil_mm,
                                       base.grid_kernel_size, base.reach_mm)
            model = eye_cache.load_design(key, self.cache_env)
        if model is None:
            model = build_eye_model(base.eye, self.c.display, self.c.options, pupil_mm=pupil_mm,
                                    age_years=self.c.age_years, kernels=kernels,
                                    grid_kernel_size=base.grid_kernel_size, reach_mm=base.reach_mm, progress=progress)
            if key is not None:
                eye_cache.store_design(key, model, self.cache_env)
        self.c.check_eye(model.eye)
        return replace(model, spectra=bank_spectra(model, grids)) if grids else model

    def frame(self, linear: "moderngl.Texture") -> None:
        """Measure this frame's light; follow the pupil with the frame two back; switch or ask."""
        self.meter.measure(linear)
        lum = self.meter.latest()
        now = time.monotonic()
        dt = self.c.frame_time_s if self.c.frame_time_s is not None else \
            (0.0 if self._last_time is None else now - self._last_time)
        self._last_time = now
        if lum is None or self.follower is None or self.bank is None:
            return
        entry = self.follower.update(lum, dt)
        if entry == self.current:
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
        entry = self.follower.update(lum, 0.0)
        if entry == self.current:
            return entry
        self.bank.request(entry, self._grids())
        deadline = time.monotonic() + wait_s
        while (model := self.bank.get(entry)) is None:
            if entry in self.bank.failed or stopped() or time.monotonic() > deadline:
                return None
            time.sleep(0.01)
        self.c.switch_design(model)
        return entry

    def status(self) -> str:
        f = self.follower
        if f is None or f.pupil_mm is None or f.estimate is None:
            return f"pupil auto: {self.current:.2f} mm design, no frame measured yet" if self.current else "pupil auto"
        held = f.held_at_reach
        return (f"pupil {f.pupil_mm:.2f} mm (auto: {f.estimate.luminance_cd_m2:.3g} cd/m^2), design "
                f"{self.current:.2f} mm{' (the grids reach no further)' if held else ''}, {self.switches} switch(es)")

    def release(self) -> None:
        self.meter.release()
        if self.bank is not None:
            self.bank.close()
