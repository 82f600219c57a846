"""The headset path (``vrcorrect xr``, whose command line is :mod:`vrcorrect.apps.xr`): an OpenXR
session through pyopenxr, each eye corrected before it is submitted.

* ``session`` - the pure parts: exit statuses, stages, messages, the swapchain format's choice, the
  session's state machine, the configuration and the run's summary.
* ``views`` - poses and projections of the views.
* ``instance`` - the OpenXR instance and the head-mounted system, checked.
* ``gaze`` - the eye tracker (``XR_EXT_eye_gaze_interaction``).
* ``app`` - :class:`XrApp`: the instance, the GL binding, the swapchains, the frame loop, the
  tear-down.

The names the commands, the benchmarks and the tests use are listed here.
Layer 5: numpy, moderngl, glfw, pyopenxr; never torch.
"""

from .app import XrApp
from .session import (
    EXIT_GRACE_S,
    EXIT_NO_RUNTIME,
    EXIT_SESSION_LOST,
    GL_RGBA8,
    GL_SRGB8_ALPHA8,
    XR_CPU_ONLY_STAGES,
    XR_STAGES,
    SessionTracker,
    XrConfig,
    XrRunSummary,
    choose_swapchain_format,
    no_runtime_message,
)
from .views import pose_matrix, projection_from_fov, view_matrix

__all__ = [
    "EXIT_NO_RUNTIME", "EXIT_SESSION_LOST", "EXIT_GRACE_S", "GL_SRGB8_ALPHA8", "GL_RGBA8", "XR_STAGES",
    "XR_CPU_ONLY_STAGES", "XrConfig", "SessionTracker", "choose_swapchain_format", "pose_matrix", "view_matrix",
    "projection_from_fov", "no_runtime_message", "XrApp", "XrRunSummary",
]
