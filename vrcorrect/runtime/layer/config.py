"""The OpenXR API layer's configuration and environment: the layer's names, the variables it reads
(``VRCORRECT_LAYER_CONFIG``, ``VRCORRECT_RX``, ``VRCORRECT_LAYER_OFF``, ``VRCORRECT_LAYER_LOG``,
``VRCORRECT_LAYER_PRIME_S``, ``VRCORRECT_LAYER_STALL_TRACE``), where its configuration, off switch
and log lie, the configuration itself (:class:`LayerConfig`, :func:`read_config`), its log (one line
a reason), the display chosen for the runtime's view size and the opt-in stall trace
(:class:`StallTrace`).

Configuration (:class:`LayerConfig`): ``$XDG_CONFIG_HOME/vrcorrect/layer.json`` (or the file named by
``VRCORRECT_LAYER_CONFIG``) with ``rx`` (prescription path), ``display`` (preset or profile path;
absent: the preset whose per-eye resolution equals the runtime's recommended view size, else
``quest2``), ``options`` (:class:`~vrcorrect.runtime.eye_model.CorrectorOptions` fields, over
:data:`LAYER_DEFAULTS`: the pupil followed from the light, the robust design, as the commands).
``VRCORRECT_RX`` overrides ``rx``.  Off switch: ``VRCORRECT_LAYER_OFF=1`` or the file
``layer.off`` beside the configuration (checked every quarter second: on and off live).
Log: ``VRCORRECT_LAYER_LOG``, else ``$XDG_STATE_HOME/vrcorrect/layer.log`` (``~/.local/state``).

Layer 5: plain Python; never torch, never :mod:`vrcorrect.apps`.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from ...plumbing.errors import InputError, ValidationError
from ...specs.display import get_display, preset_names
from ...specs.vocabulary import VIEW_ORDER

if TYPE_CHECKING:  # pragma: no cover - typing only
    from ...specs.display import DisplayProfile

__all__ = ["BUILD_NICE", "CAPTURE_WAIT_S", "CLOSE_WAIT_S", "CONFIG_ENV", "DISABLE_ENV", "LAYER_NAME", "LOG_ENV",
           "STALL_TRACE_ENV", "STALL_TRACE_S", "StallTrace",
           "LAYER_DEFAULTS", "LayerConfig", "LayerLog", "LIGHT_WAIT_S", "OFF_ENV", "PRIME_BUDGET_S", "PRIME_ENV", "PRIME_MAX_FRAMES", "RX_ENV",
           "choose_display", "config_path", "eye_of_view", "log_path", "off_file", "one_line",
           "one_line_text", "prime_budget", "read_config"]


LAYER_NAME = "XR_APILAYER_VRCORRECT_correction"
DISABLE_ENV = "DISABLE_VRCORRECT_LAYER"      # the manifest's disable_environment: the loader skips the layer
OFF_ENV = "VRCORRECT_LAYER_OFF"              # the engine's live off switch (the layer stays loaded)
CONFIG_ENV = "VRCORRECT_LAYER_CONFIG"
RX_ENV = "VRCORRECT_RX"
LOG_ENV = "VRCORRECT_LAYER_LOG"
STALL_TRACE_ENV = "VRCORRECT_LAYER_STALL_TRACE"
STALL_TRACE_S = 0.5
"""A frame whose part in the layer (``xrEndFrame``, from the frame's start to its end) lasts
longer than this many seconds has every thread's Python stack written to the file named by
``VRCORRECT_LAYER_STALL_TRACE`` (:class:`StallTrace`): where a host's frame waited on the layer."""
LAYER_DEFAULTS: Mapping[str, Any] = {"pupil": "auto", "robust": True, "band": "auto"}
"""The corrector options the layer uses where its configuration's ``options`` do not say otherwise: the
viewing pupil followed from the light of the frames shown, the robust design and its band by the
picture, as ``vrcorrect xr``, ``mirror``, ``overlay`` and ``render`` do (``--pupil auto --robust on
--band auto``)."""
_CHECK_INTERVAL_S = 0.25
_REPORT_INTERVAL_S = 1.0
CAPTURE_WAIT_S = 2.0
"""How long a build waits for the application's next frame to prime its correction on (no frame: it
is handed over unprimed, warmed up only)."""
PRIME_MAX_FRAMES = 40
"""Frames a build corrects a captured view for at most before handing over (converged sooner)."""
PRIME_ENV = "VRCORRECT_LAYER_PRIME_S"
PRIME_BUDGET_S = 1.0
"""Seconds a build primes its correction for at most (all eyes together; ``VRCORRECT_LAYER_PRIME_S``
sets another, ``converge`` none).  On a GPU priming converges well inside it (a frame's iterations
take milliseconds); on a software renderer, where a frame of both eyes at 96x64 takes 0.1-0.3 s and
a still scene needs some 35 frames, the correction is handed over after the budget and goes on
converging on the application's frames, as it does after any cut, instead of keeping the
application uncorrected for seconds more."""
LIGHT_WAIT_S = 30.0
"""How long a build's priming waits at most for the design of the light's pupil (``pupil="auto"``,
:meth:`~vrcorrect.runtime.layer.pipeline.Pipeline.prime`), the application passing through meanwhile;
past it the correction starts with the mid-grey frame's design and switches when the light's is ready.
A second launch takes it from the design cache (:mod:`~vrcorrect.runtime.eye_cache`) at once."""
BUILD_NICE = 10
"""The build worker's CPU priority (Linux nice value, per thread): the application's threads come first.
Not the lowest: the worker holds Python's lock between its GL calls, and a worker the scheduler leaves
waiting while it holds it keeps the application's ``xrEndFrame`` waiting too (nice 19 on a busy machine
held passed-through frames up to 0.54 s on the lock; nice 10, 0.12 s)."""
CLOSE_WAIT_S = 30.0
"""How long the instance's end waits for an eye-model build still running (:meth:`Engine.close`)."""
_NEVER = object()


def _config_home(env: Mapping[str, str]) -> Path:
    base = env.get("XDG_CONFIG_HOME") or str(Path(env.get("HOME") or Path.home()) / ".config")
    return Path(base)


def config_path(env: Mapping[str, str] | None = None) -> Path:
    """The layer configuration file (``VRCORRECT_LAYER_CONFIG`` or ``$XDG_CONFIG_HOME/vrcorrect/layer.json``)."""
    env = os.environ if env is None else env
    named = env.get(CONFIG_ENV)
    return Path(named) if named else _config_home(env) / "vrcorrect" / "layer.json"


def off_file(env: Mapping[str, str] | None = None) -> Path:
    """The off switch file: while it exists the layer passes every frame through."""
    return config_path(env).with_name("layer.off")


def log_path(env: Mapping[str, str] | None = None) -> Path:
    """Where the layer (C shim and engine) appends its log lines."""
    env = os.environ if env is None else env
    if env.get(LOG_ENV):
        return Path(env[LOG_ENV])
    state = env.get("XDG_STATE_HOME") or str(Path(env.get("HOME") or Path.home()) / ".local" / "state")
    return Path(state) / "vrcorrect" / "layer.log"


def prime_budget(env: Mapping[str, str] | None = None) -> float:
    """The priming budget in seconds (:data:`PRIME_BUDGET_S`; ``VRCORRECT_LAYER_PRIME_S``: seconds,
    or ``converge`` for no budget but :data:`PRIME_MAX_FRAMES`).

    Raises
    ------
    ValidationError
        The variable is neither a number of seconds from 0 to 60 nor ``converge``.
    """
    env = os.environ if env is None else env
    text = env.get(PRIME_ENV, "").strip()
    if not text:
        return PRIME_BUDGET_S
    if text == "converge":
        return math.inf
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 <= value <= 60.0:
        raise ValidationError(PRIME_ENV, text, "seconds from 0 to 60, or 'converge'")
    return value


def eye_of_view(view: int) -> str:
    """``"left"`` for view 0, ``"right"`` for view 1 (``PRIMARY_STEREO``,
    :data:`~vrcorrect.specs.vocabulary.VIEW_ORDER`); other views are refused."""
    if view in (0, 1):
        return VIEW_ORDER[int(view)]
    raise ValidationError("view", view, "0 (left eye) or 1 (right eye): stereo projection views only")


@dataclass(frozen=True)
class LayerConfig:
    """What the layer corrects with: read from the configuration file and the environment."""

    rx: Path | None = None
    display: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    source: Path | None = None              # the configuration file it came from (None: none found)

    @property
    def corrector_options(self) -> dict[str, Any]:
        """The options a Corrector of this configuration takes: ``options`` over :data:`LAYER_DEFAULTS`."""
        return {**LAYER_DEFAULTS, **self.options}


def read_config(env: Mapping[str, str] | None = None) -> LayerConfig:
    """The configuration (file, then ``VRCORRECT_RX``).  A missing file is an empty configuration.

    Raises
    ------
    InputError
        The file exists but cannot be read or is not a JSON object.
    ValidationError
        A field of the wrong type.
    """
    env = os.environ if env is None else env
    path = config_path(env)
    doc: dict[str, Any] = {}
    source = None
    if path.exists():
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: cannot read the layer configuration: {exc}") from None
        if not isinstance(doc, dict):
            raise InputError(f"{path}: the layer configuration must be a JSON object")
        source = path
    rx = doc.get("rx")
    if rx is not None and not isinstance(rx, str):
        raise ValidationError("rx", rx, "a prescription JSON path", source=str(path))
    display = doc.get("display")
    if display is not None and not isinstance(display, str):
        raise ValidationError("display", display, "a display preset name or profile path", source=str(path))
    options = doc.get("options", {})
    if not isinstance(options, dict):
        raise ValidationError("options", options, "an object of corrector options", source=str(path))
    if env.get(RX_ENV):
        rx = env[RX_ENV]
    rx_path = None
    if rx:
        rx_path = Path(rx).expanduser()
        if not rx_path.is_absolute() and source is not None:
            rx_path = source.parent / rx_path
    return LayerConfig(rx=rx_path, display=display, options=dict(options), source=source)


class LayerLog:
    """One line per event, to the log file and stderr; pass-through reasons only when they change."""

    def __init__(self, path: Path):
        self.path = path
        self.last_reason: str | None = None

    def line(self, text: str) -> None:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(f"{stamp} {text}\n")
        except OSError:
            pass
        try:
            sys.stderr.write(f"vrcorrect layer: {text}\n")
        except Exception:  # noqa: BLE001  (a closed stderr must not break the frame)
            pass

    def reason(self, text: str) -> None:
        if text != self.last_reason:
            self.last_reason = text
            self.line(f"pass-through: {text}")

    def corrected(self) -> None:
        self.last_reason = None


def _off(env: Mapping[str, str]) -> str | None:
    value = env.get(OFF_ENV, "").strip().lower()
    if value and value not in ("0", "false", "no", "off"):
        return f"switched off ({OFF_ENV}={env[OFF_ENV]})"
    switch = off_file(env)
    if switch.exists():
        return f"switched off (the file {switch} exists)"
    return None


def choose_display(name: str | None, view_size: tuple[int, int]) -> tuple[DisplayProfile, str]:
    """The display profile and why it was chosen: the user's, else the preset whose per-eye
    resolution equals the runtime's recommended view size, else ``quest2``."""

    if name:
        return get_display(name), "configured"
    for key in preset_names():
        try:
            profile = get_display(key)
        except Exception:  # noqa: BLE001
            continue
        if profile.kind == "headset" and profile.resolution_px == tuple(view_size):
            return profile, f"matches the runtime's view size {view_size[0]}x{view_size[1]}"
    return get_display("quest2"), (f"no preset has the runtime's view size {view_size[0]}x{view_size[1]}; "
                                   "set display in the layer configuration")


def one_line(exc: BaseException) -> str:
    text = one_line_text(str(exc))
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def one_line_text(text: str) -> str:
    return " ".join(text.split())


class StallTrace:
    """Opt-in (``VRCORRECT_LAYER_STALL_TRACE=FILE``): a diagnostic of frames the layer held the host up
    in.  :meth:`arm` at a frame's start has :mod:`faulthandler` write every thread's Python stack to
    ``path`` if :meth:`disarm` has not come within ``seconds`` (from a C watchdog thread: it writes
    even while a thread holds Python's lock or waits inside GL); :meth:`disarm` adds which frame it
    was and how long it lasted.  One such watchdog exists per process, so this is off unless asked
    for (an application of its own using ``faulthandler.dump_traceback_later`` loses it).  With
    ``path`` None (not asked for) or a file that cannot be written, it does nothing."""

    def __init__(self, path: str | os.PathLike[str] | None, seconds: float = STALL_TRACE_S):
        self.path, self.seconds = (Path(path) if path else None), float(seconds)
        self._file: Any = None
        self._armed: tuple[int, float, int] | None = None      # (frame, start, the file's size then)

    def arm(self, frame: int) -> str:
        """Watch the frame after ``frame`` corrected ones; returns '' or, once, why the trace is off
        (its file cannot be written: a diagnostic never stops the correction)."""
        if self.path is None:                      # off (every frame passes here): nothing
            return ""
        import faulthandler  # opt-in: a diagnostic nobody else loads

        try:
            if self._file is None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._file = open(self.path, "a", encoding="utf-8")
            self._file.flush()
            self._armed = (frame, time.perf_counter(), os.fstat(self._file.fileno()).st_size)
        except OSError as exc:
            self.path = None
            return f"no stall trace ({STALL_TRACE_ENV}): {one_line(exc)}"
        faulthandler.dump_traceback_later(self.seconds, repeat=False, file=self._file)
        return ""

    def disarm(self) -> str:
        """End the frame's watch; returns '' or, where the frame outlasted ``seconds`` (its stacks
        were written), the log's line saying so."""
        if self._armed is None:
            return ""
        import faulthandler  # as above

        faulthandler.cancel_dump_traceback_later()
        frame, start, size = self._armed
        self._armed = None
        if os.fstat(self._file.fileno()).st_size == size:
            return ""
        self._file.write(f"(the stacks above: the frame after {frame} corrected ones, {time.perf_counter() - start:.3f} "
                         f"s in the layer; written {self.seconds:g} s into it)\n\n")
        self._file.flush()
        return f"a frame took over {self.seconds:g} s in the layer: every thread's stack is in {self.path}"

    def close(self) -> None:
        self.disarm()
        if self._file is not None:
            self._file.close()
            self._file = None
