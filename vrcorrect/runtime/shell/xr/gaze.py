"""``vrcorrect xr``'s eye tracker: the gaze from ``XR_EXT_eye_gaze_interaction`` through pyopenxr, for
a foveated correction (``--fovea DEG``: the window follows the gaze).

The extension is asked for only with a fovea and only when the runtime offers it
(:func:`tracker_offered`). :class:`EyeTracker` then makes one action set with one pose action bound
to ``/user/eyes_ext/input/gaze_ext/pose`` of ``/interaction_profiles/ext/eye_gaze_interaction``,
attaches it, and each frame syncs it and locates the gaze in the application's space at the frame's
predicted display time (:meth:`EyeTracker.locate`). Each eye's window goes where the gaze crosses
that eye's view (:func:`~vrcorrect.runtime.gaze.gaze_in_view`); a frame without a gaze (the tracker
lost the eye, the session is not focused) keeps the configured ``--gaze``.
"""

from __future__ import annotations

import ctypes
from typing import Any

__all__ = ["EXTENSION", "PROFILE", "POSE_PATH", "tracker_offered", "EyeTracker"]

EXTENSION = "XR_EXT_eye_gaze_interaction"
PROFILE = "/interaction_profiles/ext/eye_gaze_interaction"
POSE_PATH = "/user/eyes_ext/input/gaze_ext/pose"


def tracker_offered(xr: Any) -> bool:
    """Whether the active runtime offers ``XR_EXT_eye_gaze_interaction``."""
    try:
        offered = xr.enumerate_instance_extension_properties()
    except Exception:  # noqa: BLE001 - no runtime: the instance's creation says so
        return False
    return any(_name(p.extension_name) == EXTENSION for p in offered)


def _name(raw: Any) -> str:
    return raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)


class EyeTracker:
    """The gaze of an eye tracker, through pyopenxr (module docstring).

    Made after the session; :attr:`why_not` says why there is no gaze (empty when :meth:`locate`
    may give one)."""

    def __init__(self, xr: Any, instance: Any, system_id: Any, session: Any):
        self.xr = xr
        self.session = session
        self.action_set = self.action = self.space = None
        self.why_not = ""
        if not self._supported(instance, system_id):
            self.why_not = "the system has no eye tracker (supportsEyeGazeInteraction is false)"
            return
        self.action_set = xr.create_action_set(instance, xr.ActionSetCreateInfo(
            action_set_name="vrcorrect_gaze", localized_action_set_name="vrcorrect: eye gaze", priority=0))
        self.action = xr.create_action(self.action_set, xr.ActionCreateInfo(
            action_name="gaze", action_type=xr.ActionType.POSE_INPUT, localized_action_name="vrcorrect: eye gaze"))
        binding = xr.ActionSuggestedBinding(action=self.action, binding=xr.string_to_path(instance, POSE_PATH))
        xr.suggest_interaction_profile_bindings(instance, xr.InteractionProfileSuggestedBinding(
            interaction_profile=xr.string_to_path(instance, PROFILE), suggested_bindings=[binding]))
        xr.attach_session_action_sets(session, xr.SessionActionSetsAttachInfo(action_sets=[self.action_set]))
        self.space = xr.create_action_space(session, xr.ActionSpaceCreateInfo(action=self.action))

    def _supported(self, instance: Any, system_id: Any) -> bool:
        xr = self.xr
        eye = xr.SystemEyeGazeInteractionPropertiesEXT()
        props = xr.SystemProperties(next=ctypes.cast(ctypes.pointer(eye), ctypes.c_void_p))
        result = xr.raw_functions.xrGetSystemProperties(instance, system_id, ctypes.byref(props))
        return int(result) >= 0 and bool(eye.supports_eye_gaze_interaction)

    def locate(self, base_space: Any, display_time: int) -> tuple[float, float, float, float] | None:
        """Sync the tracker's action and locate the gaze in ``base_space`` at ``display_time``: its
        orientation (x, y, z, w), whose -Z axis is the gaze; ``None`` when there is none this frame."""
        if self.space is None:
            return None
        xr = self.xr
        try:
            xr.sync_actions(self.session, xr.ActionsSyncInfo(
                active_action_sets=[xr.ActiveActionSet(action_set=self.action_set, subaction_path=xr.NULL_PATH)]))
            state = xr.get_action_state_pose(self.session, xr.ActionStateGetInfo(action=self.action))
            if not state.is_active:
                return None
            location = xr.locate_space(self.space, base_space, display_time)
        except xr.XrException:
            return None
        if not int(location.location_flags) & int(xr.SpaceLocationFlags.ORIENTATION_VALID_BIT):
            return None
        o = location.pose.orientation
        return (o.x, o.y, o.z, o.w)

    def close(self) -> None:
        """Destroy the space and the action set (the action goes with its set)."""
        xr = self.xr
        for fn, handle in ((getattr(xr, "destroy_space", None), self.space),
                           (getattr(xr, "destroy_action_set", None), self.action_set)):
            if fn is not None and handle is not None:
                try:
                    fn(handle)
                except Exception:  # noqa: BLE001 - tear-down: a lost session's handles may be gone
                    pass
        self.space = self.action_set = self.action = None
