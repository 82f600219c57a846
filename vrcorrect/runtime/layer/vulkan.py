"""The Vulkan side of the OpenXR API layer's engine (:class:`VulkanFrames`, a part of
:class:`~vrcorrect.runtime.layer.engine.Engine`): the application's images and semaphores imported
into GL, a view corrected from an imported image, and the frame's end signalled back to Vulkan.

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

import os

from ...plumbing.errors import ValidationError
from .config import eye_of_view, one_line
from .interop import VK_FORMATS, ChainMemory, Semaphores, check_rect, flush_gl
from .pipeline import Pipeline

__all__ = ["VulkanFrames"]


class VulkanFrames:
    """The Vulkan half of the :class:`~vrcorrect.runtime.layer.engine.Engine`'s frame protocol (the
    engine's own state: the C shim calls these on the engine)."""

    def import_semaphores(self, ready_fd: int, done_fd: int) -> bool:
        """Vulkan: the shim's two external semaphores as file descriptors (the engine's to close), or -1
        when the device has no ``VK_KHR_external_semaphore_fd``; each pipeline imports duplicates where
        its GL has ``GL_EXT_semaphore_fd``."""
        if ready_fd < 0 or done_fd < 0:
            self._semaphore_note = "the Vulkan device has no VK_KHR_external_semaphore_fd"
            return False
        self._semaphore_fds = (int(ready_fd), int(done_fd))
        return True

    def attach_semaphores(self, pipeline: Pipeline) -> str:
        """(The builder, on the pipeline's context.)  Import the external semaphores into ``pipeline``
        where its GL can; returns how the pipeline is synchronised with the shim's copies."""
        if self._semaphore_fds is None:
            return f"a fence and glFinish ({self._semaphore_note})"
        missing = sorted({"GL_EXT_semaphore", "GL_EXT_semaphore_fd"} - set(pipeline.ctx.extensions))
        if missing:
            renderer = pipeline.ctx.info.get("GL_RENDERER", "?")
            return f"a fence and glFinish (the engine's GL, {renderer}, lacks {' and '.join(missing)})"
        pipeline.semaphores = Semaphores(pipeline.loader, self._semaphore_fds)
        return "external semaphores (VK_KHR_external_semaphore_fd, GL_EXT_semaphore_fd): no CPU wait"

    def drain(self) -> bool:
        """Vulkan, with semaphores: the frame failed after the shim's copy in signalled ``ready``: GL
        waits for it all the same (a binary semaphore is waited for before it is signalled again)."""
        try:
            p = self.pipeline
            if p is not None and p.semaphores is not None and not self._waited_ready:
                with self._current(p):
                    p.semaphores.wait_ready([c.input for c in p.chains.values()])
                self._waited_ready = True
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"waiting for the Vulkan copy: {one_line(exc)}")
            return False

    def chain_memory(self) -> dict[int, ChainMemory]:
        """The Vulkan swapchains' shared images now (any thread)."""
        return dict(self._chains)

    def capture_vulkan(self, view_index: int, chain: int, x: int, y: int, width: int, height: int,
                       view_in_layer: int = -1) -> bool:
        """Vulkan: hand the builder a view of this frame (its rect, copied by the shim into the chain's
        shared ``input`` image); the frame passes through."""
        try:
            eye = eye_of_view(view_in_layer if view_in_layer >= 0 else view_index)
            memory = self._chains.get(chain)
            if memory is None:
                return False
            check_rect(x, y, width, height, memory.width, memory.height)
            self._add_capture({"eye": eye, "code": memory.code, "chain": int(chain),
                               "rect": (int(x), int(y), int(width), int(height))})
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {one_line(exc)}")
            return False

    def import_images(self, chain: int, vk_format: int, width: int, height: int, input_fd: int, input_size: int,
                      result_fd: int, result_size: int) -> bool:
        """Vulkan: a swapchain's two shared images (their memory as file descriptors, which the engine
        takes over and keeps until :meth:`release_images`): every pipeline imports them (the current
        one now).  Returns False (with one log line) when it could not."""
        fds = (int(input_fd), int(result_fd))
        try:
            fmt = VK_FORMATS.get(vk_format)
            if fmt is None:
                raise ValidationError("swapchain format", hex(vk_format),
                                      ", ".join(f"{f.name} {hex(code)}" for code, f in VK_FORMATS.items()))
            self.release_images(chain)
            memory = ChainMemory(fmt, int(vk_format), int(width), int(height), fds, (int(input_size), int(result_size)))
            self._chains[chain] = memory
            fds = ()
            self._add_targets(("chain", chain), self._chain_targets(int(vk_format), int(width), int(height)))
            if self.pipeline is not None:
                with self._current(self.pipeline):
                    self.pipeline.import_chain(chain, memory)
            self.log.line(f"Vulkan swapchain {chain}: {fmt.name} {width}x{height}, shared with the engine's GL")
            return True
        except Exception as exc:  # noqa: BLE001
            for fd in fds:
                if fd >= 0:
                    os.close(fd)
            self.release_images(chain)
            self.log.reason(f"the Vulkan application's images cannot be shared with the engine's GL: {one_line(exc)}")
            return False

    def release_images(self, chain: int) -> None:
        """Vulkan: let go of a swapchain's shared images (before the shim frees their memory)."""
        memory = self._chains.pop(chain, None)
        with self._targets_lock:
            self._targets.pop(("chain", chain), None)
        try:
            if self.pipeline is not None and chain in self.pipeline.chains:
                with self._current(self.pipeline):
                    self.pipeline.release_chain(chain)
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"Vulkan swapchain {chain}: releasing its images: {one_line(exc)}")
        finally:
            if memory is not None:
                memory.close()

    def correct_vulkan(self, view_index: int, chain: int, x: int, y: int, width: int, height: int,
                       view_in_layer: int = -1) -> bool:
        """Vulkan: correct the rect (x, y, width, height; Vulkan pixels, origin at the top left) of
        swapchain ``chain``'s shared ``input`` image into the same rect of its ``result`` image."""
        try:
            view = view_in_layer if view_in_layer >= 0 else view_index
            eye = eye_of_view(view)
            memory = self._chains.get(chain)
            if memory is None:
                raise ValidationError("swapchain", chain, "one whose images the engine imported")
            check_rect(x, y, width, height, memory.width, memory.height)
            p = self.pipeline
            if p is None or not self._covered((memory.code, int(width), int(height))):
                return False
            shared = p.chains.get(chain)
            if shared is None:
                raise ValidationError("swapchain", chain, "one whose images the engine imported")
            self._announce(shared.format)
            if self.capture is not None and not self.capture.ready.is_set():    # a rebuild primes on this frame
                self.capture_vulkan(view_index, chain, x, y, width, height, view_in_layer)
            self._aim(p, eye, width, height)
            with self._current(p):
                if p.semaphores is not None and not self._waited_ready:       # the shim's copy in, on the GPU
                    p.semaphores.wait_ready([c.input for c in p.chains.values()])
                    self._waited_ready = True
                ms = p.correct_rect(eye, shared.format, shared.input, shared.result, (x, y, width, height), flip=True,
                                    query=self._timed(p, eye))
            self._cpu_ms.setdefault(eye, []).append(ms)
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {one_line(exc)}")
            return False

    def finish(self) -> bool:
        """Vulkan: the GL work of the frame done before the shim copies the results: signalled on the
        ``done`` semaphore (with semaphores), else waited for (``glFinish``)."""
        try:
            p = self.pipeline
            if p is None:
                raise RuntimeError("no correction is ready")
            with self._current(p) as ctx:
                if p.semaphores is not None:
                    p.semaphores.signal_done([c.result for c in p.chains.values()])
                    flush_gl(p.loader)
                else:
                    ctx.finish()
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"glFinish: {one_line(exc)}")
            return False
