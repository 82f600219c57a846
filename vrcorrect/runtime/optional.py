"""The real-time path's optional dependencies (the ``realtime`` extra: moderngl, glfw, pyopenxr,
mss), imported when first needed, with one message naming the package, who needs it and the extra
to install. Every part of the runtime (the plugin, the shells, the API layer) may use these.

Layer 5; imports nothing but the errors.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ..plumbing.errors import GLUnavailableError, VrcorrectError, XrUnavailableError

__all__ = ["REALTIME_EXTRA", "import_optional", "require_moderngl", "require_glfw", "require_xr"]

REALTIME_EXTRA = "pip install -e '.[realtime]' (tools/setup.sh does)"
"""How to install the real-time path's optional dependencies."""


def import_optional(module: str, *, package: str | None = None, error: type[VrcorrectError] = GLUnavailableError,
                    needed_by: str | None = None) -> ModuleType:
    """``module`` imported, or ``error`` saying which package is missing (``package``, default the
    module's name), who needs it and how to install it (the realtime extra)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - the realtime extra is installed in CI
        who = f"{needed_by} needs {package or module}, which" if needed_by else package or module
        raise error(f"{who} is not installed ({exc}); install the realtime extra: {REALTIME_EXTRA}") from None


def require_moderngl() -> ModuleType:
    """moderngl, or :class:`~vrcorrect.plumbing.errors.GLUnavailableError`."""
    # lazy: importing the runtime (and building the CLI's parser) must not need moderngl
    return import_optional("moderngl")


def require_glfw() -> ModuleType:
    """pyGLFW, or :class:`~vrcorrect.plumbing.errors.GLUnavailableError`."""
    # lazy: glfw loads the native GLFW library, needed only once a window opens
    return import_optional("glfw")


def require_xr() -> ModuleType:
    """pyopenxr, or :class:`XrUnavailableError`."""
    # lazy: pyopenxr loads the OpenXR loader, needed only by the headset app
    return import_optional("xr", package="pyopenxr", error=XrUnavailableError)
