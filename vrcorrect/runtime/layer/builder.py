"""The OpenXR API layer's build worker: every build (the first prescription, an edit, a view size
or format the current pipeline was not prepared for) runs here, off the application's frame: the
eye models (from the cache, else designed), then a pipeline on its own context, warmed up and
primed on a captured frame of the application's.

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from typing import TYPE_CHECKING, Any

from ...plumbing.errors import ValidationError
from ...specs.vocabulary import Backend

if TYPE_CHECKING:  # pragma: no cover - typing only
    from ...specs.display import DisplayProfile
    from ..corrector import Corrector
    from ..eye_source import EyeSource
    from .engine import Engine
from .. import eye_cache
from ..corrector import Corrector
from ..eye_model import CorrectorOptions
from ..eye_source import EyeSource
from ..glcache import egl_context, glx_context
from .config import (
    BUILD_NICE,
    CAPTURE_WAIT_S,
    LIGHT_WAIT_S,
    PRIME_BUDGET_S,
    LayerConfig,
    choose_display,
    one_line,
    one_line_text,
    prime_budget,
)
from .interop import MemoryObjects, Target
from .pipeline import Pipeline

__all__ = ["Builder", "CaptureRequest"]


class CaptureRequest:
    """The builder's request for a frame's content to prepare its pipeline on (priming, off the
    application's thread): the application's thread adds each view of the next frame it sees
    (OpenGL: the application's texture, with a fence after its rendering; Vulkan: the shared
    ``input`` image the shim copied the rect into) and sets :attr:`ready` at the frame's end."""

    def __init__(self) -> None:
        self.views: list[dict[str, Any]] = []
        self.ready = threading.Event()


class Builder:
    """The engine's build worker (one per configuration): it takes the eye models (from the cache, or
    from the eye source's worker, which designs them) and makes from them, off the application's
    thread, a :class:`Pipeline` on a GL context of its own (compiled, from the program cache where
    it can, and warmed up for the swapchains the application made); the application's thread takes
    it from :attr:`events` when it is ready.  It does the same for a prescription edit (the eye
    source's reload: the current pipeline corrects meanwhile) and for a view size or format the
    current pipeline was not prepared for.  Events: ``("log", text)``, ``("failed", stamp, text)``
    (the first models or pipeline could not be made), ``("pipeline", pipeline, what)``."""

    def __init__(self, engine: "Engine", config: LayerConfig, stamp: Any):
        self.engine, self.config, self.stamp = engine, config, stamp
        self.source: EyeSource | None = None
        self.display_holder: dict[str, Any] = {}
        self.events: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self._wake = threading.Event()
        self._stopped = False
        self._rebuild = False
        self.thread = threading.Thread(target=self._run, name="vrcorrect-layer-build", daemon=True)
        self.thread.start()

    def request_rebuild(self) -> None:
        self._rebuild = True
        self._wake.set()

    def stop(self) -> None:
        """Stop after the step running (a pipeline it builds is released, not handed over; its eye
        source is let go)."""
        self._stopped = True
        self._wake.set()

    def join(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s for the thread and its eye source's worker to end."""
        deadline = time.monotonic() + timeout
        self.thread.join(timeout)
        source = self.source
        return not self.thread.is_alive() and (source is None or source.join(max(0.0, deadline - time.monotonic())))

    def _post(self, *event: Any) -> None:
        self.events.put(event)

    def _run(self) -> None:
        try:
            # below the application's threads for the CPU (a Linux thread's own nice value; the eye
            # source's worker and GL's threads made from here inherit it)
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BUILD_NICE)
        except (AttributeError, OSError):
            pass
        try:
            if self._open():
                self._loop()
        except Exception as exc:  # noqa: BLE001  (every failure is a pass-through with its reason)
            stamp = self.source.snapshot.stamp if self.source is not None else self.stamp
            self._post("failed", stamp, f"the layer's build worker failed: {one_line(exc)}")
        finally:
            if self._stopped and self.source is not None:
                self.source.close(wait=False)

    def _open(self) -> bool:
        """The eye source (the prescription read, the options checked, with the options a
        :class:`~vrcorrect.runtime.corrector.Corrector` makes of the same configuration: the
        correction is the one it would design itself)."""

        config, holder = self.config, self.display_holder
        try:
            options = config.corrector_options
            backend = options.pop("backend", Backend.GLSL)  # Corrector(backend=...) then CorrectorOptions(backend=...)

            def display() -> DisplayProfile:            # on a worker: loading a profile takes seconds
                if "display" in holder:                 # from the cache
                    return holder["display"]
                profile, reason = choose_display(config.display, self.engine.view_size)
                holder["why"] = reason
                return profile

            self.source = EyeSource(config.rx, display, CorrectorOptions(backend=backend, **options))
        except Exception as exc:  # noqa: BLE001
            self._post("failed", self.stamp, one_line(exc))
            return False
        if not self._stopped:
            self.engine._source = self.source
        return not self._stopped

    def _loop(self) -> None:

        source, config = self.source, self.config
        assert source is not None
        t0 = time.perf_counter()
        cache_key = eye_cache.source_key(source, config.display, self.engine.view_size)
        cached = eye_cache.load(cache_key, self.engine.env)
        models: dict[str, tuple[Any, Any]] | None = None
        design_s = 0.0
        if cached is not None:
            self.display_holder["display"], self.display_holder["why"] = cached["display"], cached["why"]
            models = {eye: (cached["models"][eye], source.prescription) for eye in source.eyes}
            self._post("log", f"the eye models for {config.rx} came from the cache ({eye_cache.cache_dir(self.engine.env)})")
        else:
            source.design_all()
        built: Pipeline | None = None                    # the last pipeline handed over (its Correctors' check)
        pending = models is not None                      # models not yet built into a pipeline
        first = True
        while not self._stopped:
            seen = source.reloads_started
            updates, messages = source.poll()
            if source.reloads_started != seen:
                self._post("log", f"building the eye models for {config.rx} (changed; correcting with the current ones "
                                  "meanwhile) ...")
            if models is None:
                start = [u for u in updates if u.reason == "start"]
                if not start:
                    if messages:                              # the worker's first word: its start was refused
                        self._post("failed", source.snapshot.stamp, one_line_text(messages[0]))
                        return
                else:
                    models = {u.eye: (u.model, u.prescription) for u in start}
                    design_s = max(u.seconds for u in start)
                    pending = True
                    eye_cache.store(cache_key, source.display, self.display_holder.get("why", ""),
                                    {eye: m for eye, (m, _) in models.items()}, self.engine.env)
            reloads = {u.eye: u for u in updates if u.reason == "reload"}
            if reloads and models is not None:
                models.update({eye: (u.model, u.prescription) for eye, u in reloads.items()})
                pending = True
                eye_cache.store(eye_cache.source_key(source, config.display, self.engine.view_size),
                                source.display, self.display_holder.get("why", ""),
                                {eye: m for eye, (m, _) in models.items()}, self.engine.env)
            if models is not None:
                for message in messages:
                    self._post("log", one_line_text(message))
            targets = self.engine.targets()
            if models is not None and (pending or self._rebuild) and targets:
                self._rebuild = False
                what = "start" if first else ("reload" if reloads or pending else "targets")
                try:
                    pipeline, seconds = self._build(models, targets)
                except Exception as exc:  # noqa: BLE001
                    if first:
                        self._post("failed", source.snapshot.stamp, one_line(exc))
                        return
                    self._post("log", f"{config.rx}: not rebuilt, keeping the current correction: {one_line(exc)}")
                    pending = False
                    continue
                if pipeline is None:                          # stopped meanwhile
                    return
                info = {"what": what, "seconds": time.perf_counter() - t0, "gl_seconds": seconds,
                        "design_seconds": design_s, "cached_models": cached is not None and first,
                        "why": self.display_holder.get("why", ""), "stats": pipeline.loader.stats}
                if first:
                    source.check = pipeline.correctors[source.eyes[0]].check_eye   # later designs refused alike
                built, first, pending = pipeline, False, False
                self._post("pipeline", pipeline, info)
                t0 = time.perf_counter()
                continue
            self._wake.wait(0.25 if not pending else 0.05)
            self._wake.clear()
        del built

    def _build(self, models: dict[str, tuple[Any, Any]], targets: set[Target]) -> tuple["Pipeline | None", float]:
        """A pipeline for ``models`` warmed up for ``targets``, on a new context current on this thread
        only while it is built; ``None`` when the builder was stopped meanwhile."""

        t0 = time.perf_counter()
        engine = self.engine
        request = CaptureRequest()
        engine.capture = request                     # the next frame's views, taken while this builds
        if engine.api == "OpenGL":
            if engine.glx_binding is None:
                raise RuntimeError("the OpenGL session's GLX binding is unknown")
            ctx = glx_context(*engine.glx_binding, require=430, cache=engine.program_cache)
        else:
            ctx = egl_context(430, cache=engine.program_cache)
        pipeline = None
        handed = False
        try:
            if ctx.version_code < 430:
                raise ValidationError("OpenGL version", ctx.version_code, "4.3 or newer (compute shaders)")
            if engine.api == "Vulkan":
                MemoryObjects(ctx)                              # refuses a GL without GL_EXT_memory_object_fd now
            assert self.source is not None
            display = self.source.display
            correctors: dict[str, Corrector] = {}
            try:
                for eye, (model, prescription) in models.items():
                    if self._stopped:
                        break
                    correctors[eye] = Corrector(ctx, prescription, display, eye, eye_model=model,
                                                **self.config.corrector_options)
                    correctors[eye].keep_pupil_designs(engine.env)   # a second launch follows the light at once
            except Exception:
                for c in correctors.values():
                    c.release()
                raise
            pipeline = Pipeline(ctx, engine.api, correctors, display, self.config.rx)
            if engine.api == "Vulkan":
                pipeline.sync = engine.attach_semaphores(pipeline)
            steps = pipeline.steps
            steps["correctors"] = time.perf_counter() - t0
            copies = []
            if not self._stopped and request.ready.wait(CAPTURE_WAIT_S):
                copies = pipeline.copy_views(request.views, engine.chain_memory())
            steps["capture"] = time.perf_counter() - t0 - sum(steps.values())
            primed = {(c["code"], c["rect"][2], c["rect"][3]) for c in copies}
            if not self._stopped:
                pipeline.warm_up(targets - primed, stopped=lambda: self._stopped)
            steps["warm-up"] = time.perf_counter() - t0 - sum(steps.values())
            if not self._stopped and copies:
                try:
                    budget = prime_budget(engine.env)
                except ValidationError as exc:
                    budget = PRIME_BUDGET_S
                    self._post("log", f"{exc}; priming for {PRIME_BUDGET_S:g} s")
                pipeline.prime(copies, stopped=lambda: self._stopped, budget_s=budget, light_wait_s=LIGHT_WAIT_S)
            steps["priming"] = time.perf_counter() - t0 - sum(steps.values()) - pipeline.light_seconds
            if pipeline.light_seconds:
                steps["the light's design"] = pipeline.light_seconds
            if self._stopped:
                return None, 0.0
            handed = True
            return pipeline, time.perf_counter() - t0
        finally:
            if engine.capture is request:
                engine.capture = None
            if handed:
                ctx.extra.__exit__(None, None, None)       # current nowhere until the application's thread takes it
            elif pipeline is not None:
                pipeline.release()                         # released on this thread, where it is current
            else:
                ctx.release()
