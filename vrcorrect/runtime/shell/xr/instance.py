"""The OpenXR instance of the headset path (``vrcorrect xr``): created with the extensions it needs,
its loader's complaints turned into one paragraph when no runtime is there, and the head-mounted
system checked for what the loop needs (two views of one size, an opaque blend, OpenGL's
requirements); and two small helpers for pyopenxr's handles.

Layer 5: pyopenxr (passed in: imported by :class:`~vrcorrect.runtime.shell.xr.app.XrApp`); never torch.
"""

from __future__ import annotations

import ctypes
import os
import sys
import tempfile
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from ....plumbing.errors import XrSessionError, XrUnavailableError
from .session import XrConfig, no_headset_message, no_runtime_message

__all__ = ["CapturedStderr", "loader_detail", "create_instance", "XrSystem", "find_system", "address", "quietly"]


class CapturedStderr:
    """Collects what C code (the OpenXR loader) writes to file descriptor 2 while active."""

    def __enter__(self) -> "CapturedStderr":
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        self.text = ""
        return self

    def __exit__(self, *exc: object) -> None:
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._file.seek(0)
        self.text = self._file.read().decode(errors="replace")
        self._file.close()


def loader_detail(text: str) -> str:
    """The loader's first error line, without its ``Error [GENERAL | ...] :`` prefix."""
    for line in text.splitlines():
        if "Error" in line and ":" in line:
            return line.split("] :", 1)[-1].strip().rstrip(".") or line.strip()
    return ""


def create_instance(xr: Any, cfg: XrConfig, extensions: Sequence[str], say: Callable[[str], None]) -> tuple[Any, str]:
    """The instance (with ``extensions``) and its runtime's name; :class:`XrUnavailableError` (one
    paragraph) when there is no runtime or it lacks OpenGL. The loader's own lines are shown with
    ``VRCORRECT_DEBUG`` set."""
    if cfg.validation:
        xr.api_layer.activate_core_validation_layer()
    info = xr.InstanceCreateInfo(
        application_info=xr.ApplicationInfo(application_name=cfg.application_name, application_version=1,
                                            engine_name="vrcorrect", engine_version=1,
                                            api_version=xr.Version(1, 0, 0)),
        enabled_extension_names=list(extensions))
    instance = None
    with CapturedStderr() as captured:
        try:
            instance = xr.create_instance(info)
            error = None
        except (xr.RuntimeUnavailableError, xr.RuntimeFailureError, xr.InitializationFailedError) as exc:
            error = exc
        except xr.ExtensionNotPresentError:
            error = "extension"
    if captured.text and os.environ.get("VRCORRECT_DEBUG"):
        say(captured.text.rstrip())
    if error == "extension":
        raise XrUnavailableError("the active OpenXR runtime does not offer XR_KHR_opengl_enable (OpenGL), which "
                                 "vrcorrect xr needs; Monado and SteamVR do. Without a headset, vrcorrect mirror "
                                 "shows both corrected eyes in a window.")
    if error is not None:
        raise XrUnavailableError(no_runtime_message(loader_detail(captured.text)))
    props = xr.get_instance_properties(instance)
    return instance, props.runtime_name.decode(errors="replace")


@dataclass
class XrSystem:
    """The head-mounted system an instance found: its id and name, each eye's recommended size and
    OpenGL's requirements (asked before the session, as ``XR_KHR_opengl_enable`` demands)."""

    system_id: Any
    name: str
    eye_size: tuple[int, int]
    gl_requirements: Any


def find_system(xr: Any, instance: Any, runtime: str, call: Callable[..., Any]) -> XrSystem:
    """The head-mounted system of ``instance``: :class:`XrUnavailableError` when there is no headset,
    :class:`XrSessionError` when it cannot run the loop (not two views of one size, no opaque
    blend, OpenGL's requirements refused). ``call(what, fn, *args)`` runs a pyopenxr call, its
    failures named."""
    try:
        system_id = xr.get_system(instance, xr.SystemGetInfo(form_factor=xr.FormFactor.HEAD_MOUNTED_DISPLAY))
    except xr.FormFactorUnavailableError:
        raise XrUnavailableError(no_headset_message(runtime)) from None
    except xr.XrException as exc:
        raise XrSessionError(f"xrGetSystem failed: {type(exc).__name__}: {exc}") from None
    name = xr.get_system_properties(instance, system_id).system_name.decode(errors="replace")
    views = call("xrEnumerateViewConfigurationViews", xr.enumerate_view_configuration_views,
                 instance, system_id, xr.ViewConfigurationType.PRIMARY_STEREO)
    if len(views) != 2:
        raise XrSessionError(f"stereo view configuration = {len(views)} views; vrcorrect xr needs 2")
    sizes = {(v.recommended_image_rect_width, v.recommended_image_rect_height) for v in views}
    if len(sizes) != 1:
        raise XrSessionError(f"recommended view sizes = {sorted(sizes)}; vrcorrect xr needs both eyes the same")
    blend = call("xrEnumerateEnvironmentBlendModes", xr.enumerate_environment_blend_modes,
                 instance, system_id, xr.ViewConfigurationType.PRIMARY_STEREO)
    if xr.EnvironmentBlendMode.OPAQUE not in [xr.EnvironmentBlendMode(int(b)) for b in blend]:
        raise XrSessionError("environment blend modes lack OPAQUE, which a VR projection layer needs")
    # XR_KHR_opengl_enable: the requirements call must come before xrCreateSession
    pfn = ctypes.cast(xr.get_instance_proc_addr(instance, "xrGetOpenGLGraphicsRequirementsKHR"),
                      xr.PFN_xrGetOpenGLGraphicsRequirementsKHR)
    requirements = xr.GraphicsRequirementsOpenGLKHR()
    result = xr.check_result(xr.Result(pfn(instance, system_id, ctypes.byref(requirements))))
    if result.is_exception():
        raise XrSessionError(f"xrGetOpenGLGraphicsRequirementsKHR failed: {result}")
    return XrSystem(system_id, name, sizes.pop(), requirements)


def address(handle: Any) -> int:
    """An integer address from what pyGLFW returns for native handles (int, c_void_p, pointer)."""
    if handle is None:
        return 0
    if isinstance(handle, int):
        return handle
    if isinstance(handle, ctypes.c_void_p):
        return handle.value or 0
    return ctypes.cast(handle, ctypes.c_void_p).value or 0


def quietly(fn: Callable[..., Any], *args: Any) -> None:
    """``fn(*args)``, any failure ignored (tear-down: a lost session's handles may already be gone)."""
    try:
        fn(*args)
    except Exception:  # tear-down: a lost session's handles may already be gone
        pass
