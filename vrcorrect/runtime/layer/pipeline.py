"""The OpenXR API layer's pipeline: both eyes' Correctors and the copy passes around them
(``shaders/layer_copy.glsl``: decode the submitted rect, encode into the output image) on a GL
context of the pipeline's own, warmed up and primed before it is handed to the frames.

The correction is the project's :class:`~vrcorrect.runtime.corrector.Corrector`, one per view
(view 0 the left eye, view 1 the right, as in ``XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO``), built
from the user's prescription JSON and display profile.  Around it, two passes of
``shaders/layer_copy.glsl``:

* *decode*: the submitted rect, texel for texel, into a layer-owned staging texture: sRGB code
  values (RGBA8) for an 8-bit swapchain, which the Corrector decodes itself (for an sRGB swapchain
  exactly the application's codes; an 8-bit UNORM swapchain holds linear light, encoded here), or
  linear light clamped to [0, 1] (RGBA32F) for a 10-bit or half-float swapchain;
* *encode*: the Corrector's sRGB-encoded result into the output image's rect in the swapchain's own
  encoding: the code values as they are for an sRGB swapchain, linear light otherwise, with the
  application's alpha.  **Values outside [0, 1]** (a float swapchain holds linear light, which an
  engine rendering in HDR lets exceed 1): the correction works on the part in [0, 1], what the
  display shows up to its white; the rest of each value (``v - clamp(v, 0, 1)``) is carried through
  uncorrected and added back, so nothing the application rendered is lost or clipped.  The engine
  says so in the log the first time it corrects such a swapchain.

*OpenGL sessions*: the engine runs on the application's GL context (current at ``xrEndFrame``),
through a moderngl context attached to it; the application's textures are only sampled, through a
sampler object of the layer's (their parameters are never set); the shim saves and restores the GL
state around.  Formats: ``GL_RGBA16F``, ``GL_RGB10_A2``, ``GL_SRGB8_ALPHA8``, ``GL_RGBA8``.

*Vulkan sessions*: a Vulkan application has no GL context, so the engine makes its own (headless
EGL, Mesa's llvmpipe here) and makes it current only inside its calls.  The shim copies the submitted
rects on the application's queue into Vulkan images of its own whose memory the engine imports
(:meth:`Engine.import_images`, ``GL_EXT_memory_object_fd`` through ctypes: moderngl has no wrapper),
the engine corrects from there into a second shared image, and the shim copies that into the
output image.  32-bit formats are imported as ``GL_R32UI`` and (un)packed in the shader
(``R8G8B8A8``/``B8G8R8A8``, sRGB or not, ``A2B10G10R10``), the half-float one as ``GL_RGBA16F``.  A
Vulkan image's first row is its top row: the passes flip the rect into GL's orientation and back.

The eye models (:func:`~vrcorrect.runtime.eye_model.build_eye_model`: PSFs, kernels, filter design;
seconds of CPU) come from an :class:`~vrcorrect.runtime.eye_source.EyeSource`, the one the mirror,
the overlay and ``vrcorrect xr`` use, never from ``xrEndFrame``: the engine reads the prescription
(a small file) and asks for both eyes (:meth:`~vrcorrect.runtime.eye_source.EyeSource.design_all`);
the source's worker chooses the display and designs them while frames pass through (one log line,
"building the eye models ..."), and on the first frame after the design the two Correctors are made
on the application's thread from the models (GL resources only).  Hot reload is the source's too:
it watches the prescription file's stamp, the engine keeps correcting with the current Correctors
while the new models design, then installs them
(:meth:`~vrcorrect.runtime.corrector.Corrector.install`, GL work only); an invalid new file keeps
the last good prescription (one log line).  An invalid first prescription passes the frames
through with its reason until the file changes; a new configuration gets a new source.  Designs
run one at a time; of edits made meanwhile only the newest is designed.  (The shim releases the
GIL between its calls, so the worker runs.)

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from ..gl import fullscreen_triangle, release
from ..shaders import compile_program

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ...specs.display import DisplayProfile
    from ..corrector import Corrector
import moderngl

from ..strategies.admm import EARLY_STOP_TOLERANCE
from .config import PRIME_BUDGET_S, PRIME_MAX_FRAMES
from .interop import (
    _ENCODINGS,
    _GL_FRAMEBUFFER_SRGB,
    _GL_R32UI,
    _GL_RGBA16F,
    _GL_TEXTURE_2D,
    _PACKINGS,
    GL_FORMATS,
    VK_FORMATS,
    ChainMemory,
    MemoryObjects,
    Semaphores,
    SwapchainFormat,
    Target,
    _set_uniforms,
    _SharedChain,
    _wait_sync,
)

__all__ = ["Pipeline"]


class Pipeline:
    """Everything the engine corrects with, in a GL context of its own: the two Correctors, the passes
    of ``shaders/layer_copy.glsl``, the staging textures, and what it made of the application's
    images (OpenGL: wrappers of its textures; Vulkan: the imported shared images).  Built and warmed
    up on the build worker (:class:`Builder`: every program compiled and run once for each
    :data:`Target`, then each Corrector reset, so that its first frame is a cold start as a fresh
    Corrector's is), then used on the application's thread only."""

    def __init__(self, ctx: "moderngl.Context", api: str, correctors: "dict[str, Corrector]",
                 display: "DisplayProfile", rx: Path):

        self.ctx, self.api, self.correctors, self.display, self.rx = ctx, api, correctors, display, rx
        self.targets: set[Target] = set()
        self.steps: dict[str, float] = {}                 # seconds of each step of its build
        self.primed_frames: dict[str, int] = {}           # frames each eye was primed for
        self.prime_converged: dict[str, bool] = {}        # whether its priming converged
        self.light_pupils: dict[str, float] = {}          # the light's design in use after priming
        self.light_seconds = 0.0                          # spent waiting for those designs
        self.formats = GL_FORMATS if api == "OpenGL" else VK_FORMATS
        self._external: dict[tuple[int, int, int], moderngl.Texture] = {}    # the application's textures (OpenGL)
        self._staging: dict[tuple[int, int, str], moderngl.Texture] = {}
        self._framebuffers: dict[int, moderngl.Framebuffer] = {}             # by the texture's GL name
        self._programs: dict[tuple[str, bool], tuple[moderngl.Program, moderngl.VertexArray]] = {}
        self._sampler = ctx.sampler(filter=(moderngl.NEAREST, moderngl.NEAREST), repeat_x=False, repeat_y=False)
        self._memory: MemoryObjects | None = None
        self.chains: dict[int, _SharedChain] = {}
        self.semaphores: Semaphores | None = None       # Vulkan: external semaphores, where GL has them
        self.sync = ""                                    # Vulkan: how it is ordered with the copies (for the log)
        self._queries: dict[str, list[moderngl.Query]] = {}
        self._query_used: dict[str, list[bool]] = {}

    @property
    def loader(self) -> Any:
        """The context's :class:`~vrcorrect.runtime.glcache.CachingLoader`."""
        return self.ctx.extra

    # ------------------------------------------------------------ the build worker's part

    def warm_up(self, targets: set[Target], stopped: Any = lambda: False) -> None:
        """Run every pass once for each target, on private textures of the target's format and size:
        a cold frame, then a warm one on other content (the early stop's comparison and plan); then
        each Corrector starts cold again.  ``stopped()`` True ends it early."""
        rng = np.random.default_rng(46)
        for code, width, height in sorted(targets - self.targets):
            if stopped():
                return
            fmt = self.formats[code]
            src, dst = (self._private_texture(code, fmt, width, height) for _ in range(2))
            try:
                for eye in self.correctors:
                    for _ in range(2):
                        src.write(self._content(rng, src))
                        self.correct_rect(eye, fmt, src, dst, (0, 0, width, height), flip=self.api == "Vulkan")
                    self.correctors[eye].reset()
            finally:
                for texture in (src, dst):
                    release(self._framebuffers.pop(texture.glo, None))
                    texture.release()
            self.targets.add((code, width, height))
        self.ctx.finish()

    def copy_views(self, views: list[dict[str, Any]], chains: Mapping[int, ChainMemory]) -> list[dict[str, Any]]:
        """The captured views' rects copied into textures of this context (OpenGL: from the
        application's texture once its fence has passed; Vulkan: from the shared ``input`` image,
        imported here), one per eye: what :meth:`prime` corrects."""
        copy = ctypes.CFUNCTYPE(None, *([ctypes.c_uint, ctypes.c_uint] + [ctypes.c_int] * 4) * 2,
                                ctypes.c_int, ctypes.c_int, ctypes.c_int)(self.loader._address("glCopyImageSubData"))
        out = []
        seen = set()
        for view in views:
            if view["eye"] in seen or view["eye"] not in self.correctors:
                continue
            seen.add(view["eye"])
            x, y, width, height = view["rect"]
            fmt = self.formats[view["code"]]
            if self.api == "OpenGL":
                _wait_sync(self.loader, view["fence"])
                source = int(view["texture"])
            else:
                memory = chains.get(view["chain"])
                try:
                    if memory is not None and view["chain"] not in self.chains:
                        self.import_chain(view["chain"], memory)
                except OSError:                  # the swapchain went away meanwhile: this view is not primed
                    memory = None
                if memory is None or view["chain"] not in self.chains:
                    continue
                source = self.chains[view["chain"]].input.glo
            texture = self._private_texture(view["code"], fmt, width, height)
            copy(source, _GL_TEXTURE_2D, 0, x, y, 0, texture.glo, _GL_TEXTURE_2D, 0, 0, 0, 0, width, height, 1)
            out.append({"eye": view["eye"], "code": view["code"], "format": fmt, "texture": texture,
                        "rect": (0, 0, width, height)})
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            for c in out:
                c["texture"].release()
            raise RuntimeError(f"a GL error ({error}) copying the captured views")
        return out

    def prime(self, copies: list[dict[str, Any]], stopped: Any = lambda: False,
              budget_s: float = PRIME_BUDGET_S, light_wait_s: float = 0.0) -> None:
        """Correct each eye's captured view as frames would, from a cold start until the early stop
        would skip the next frame of the same content (the last two frames' objectives agree to its
        tolerance), so that the application's first corrected frames are already converged, or until
        the eye's share of ``budget_s`` is spent (then the application's frames go on from there);
        the Correctors keep that state (a fresh Corrector given the same number of frames reaches the
        same one).  :attr:`primed_frames` counts each eye's frames, :attr:`prime_converged` says
        whether they converged.

        With ``light_wait_s`` (``pupil="auto"``), after each eye's first frame the eye switches to the
        design for that frame's light (:meth:`~vrcorrect.runtime.corrector.Corrector.follow_light_now`:
        from the bank's worker or the design cache, waiting at most ``light_wait_s``), so that the
        application's first corrected frames are not a mid-grey frame's design switched seconds later;
        that wait is not counted in the budget (:attr:`light_pupils`: the light's design in use after
        priming; :attr:`light_seconds`)."""

        share = budget_s / max(len(copies), 1)
        for c in copies:
            x, y, width, height = c["rect"]
            scratch = self._private_texture(c["code"], c["format"], width, height)
            deadline = time.perf_counter() + share
            self.prime_converged[c["eye"]] = False
            try:
                corrector = self.correctors[c["eye"]]
                previous = None
                for n in range(PRIME_MAX_FRAMES):
                    if stopped():
                        return
                    if n > 0 and time.perf_counter() >= deadline:
                        break
                    self.primed_frames[c["eye"]] = n + 1
                    self.correct_rect(c["eye"], c["format"], c["texture"], scratch, c["rect"],
                                      flip=self.api == "Vulkan")
                    if n == 0 and light_wait_s > 0:
                        t0, before = time.perf_counter(), corrector.model
                        pupil = corrector.follow_light_now(light_wait_s, stopped)
                        waited = time.perf_counter() - t0
                        self.light_seconds += waited
                        deadline += waited
                        if pupil is not None:
                            self.light_pupils[c["eye"]] = pupil
                        if corrector.model is not before:
                            continue                           # converge on the new design
                    fraction = corrector.last_objective_fraction((width, height))
                    if fraction is None:                       # no guard: nothing to converge on
                        self.prime_converged[c["eye"]] = True
                        break
                    if previous is not None and abs(fraction - previous) <= EARLY_STOP_TOLERANCE * max(previous, 1e-30):
                        self.prime_converged[c["eye"]] = True
                        break
                    previous = fraction
                self.targets.add((c["code"], width, height))
            finally:
                for texture in (c["texture"], scratch):
                    release(self._framebuffers.pop(texture.glo, None))
                    texture.release()
        self.ctx.finish()

    def longest_calls(self) -> str:
        """Each eye's longest pass call in its last correction (:attr:`Gpu.longest
        <vrcorrect.runtime.dispatch.Gpu.longest>`), in words."""
        return "; ".join(f"{eye} {c.gpu.longest[1] or '-'} {c.gpu.longest[0]:.0f} ms"
                         for eye, c in sorted(self.correctors.items()))

    def _private_texture(self, code: int, fmt: SwapchainFormat, width: int, height: int) -> "moderngl.Texture":
        """A texture of the engine's own as the application's images are stored (OpenGL: the swapchain's
        internal format; Vulkan: the shared images' R32UI or RGBA16F)."""
        if self.api == "Vulkan":
            return (self.ctx.texture((width, height), 1, dtype="u4") if fmt.packing is not None
                    else self.ctx.texture((width, height), 4, dtype="f2"))
        return self.ctx.texture((width, height), 4, dtype="f2" if fmt.encoding == "float" else "f1",
                                internal_format=code)

    @staticmethod
    def _content(rng: np.random.Generator, texture: "moderngl.Texture") -> bytes:
        w, h = texture.size
        if texture.dtype == "f2":
            return rng.random((h, w, 4)).astype(np.float16).tobytes()
        if texture.dtype == "u4":
            return rng.integers(0, 2 ** 32, (h, w), dtype=np.uint32).tobytes()
        return rng.integers(0, 256, (h, w, 4), dtype=np.uint8).tobytes()

    # ------------------------------------------------------------ frames (the application's thread)

    def correct_rect(self, eye: str, fmt: SwapchainFormat, src: "moderngl.Texture", dst: "moderngl.Texture",
                     rect: tuple[int, int, int, int], flip: bool, query: "moderngl.Query | None" = None) -> float:
        """Decode the rect of ``src`` into staging, correct it for ``eye``, encode the result into the
        rect of ``dst`` (module docstring); returns the CPU ms of the correction."""
        x, y, width, height = rect
        packed = fmt.packing is not None
        common = {"u_packing": _PACKINGS.get(fmt.packing or "", 0), "u_encoding": _ENCODINGS[fmt.encoding],
                  "u_offset": (x, y), "u_height": height, "u_flip": flip}
        staging = self._stage_texture(width, height, "f1" if fmt.stage_codes else "f4")
        result = self._stage_texture(width, height, "result")
        self._draw("DECODE", packed, {**common, "u_source": 0, "u_stage_codes": fmt.stage_codes}, [src], staging,
                   (0, 0, width, height))
        t0 = time.perf_counter()
        with query if query is not None else contextlib.nullcontext():
            self.correctors[eye].apply(staging, self._framebuffer(result))
        self._draw("ENCODE", packed, {**common, "u_source": 0, "u_result": 1, "u_carry": fmt.encoding == "float"},
                   [src, result], dst, rect)
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            raise RuntimeError(f"a GL error ({error}) during the correction")
        return 1e3 * (time.perf_counter() - t0)

    def application_texture(self, name: int, width: int, height: int, fmt: SwapchainFormat) -> "moderngl.Texture":
        """OpenGL: an application's texture (a swapchain image: shared with this context) as this
        context's moderngl texture (a wrapper: nothing is made or deleted)."""
        key = (int(name), width, height)
        tex = self._external.get(key)
        if tex is None:
            tex = self.ctx.external_texture(int(name), (width, height), 4, 0, "f2" if fmt.encoding == "float" else "f1")
            self._external[key] = tex
        return tex

    def forget_textures(self, names: list[int]) -> None:
        """OpenGL: a swapchain goes away: the wrappers and framebuffers made for its textures."""
        for name in names:
            for key in [k for k in self._external if k[0] == name]:
                del self._external[key]
            release(self._framebuffers.pop(name, None))

    def import_chain(self, chain: int, memory: ChainMemory) -> None:
        """Vulkan: import duplicates of a swapchain's shared images into this context."""
        if self._memory is None:
            self._memory = MemoryObjects(self.ctx)
        packed = memory.format.packing is not None
        internal, components, dtype = (_GL_R32UI, 1, "u4") if packed else (_GL_RGBA16F, 4, "f2")
        names: list[tuple[int, int]] = []
        textures = []
        try:
            for fd, size in zip(memory.fds, memory.sizes):
                names.append(self._memory.texture(os.dup(fd), size, memory.width, memory.height, internal))
                textures.append(self.ctx.external_texture(names[-1][0], (memory.width, memory.height), components, 0,
                                                          dtype))
        except Exception:
            for texture, memory_object in names:
                self._memory.free(texture, memory_object)
            raise
        self.release_chain(chain)
        self.chains[chain] = _SharedChain(memory.format, textures[0], textures[1], tuple(names))

    def release_chain(self, chain: int) -> None:
        shared = self.chains.pop(chain, None)
        if shared is None:
            return
        for texture in (shared.input, shared.result):
            release(self._framebuffers.pop(texture.glo, None))
            texture.release()                         # an external texture: moderngl forgets it, deletes nothing
        if self._memory is not None:
            for texture_name, memory_object in shared.names:
                self._memory.free(texture_name, memory_object)

    def query(self, eye: str, frame: int) -> tuple["moderngl.Query", float | None | bool]:
        """This frame's timer query for ``eye``, and the slot's previous result (two frames ago) in ms:
        ``None`` when it saturated (a 32-bit nanosecond count ends at 4.29 s), ``False`` when unused."""
        ring = self._queries.get(eye)
        if ring is None:
            ring = self._queries[eye] = [self.ctx.query(time=True), self.ctx.query(time=True)]
            self._query_used[eye] = [False, False]
        slot = frame % 2
        previous: float | None | bool = False
        if self._query_used[eye][slot]:
            ns = ring[slot].elapsed
            previous = None if ns >= 0xFFFFFFFF else ns / 1e6
        self._query_used[eye][slot] = True
        return ring[slot], previous

    # ------------------------------------------------------------ GL objects

    def _program(self, stage: str, packed: bool) -> tuple["moderngl.Program", "moderngl.VertexArray"]:
        key = (stage, packed)
        if key not in self._programs:
            defines: dict[str, None] = {stage: None}
            if packed:
                defines["PACKED"] = None
            program = compile_program(self.ctx, "layer_copy.glsl", defines=defines)
            self._programs[key] = (program, fullscreen_triangle(self.ctx, program))
        return self._programs[key]

    def _draw(self, stage: str, packed: bool, uniforms: Mapping[str, Any], textures: list["moderngl.Texture"],
              target: "moderngl.Texture", viewport: tuple[int, int, int, int]) -> None:
        """One pass of ``layer_copy.glsl`` into ``target`` over ``viewport``, ``textures`` on units 0, 1, ...
        read through the layer's nearest-texel sampler (a texture's own parameters are never set: it
        may be the application's), which is unbound again after the pass (the Corrector's passes
        sample with their textures' own parameters)."""
        ctx = self.ctx
        ctx.disable_direct(_GL_FRAMEBUFFER_SRGB)
        program, vao = self._program(stage, packed)
        _set_uniforms(program, uniforms)
        for unit, texture in enumerate(textures):
            texture.use(unit)
            self._sampler.use(unit)
        fb = self._framebuffer(target)
        fb.use()
        ctx.viewport = viewport
        vao.render(mode=ctx.TRIANGLES, vertices=3)
        for unit in range(len(textures)):
            self._sampler.clear(unit)

    def _stage_texture(self, width: int, height: int, kind: str) -> "moderngl.Texture":
        """The layer's own textures: ``"f1"``/``"f4"`` staging (the Corrector's input), ``"result"``
        (RGBA8: the Corrector's sRGB-encoded output)."""
        key = (width, height, kind)
        tex = self._staging.get(key)
        if tex is None:
            tex = self.ctx.texture((width, height), 4, dtype="f1" if kind == "result" else kind)
            self._staging[key] = tex
        return tex

    def _framebuffer(self, texture: "moderngl.Texture") -> "moderngl.Framebuffer":
        fb = self._framebuffers.get(texture.glo)
        if fb is None:
            fb = self.ctx.framebuffer(color_attachments=[texture])
            self._framebuffers[texture.glo] = fb
        return fb

    def release(self) -> None:
        """Release every GL object and the context itself (the context must be current on the calling
        thread; it is not current anywhere afterwards)."""
        try:
            for chain in list(self.chains):
                self.release_chain(chain)
            if self.semaphores is not None:
                self.semaphores.release()
                self.semaphores = None
            for c in self.correctors.values():
                c.release()
            release(*self._framebuffers.values())       # never the application's textures themselves
            release(*self._staging.values(), *(o for pair in self._programs.values() for o in reversed(pair)),
                    self._sampler)                       # (moderngl's queries go with the context)
        finally:
            self.correctors = {}
            self._framebuffers.clear()
            self._staging.clear()
            self._external.clear()
            self._programs.clear()
            self._queries.clear()
            try:
                self.ctx.release()                       # the engine's own context (its loader destroys it)
            except Exception:  # noqa: BLE001
                pass
