"""Every GPU pass of the correction goes through :class:`Gpu`, which binds its resources and counts
the bytes it moves, so the cost of a frame is counted from the code that runs it.

A pass names what it touches when it is dispatched: textures it samples, image units it reads,
writes or both, storage buffers.  :meth:`Gpu.run` binds exactly those (a pass cannot bind a
resource without it being counted), runs the compute program, puts the memory barrier after it and,
when a :class:`CostLedger` is attached, records a :class:`PassRecord`: its name, work groups and
bytes read and written.  :meth:`Gpu.draw` does the same for a fragment pass into a framebuffer and
:meth:`Gpu.transfer` for a read-back or upload (the ONNX backend).

The byte model is the one bandwidth-bound GPU code is judged by: each texel of a resource a pass
reads is read once, each texel it writes is written once, a read-write binding counts both, at the
texture's stored size (components times bytes per component: an ``rgba16f`` texel is 8 bytes, an
``rg32f`` one 8).  Caches that let a pass read a texel twice for the price of once are not
modelled, nor are the misses that make it cost more; where a pass touches only part of a resource
(the rows of a grid that hold the image), it says so with ``rows`` and is counted for those.  A
pass marked ``round_trip`` is the spectral product of one FFT round trip (forward transform,
product, inverse transform): the ledger counts round trips from those marks.

Layer 5: moderngl objects, no numpy arithmetic; never torch.
"""

from __future__ import annotations

import time

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence, Union

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["PassRecord", "CostLedger", "Gpu", "texel_bytes", "resource_bytes", "BANDWIDTHS", "project_ms"]

_COMPONENT_BYTES = {"f1": 1, "u1": 1, "i1": 1, "f2": 2, "u2": 2, "i2": 2, "f4": 4, "u4": 4, "i4": 4}

Texture = Union["moderngl.Texture", "moderngl.TextureArray"]


def texel_bytes(texture: Texture) -> int:
    """Bytes of one texel as stored: components times the bytes of a component."""
    return int(texture.components) * _COMPONENT_BYTES[texture.dtype]


Part = Union[int, tuple[int, int]]
"""The part of a texture a pass touches: that many rows of each layer, or (rows, layers)."""


def resource_bytes(resource: Any, part: Part | None = None) -> int:
    """Bytes of a texture, a texture array (every layer) or a buffer; ``part``: only that many rows
    of each layer, or ``(rows, layers)``."""
    if hasattr(resource, "components"):
        size = tuple(resource.size)
        width, height = size[0], size[1]
        layers = size[2] if len(size) > 2 else 1
        rows = height
        if part is not None:
            rows, layers = (part, layers) if isinstance(part, int) else part
        return width * min(rows, height) * min(layers, size[2] if len(size) > 2 else 1) * texel_bytes(resource)
    return int(resource.size)                            # a buffer


@dataclass(frozen=True)
class PassRecord:
    """One pass as it ran: its name, the stage of the frame it belongs to, its work groups (``()``
    for a draw or a transfer) and the bytes it read and wrote."""

    name: str
    stage: str
    groups: tuple[int, ...]
    bytes_read: int
    bytes_written: int
    round_trip: bool = False
    kind: str = "compute"                                # compute, draw, transfer or skipped

    @property
    def bytes(self) -> int:
        return self.bytes_read + self.bytes_written


@dataclass
class CostLedger:
    """The passes recorded while attached to a :class:`Gpu` (``records``), with their totals."""

    records: list[PassRecord] = field(default_factory=list)

    def clear(self) -> None:
        self.records.clear()

    @property
    def dispatches(self) -> int:
        """Compute dispatches and draws that did work (not transfers, nor indirect dispatches the
        GPU gave no work groups)."""
        return sum(r.kind in ("compute", "draw") for r in self.records)

    @property
    def fft_round_trips(self) -> int:
        return sum(r.round_trip for r in self.records)

    @property
    def bytes_read(self) -> int:
        return sum(r.bytes_read for r in self.records)

    @property
    def bytes_written(self) -> int:
        return sum(r.bytes_written for r in self.records)

    @property
    def bytes(self) -> int:
        return self.bytes_read + self.bytes_written

    def by_stage(self) -> dict[str, dict[str, int]]:
        """``{stage: {"dispatches", "round_trips", "bytes"}}`` in the order the stages ran."""
        out: dict[str, dict[str, int]] = {}
        for r in self.records:
            s = out.setdefault(r.stage, {"dispatches": 0, "round_trips": 0, "bytes": 0})
            s["dispatches"] += r.kind in ("compute", "draw")
            s["round_trips"] += r.round_trip
            s["bytes"] += r.bytes
        return out

    def summary(self) -> dict[str, Any]:
        return {"dispatches": self.dispatches, "fft_round_trips": self.fft_round_trips, "bytes": self.bytes,
                "bytes_read": self.bytes_read, "bytes_written": self.bytes_written, "stages": self.by_stage()}


BANDWIDTHS: dict[str, tuple[float, str]] = {
    "RTX 3060": (360e9, "NVIDIA GeForce RTX 3060 12 GB: 192-bit GDDR6 at 15 Gbps, 360 GB/s (NVIDIA's specification)"),
    "RTX 4090": (1008e9, "NVIDIA GeForce RTX 4090: 384-bit GDDR6X at 21 Gbps, 1008 GB/s (NVIDIA's specification)"),
    "H100 SXM": (3.35e12, "NVIDIA H100 SXM5 80 GB: HBM3, 3.35 TB/s (NVIDIA's H100 datasheet)"),
}
"""Published peak memory bandwidth of the GPUs a frame's cost is projected on (bytes per second,
and where the figure comes from)."""


def project_ms(bytes_moved: int, bandwidth: float) -> float:
    """Milliseconds to move ``bytes_moved`` at ``bandwidth`` bytes per second: a projection for a
    bandwidth-bound frame at the GPU's peak (real code reaches some fraction of it), not a
    measurement."""
    return 1e3 * bytes_moved / bandwidth


class Gpu:
    """Runs the correction's passes on ``ctx`` and counts them into :attr:`ledger` (when set).

    :attr:`stage` names the part of the frame the following passes belong to; :meth:`begin` starts
    the next one (``decode``, ``start``, ``iterations``, ``guard``, ``present``, ...) and first calls
    :attr:`profile`, when set, with the name of the stage whose work has just been issued (a
    benchmark's hook calls ``ctx.finish()`` there and reads the clock)."""

    def __init__(self, ctx: "moderngl.Context", ledger: CostLedger | None = None):
        self.ctx = ctx
        self.ledger = ledger
        self.stage = ""
        self.profile: Callable[[str], None] | None = None
        self.dry_run = False
        """Bind and count every pass but run none (``vrcorrect bench cost --dry-run``: a frame's
        count in seconds on a software renderer; what the frame computes is then meaningless)."""
        self.dry_run_idle = False
        """With :attr:`dry_run`: count indirect dispatches as given no work groups (what the early
        stop's plan decides on a still, converged view)."""
        self.pass_times: dict[str, list[float]] | None = None
        """When a dict: every pass runs between two ``glFinish`` calls and its wall time in ms is
        appended under its name (``vrcorrect bench cost --frames``: where a frame's time goes; the
        waits make the frame itself slower, so never while timing whole frames)."""
        self.longest: tuple[float, str] = (0.0, "")
        """The longest call of a pass since it was last set to ``(0.0, "")`` (:meth:`Corrector.apply
        <vrcorrect.runtime.corrector.Corrector.apply>` does at each frame's start): (ms, pass name).
        On a real GPU a call only queues its work; a software renderer (llvmpipe) compiles and runs it
        inside the call, so there it names where a slow frame's time went (the layer's stall trace)."""

    def begin(self, stage: str) -> None:
        """The passes that follow belong to ``stage``; the stage before it is over."""
        if self.profile is not None and self.stage:
            self.profile(self.stage)
        self.stage = stage

    def end(self) -> None:
        """The frame's last stage is over."""
        self.begin("")

    def _pass_start(self) -> float:
        """The clock before a pass's call (with :attr:`pass_times` set, after waiting for the GPU)."""
        if self.pass_times is not None:
            self.ctx.finish()
        return time.perf_counter()

    def _pass_end(self, name: str, t0: float) -> None:
        """After a pass's call: :attr:`longest`; with :attr:`pass_times` set, wait for the pass and
        record its time."""
        if self.pass_times is not None:
            self.ctx.finish()
        ms = 1e3 * (time.perf_counter() - t0)
        if self.pass_times is not None:
            self.pass_times.setdefault(name, []).append(ms)
        if ms > self.longest[0]:
            self.longest = (ms, name)

    def _count(self, name: str, groups: tuple[int, ...], read: int, written: int, round_trip: bool,
               kind: str) -> None:
        if self.ledger is not None:
            self.ledger.records.append(PassRecord(name, self.stage, groups, read, written, round_trip, kind))

    def run(self, name: str, program: "moderngl.ComputeShader", groups: Sequence[int], *,
            sample: Mapping[str, Texture] | None = None,
            read: Mapping[int, Texture] | None = None,
            write: Mapping[int, Texture] | None = None,
            modify: Mapping[int, Texture] | None = None,
            buffers: Mapping[int, tuple["moderngl.Buffer", str]] | None = None,
            uniforms: Mapping[str, Any] | None = None,
            rows: Mapping[str | int, Part] | None = None,
            written: Mapping[int, Part] | None = None,
            round_trip: bool = False,
            indirect: tuple["moderngl.Buffer", int] | None = None,
            idle: Mapping[str | int, Texture] | None = None) -> None:
        """Bind and run one compute pass, then a memory barrier.

        ``sample``: uniform name -> texture (sampled, read; texture units 0, 1, ... in order);
        ``read`` / ``write`` / ``modify``: image unit -> texture bound read-only, write-only or
        read-write (every layer of an array); ``buffers``: storage-buffer binding -> (buffer,
        ``"r"``, ``"w"`` or ``"rw"``); ``uniforms``: set when the program has them; ``rows``: a
        sampled texture's uniform name or an image unit -> the part of it the pass touches, rows of
        each layer or ``(rows, layers)`` (default: all; for a ``modify`` binding, the part read);
        ``written``: a ``modify`` binding's unit -> the part written, where it differs from the part
        read; ``round_trip``: this pass is the spectral product of an FFT round trip; ``indirect``:
        (buffer, byte offset) of the work groups, which a pass on the GPU wrote (``groups`` is then
        what it writes when the pass runs): with a ledger attached they are read back (a wait for
        the GPU, so only when counting) and a pass given no work groups is counted as nothing.
        ``idle``: samplers (by uniform name, on the texture units after ``sample``'s) and read-only
        images (by unit) the program declares but this pass does not read, bound anyway so that every
        run of the program sees the same formats there: a driver may compile a variant of the program
        for each set of formats bound (Mesa's llvmpipe does: about a second for the ADMM's start pass
        at 96x64); not counted."""
        partial = rows or {}
        nread = nwritten = 0
        for unit, (uniform, texture) in enumerate((sample or {}).items()):
            texture.use(unit)
            program[uniform] = unit
            nread += resource_bytes(texture, partial.get(uniform))
        unit = len(sample or {})
        for key, texture in (idle or {}).items():
            if isinstance(key, str):
                texture.use(unit)
                program[key] = unit
                unit += 1
            else:
                texture.bind_to_image(key, read=True, write=False)
        for access, binds in (("r", read), ("w", write), ("rw", modify)):
            for binding, texture in (binds or {}).items():
                texture.bind_to_image(binding, read="r" in access, write="w" in access)
                n = resource_bytes(texture, partial.get(binding))
                nread += n if "r" in access else 0
                if "w" in access:
                    nwritten += resource_bytes(texture, (written or {})[binding]) if access == "rw" and \
                        binding in (written or {}) else n
        for binding, (buffer, access) in (buffers or {}).items():
            buffer.bind_to_storage_buffer(binding)
            nread += buffer.size if "r" in access else 0
            nwritten += buffer.size if "w" in access else 0
        for key, value in (uniforms or {}).items():
            if key in program:
                program[key] = value
        if not self.dry_run:
            t0 = self._pass_start()
            if indirect is not None:
                program.run_indirect(indirect[0], indirect[1])
            else:
                program.run(*groups)
            self.ctx.memory_barrier()
            self._pass_end(name, t0)
        if indirect is not None and self.ledger is not None and (not self.dry_run or self.dry_run_idle):
            args = (0, 1, 1) if self.dry_run else \
                tuple(int(v) for v in memoryview(indirect[0].read(12, offset=indirect[1])).cast("I"))
            if 0 in args:                                  # the GPU gave it no work: it did nothing
                self._count(name + " (skipped)", args, 0, 0, False, "skipped")
                return
        self._count(name, tuple(int(g) for g in groups), nread, nwritten, round_trip, "compute")

    def draw(self, name: str, vao: "moderngl.VertexArray", program: "moderngl.Program",
             framebuffer: "moderngl.Framebuffer", viewport: tuple[int, int, int, int], *,
             sample: Mapping[str, Texture] | None = None, uniforms: Mapping[str, Any] | None = None,
             buffers: Mapping[int, "moderngl.Buffer"] | None = None, rows: Mapping[str, Part] | None = None) -> None:
        """A full-screen fragment pass: sample ``sample`` (``rows`` as for :meth:`run`), read the
        storage ``buffers``, and write ``framebuffer`` in ``viewport`` (counted as the viewport's
        pixels at the first colour attachment's texel size)."""
        nread = 0
        for unit, (uniform, texture) in enumerate((sample or {}).items()):
            texture.use(unit)
            program[uniform] = unit
            nread += resource_bytes(texture, (rows or {}).get(uniform))
        for binding, buffer in (buffers or {}).items():
            buffer.bind_to_storage_buffer(binding)
            nread += buffer.size
        for key, value in (uniforms or {}).items():
            if key in program:
                program[key] = value
        framebuffer.use()
        framebuffer.viewport = viewport
        if not self.dry_run:
            t0 = self._pass_start()
            vao.render(mode=self.ctx.TRIANGLES, vertices=3)
            self._pass_end(name, t0)
        attachments = framebuffer.color_attachments
        per_pixel = texel_bytes(attachments[0]) if attachments and hasattr(attachments[0], "dtype") else 4
        self._count(name, (), nread, viewport[2] * viewport[3] * per_pixel, False, "draw")

    def transfer(self, name: str, read: int = 0, written: int = 0) -> None:
        """Bytes a read-back (``read`` from GPU memory) or upload (``written``) moved."""
        self._count(name, (), int(read), int(written), False, "transfer")
