"""The test runtime's simulated eye tracker (``tests/xr_runtime/xr_test_runtime.c``, ``XRTEST_GAZE_DEG``):
XR_EXT_eye_gaze_interaction, driven here from this process through pyopenxr's real OpenXR loader
(``XR_RUNTIME_JSON``), the runtime built by ``tools/xr_test_runtime.sh`` as the layer's tests build it.

Checked: the extension is offered, and accepted, only with a well-formed ``XRTEST_GAZE_DEG``; a malformed
one fails xrCreateInstance with a line in runtime.log; the system property; the eye-gaze profile's bindings
(only with the extension, only its gaze pose, only pose actions, a later suggestion replacing an earlier
one); a gaze action is active and its action spaces located only after a sync in FOCUSED that named its
set; the located gaze turns -z to normalize(tan x, tan y, -1) in VIEW, point i of the path during frame i
(the last one held), composed with the head's turning (``XRTEST_YAW_MRAD``) in LOCAL, with the space's
poseInActionSpace, and inverted when the gaze space is the base.

A session needs a graphics binding: a hidden GLFW window's GLX context, on the ``x_display`` fixture's
display (Xvfb), as ``vrcorrect xr`` binds it.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import subprocess
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

import xr

ROOT = Path(__file__).resolve().parents[1]
RUNTIME_SCRIPT = ROOT / "tools" / "xr_test_runtime.sh"
GAZE_EXT = "XR_EXT_eye_gaze_interaction"
PROFILE = "/interaction_profiles/ext/eye_gaze_interaction"
GAZE_POSE = "/user/eyes_ext/input/gaze_ext/pose"
ALL_LOCATED = (xr.SpaceLocationFlags.ORIENTATION_VALID_BIT | xr.SpaceLocationFlags.POSITION_VALID_BIT
               | xr.SpaceLocationFlags.ORIENTATION_TRACKED_BIT | xr.SpaceLocationFlags.POSITION_TRACKED_BIT)
# point 0 is the gaze of frame 0, before the session is FOCUSED (an action cannot be live then)
PATH = [(-40.0, -40.0), (5.0, -3.0), (-12.5, 20.0), (30.0, 7.5), (-60.0, -25.0)]


def _path_text(points) -> str:
    return ";".join(f"{x:g},{y:g}" for x, y in points)


# --------------------------------------------------------------------------
# Geometry, computed here independently of the runtime
# --------------------------------------------------------------------------


def _matrix(q) -> np.ndarray:
    """The rotation matrix of an xr.Quaternionf (or (x, y, z, w))."""
    x, y, z, w = (q.x, q.y, q.z, q.w) if hasattr(q, "w") else q
    n = math.sqrt(x * x + y * y + z * z + w * w)
    assert abs(n - 1) < 1e-5, n
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _about_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _about_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _about_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _direction(point) -> np.ndarray:
    """The gaze direction in VIEW space: normalize(tan x, tan y, -1)."""
    d = np.array([math.tan(math.radians(point[0])), math.tan(math.radians(point[1])), -1.0])
    return d / np.linalg.norm(d)


def _gaze_matrix(point) -> np.ndarray:
    """The gaze rotation as documented: a yaw about +y, then a pitch about the new +x, turning -z to the
    direction (no roll: the gaze's +x stays horizontal)."""
    d = _direction(point)
    return _about_y(math.atan2(-d[0], -d[2])) @ _about_x(math.asin(d[1]))


def test_the_expected_rotation_itself_turns_minus_z_to_the_direction():
    for point in PATH:
        r = _gaze_matrix(point)
        np.testing.assert_allclose(r @ [0, 0, -1], _direction(point), atol=1e-12)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert abs((r @ [1, 0, 0])[1]) < 1e-12


# --------------------------------------------------------------------------
# The runtime, the environment, instances and sessions
# --------------------------------------------------------------------------


@pytest.fixture(scope="session")
def runtime(tmp_path_factory) -> Path:
    """The test runtime built once by tools/xr_test_runtime.sh; its manifest (XR_RUNTIME_JSON)."""
    folder = tmp_path_factory.mktemp("xr_gaze_runtime")
    script = subprocess.run(["bash", str(RUNTIME_SCRIPT), str(folder)], capture_output=True, text=True)
    assert script.returncode == 0, script.stderr
    manifest = Path(script.stdout.strip().splitlines()[-1])
    assert manifest.is_file(), script.stdout
    return manifest


@pytest.fixture
def out(runtime, tmp_path, monkeypatch) -> Path:
    """Point this process's OpenXR loader at the test runtime, with no other XR_/XRTEST_ settings; the
    runtime's output folder (runtime.log)."""
    folder = tmp_path / "xr"
    for key in list(os.environ):
        if key.startswith(("XR_", "XRTEST_")):
            monkeypatch.delenv(key)
    monkeypatch.setenv("XR_RUNTIME_JSON", str(runtime))
    monkeypatch.setenv("XRTEST_OUT_DIR", str(folder))
    return folder


def _log(folder: Path) -> list[str]:
    return (folder / "runtime.log").read_text().splitlines()


def _offered() -> dict[str, int]:
    return {p.extension_name.decode(): p.extension_version for p in xr.enumerate_instance_extension_properties()}


def _create_instance(*extensions: str):
    return xr.create_instance(xr.InstanceCreateInfo(
        application_info=xr.ApplicationInfo(application_name="gaze test", application_version=1,
                                            engine_name="tests", engine_version=1, api_version=xr.Version(1, 0, 0)),
        enabled_extension_names=list(extensions)))


@contextlib.contextmanager
def _instance(*extensions: str) -> Iterator[tuple[Any, int]]:
    instance = _create_instance(*extensions)
    try:
        system = xr.get_system(instance, xr.SystemGetInfo(form_factor=xr.FormFactor.HEAD_MOUNTED_DISPLAY))
        yield instance, system
    finally:
        xr.destroy_instance(instance)


def _supports_eye_gaze(instance, system) -> bool:
    eye = xr.SystemEyeGazeInteractionPropertiesEXT(supports_eye_gaze_interaction=7)
    props = xr.SystemProperties(next=ctypes.cast(ctypes.pointer(eye), ctypes.c_void_p))
    result = xr.raw_functions.xrGetSystemProperties(instance, system, ctypes.byref(props))
    assert result == xr.Result.SUCCESS
    assert eye.supports_eye_gaze_interaction in (0, 1)          # written by the runtime, not left at 7
    return bool(eye.supports_eye_gaze_interaction)


def _address(handle: Any) -> int:
    if isinstance(handle, int):
        return handle
    if isinstance(handle, ctypes.c_void_p):
        return handle.value or 0
    return ctypes.cast(handle, ctypes.c_void_p).value or 0


@contextlib.contextmanager
def _session(instance, system) -> Iterator[Any]:
    """A session bound to a hidden GLFW window's GLX context (XR_KHR_opengl_enable, as vrcorrect xr)."""
    from vrcorrect.runtime.shell.window import GlfwSession

    pfn = ctypes.cast(xr.get_instance_proc_addr(instance, "xrGetOpenGLGraphicsRequirementsKHR"),
                      xr.PFN_xrGetOpenGLGraphicsRequirementsKHR)
    requirements = xr.GraphicsRequirementsOpenGLKHR()
    assert pfn(instance, system, ctypes.byref(requirements)) == xr.Result.SUCCESS
    with GlfwSession(platform="x11") as window:
        window.open(64, 64, "gaze test", visible=False, vsync=False)
        glfw = window.glfw
        binding = xr.GraphicsBindingOpenGLXlibKHR()
        fields = dict(binding._fields_)
        binding.x_display = ctypes.cast(ctypes.c_void_p(_address(glfw.get_x11_display())), fields["x_display"])
        binding.glx_context = ctypes.cast(ctypes.c_void_p(_address(glfw.get_glx_context(window.window))),
                                          fields["glx_context"])
        binding.glx_drawable = int(glfw.get_glx_window(window.window))
        session = xr.create_session(instance, xr.SessionCreateInfo(
            system_id=system, next=ctypes.cast(ctypes.pointer(binding), ctypes.c_void_p)))
        try:
            yield session
        finally:
            xr.destroy_session(session)


def _events(instance) -> list[tuple[str, str | None]]:
    """Every queued event: (structure type name, session state name or None)."""
    out = []
    while True:
        try:
            buffer = xr.poll_event(instance)
        except xr.EventUnavailable:
            return out
        kind = xr.StructureType(buffer.type)
        state = None
        if kind == xr.StructureType.EVENT_DATA_SESSION_STATE_CHANGED:
            event = ctypes.cast(ctypes.byref(buffer), ctypes.POINTER(xr.EventDataSessionStateChanged)).contents
            state = xr.SessionState(event.state).name
        out.append((kind.name, state))


def _int(value: Any) -> int:
    """An XrPath as pyopenxr gives it (a ctypes integer or an int) as an int."""
    return int(value.value if hasattr(value, "value") else value)


def _path(instance, text: str) -> int:
    return _int(xr.string_to_path(instance, text))


class Actions:
    """Action sets and pose actions by name."""

    def __init__(self, instance, layout: dict[str, list[str]], kinds: dict[str, Any] | None = None,
                 subactions: dict[str, list[str]] | None = None):
        self.instance = instance
        self.sets, self.actions = {}, {}
        for set_name, names in layout.items():
            self.sets[set_name] = xr.create_action_set(instance, xr.ActionSetCreateInfo(
                action_set_name=set_name, localized_action_set_name=set_name, priority=0))
            for name in names:
                kind = (kinds or {}).get(name, xr.ActionType.POSE_INPUT)
                paths = [_path(instance, p) for p in (subactions or {}).get(name, [])]
                self.actions[name] = xr.create_action(self.sets[set_name], xr.ActionCreateInfo(
                    action_name=name, action_type=kind, localized_action_name=name, subaction_paths=paths or None))

    def suggest(self, profile: str, bindings: dict[str, str]) -> None:
        xr.suggest_interaction_profile_bindings(self.instance, xr.InteractionProfileSuggestedBinding(
            interaction_profile=_path(self.instance, profile),
            suggested_bindings=[xr.ActionSuggestedBinding(self.actions[a], _path(self.instance, b))
                                for a, b in bindings.items()]))

    def attach(self, session) -> None:
        xr.attach_session_action_sets(session, xr.SessionActionSetsAttachInfo(action_sets=list(self.sets.values())))

    def sync(self, session, *set_names: str) -> None:
        xr.sync_actions(session, xr.ActionsSyncInfo(active_action_sets=[
            xr.ActiveActionSet(self.sets[name], xr.NULL_PATH) for name in set_names]))

    def active(self, session, name: str) -> bool:
        return bool(xr.get_action_state_pose(session, xr.ActionStateGetInfo(action=self.actions[name])).is_active)

    def space(self, session, name: str, pose: Any = None) -> Any:
        return xr.create_action_space(session, xr.ActionSpaceCreateInfo(
            action=self.actions[name], pose_in_action_space=pose or xr.Posef()))


def _reference(session, kind) -> Any:
    return xr.create_reference_space(session, xr.ReferenceSpaceCreateInfo(reference_space_type=kind))


def _locate(space, base, time: int) -> tuple[Any, int]:
    """xrLocateSpace with an XrEyeGazeSampleTimeEXT chained: (the location, the sample time)."""
    sample = xr.EyeGazeSampleTimeEXT(time=-5)
    location = xr.SpaceLocation(next=ctypes.cast(ctypes.pointer(sample), ctypes.c_void_p))
    assert xr.raw_functions.xrLocateSpace(space, base, time, ctypes.byref(location)) == xr.Result.SUCCESS
    return location, int(sample.time)


def _position(location) -> np.ndarray:
    p = location.pose.position
    return np.array([p.x, p.y, p.z])


class Frames:
    """The session's frame loop: begin the session when READY, then wait / begin / end frames with no
    layers (the runtime counts xrEndFrame calls)."""

    def __init__(self, instance, session):
        self.instance, self.session = instance, session
        self.ended = 0
        self.states: list[str] = []
        self.events: list[str] = []

    def poll(self) -> None:
        for kind, state in _events(self.instance):
            self.events.append(kind)
            if state is None:
                continue
            self.states.append(state)
            if state == "READY":
                xr.begin_session(self.session, xr.SessionBeginInfo(
                    primary_view_configuration_type=xr.ViewConfigurationType.PRIMARY_STEREO))

    def wait(self) -> int:
        return int(xr.wait_frame(self.session).predicted_display_time)

    def begin(self) -> None:
        xr.begin_frame(self.session)

    def end(self, display_time: int) -> None:
        xr.end_frame(self.session, xr.FrameEndInfo(display_time=display_time,
                                                    environment_blend_mode=xr.EnvironmentBlendMode.OPAQUE))
        self.ended += 1
        self.poll()

    def frame(self) -> int:
        t = self.wait()
        self.begin()
        self.end(t)
        return t


# --------------------------------------------------------------------------
# The offer
# --------------------------------------------------------------------------


def test_without_the_variable_the_extension_is_neither_offered_nor_accepted(out):
    offered = _offered()
    assert "XR_KHR_opengl_enable" in offered and GAZE_EXT not in offered
    with pytest.raises(xr.ExtensionNotPresentError):
        _create_instance("XR_KHR_opengl_enable", GAZE_EXT)
    with _instance("XR_KHR_opengl_enable") as (instance, system):
        assert _supports_eye_gaze(instance, system) is False
        actions = Actions(instance, {"eyes": ["gaze"]})
        with pytest.raises(xr.PathUnsupportedError):
            actions.suggest(PROFILE, {"gaze": GAZE_POSE})
    assert not any("gaze path" in line for line in _log(out))


def test_with_the_variable_it_is_offered_and_the_system_supports_eye_gaze(out, monkeypatch):
    monkeypatch.setenv("XRTEST_GAZE_DEG", _path_text(PATH))
    assert _offered()[GAZE_EXT] == 1
    with _instance("XR_KHR_opengl_enable", GAZE_EXT) as (instance, system):
        assert _supports_eye_gaze(instance, system) is True
    assert f"gaze path {len(PATH)} points" in _log(out)
    # offered but not enabled: no eye gaze, and its profile is refused
    with _instance("XR_KHR_opengl_enable") as (instance, system):
        assert _supports_eye_gaze(instance, system) is False
        actions = Actions(instance, {"eyes": ["gaze"]})
        with pytest.raises(xr.PathUnsupportedError):
            actions.suggest(PROFILE, {"gaze": GAZE_POSE})
        actions.suggest("/interaction_profiles/khr/simple_controller", {"gaze": "/user/hand/left/input/grip/pose"})


@pytest.mark.parametrize("text, point", [
    ("abc", 1), ("10,90", 1), ("1,2;;3,4", 2), ("1,2;", 2), ("1", 1), ("1,2,3", 1), ("5;6", 1), ("", 1),
    ("0,0;-80.5,0", 2), ("nan,0", 1), ("1,2 x", 1),
])
def test_a_malformed_path_fails_instance_creation_and_says_why(out, monkeypatch, text, point):
    monkeypatch.setenv("XRTEST_GAZE_DEG", text)
    assert GAZE_EXT not in _offered()
    with pytest.raises(xr.InitializationFailedError):
        _create_instance("XR_KHR_opengl_enable")
    # not offered, so the loader itself refuses the extension before the runtime sees the call
    with pytest.raises(xr.ExtensionNotPresentError):
        _create_instance("XR_KHR_opengl_enable", GAZE_EXT)
    lines = [line for line in _log(out) if "XRTEST_GAZE_DEG" in line]
    assert len(lines) == 1, _log(out)
    assert f'"{text}"' in lines[0] and f"at point {point}" in lines[0] and '"x,y;x,y;..."' in lines[0]
    assert "80" in lines[0] and "4096" in lines[0]


def test_a_path_of_4096_points_is_taken_and_one_more_is_refused(out, monkeypatch):
    monkeypatch.setenv("XRTEST_GAZE_DEG", ";".join(["1.5, -2"] * 4096))
    with _instance("XR_KHR_opengl_enable", GAZE_EXT) as (instance, system):
        assert _supports_eye_gaze(instance, system)
    assert "gaze path 4096 points" in _log(out)
    monkeypatch.setenv("XRTEST_GAZE_DEG", ";".join(["1.5,-2"] * 4097))
    assert GAZE_EXT not in _offered()
    with pytest.raises(xr.InitializationFailedError):
        _create_instance("XR_KHR_opengl_enable")
    assert "at point 4097" in _log(out)[-1]


def test_the_eye_gaze_profile_takes_only_the_gaze_pose_of_pose_actions(out, monkeypatch):
    monkeypatch.setenv("XRTEST_GAZE_DEG", "0,0")
    with _instance("XR_KHR_opengl_enable", GAZE_EXT) as (instance, _):
        actions = Actions(instance, {"eyes": ["gaze", "blink"]}, kinds={"blink": xr.ActionType.BOOLEAN_INPUT})
        for bindings in ({"gaze": "/user/eyes_ext/input/gaze_ext"}, {"gaze": "/user/hand/left/input/grip/pose"},
                         {"blink": GAZE_POSE}, {"gaze": GAZE_POSE, "blink": GAZE_POSE}):
            with pytest.raises(xr.PathUnsupportedError):
                actions.suggest(PROFILE, bindings)
        actions.suggest(PROFILE, {"gaze": GAZE_POSE})
    assert f"actions suggest {PROFILE} 1" in _log(out)


# --------------------------------------------------------------------------
# The gaze, frame by frame
# --------------------------------------------------------------------------


def test_the_gaze_follows_the_path_frame_by_frame_in_view_space(x_display, out, monkeypatch):
    monkeypatch.setenv("XRTEST_GAZE_DEG", _path_text(PATH))
    with _instance("XR_KHR_opengl_enable", GAZE_EXT) as (instance, system):
        actions = Actions(instance, {"eyes": ["gaze"], "hands": ["hand"]})
        actions.suggest(PROFILE, {"gaze": GAZE_POSE})
        with _session(instance, system) as session:
            frames = Frames(instance, session)
            actions.attach(session)
            view = _reference(session, xr.ReferenceSpaceType.VIEW)
            local = _reference(session, xr.ReferenceSpaceType.LOCAL)
            gaze, hand = actions.space(session, "gaze"), actions.space(session, "hand")
            eyes_ext = _path(instance, "/user/eyes_ext")
            assert _int(xr.get_current_interaction_profile(session, eyes_ext).interaction_profile) == \
                _path(instance, PROFILE)
            assert _int(xr.get_current_interaction_profile(
                session, _path(instance, "/user/hand/left")).interaction_profile) == xr.NULL_PATH
            assert [_int(p) for p in xr.enumerate_bound_sources_for_action(
                session, xr.BoundSourcesForActionEnumerateInfo(action=actions.actions["gaze"]))] == \
                [_path(instance, GAZE_POSE)]
            frames.poll()
            assert "EVENT_DATA_INTERACTION_PROFILE_CHANGED" in frames.events
            assert frames.states == ["IDLE", "READY"]
            # before any sync: inactive, unlocated
            t = frames.wait()
            assert not actions.active(session, "gaze")
            location, sampled = _locate(gaze, view, t)
            assert int(location.location_flags) == 0 and sampled == 0
            # frame 0 is not FOCUSED yet: a sync then answers XR_SESSION_NOT_FOCUSED (pyopenxr raises it) and
            # leaves every action inactive
            with pytest.raises(xr.SessionNotFocused):
                actions.sync(session, "eyes")
            assert not actions.active(session, "gaze")
            assert int(_locate(gaze, view, t)[0].location_flags) == 0
            frames.begin()
            frames.end(t)
            assert frames.states[-1] == "FOCUSED"
            for frame in range(1, len(PATH) + 3):
                t = frames.wait()
                actions.sync(session, "eyes", "hands")
                assert actions.active(session, "gaze") and not actions.active(session, "hand")
                assert int(_locate(hand, view, t)[0].location_flags) == 0
                point = PATH[min(frame, len(PATH) - 1)]            # the last point holds
                for when in ("after wait", "after begin"):
                    location, sampled = _locate(gaze, view, t)
                    assert int(location.location_flags) == int(ALL_LOCATED), (frame, when)
                    assert sampled == t
                    r = _matrix(location.pose.orientation)
                    np.testing.assert_allclose(r @ [0, 0, -1], _direction(point), atol=1e-5, err_msg=f"{frame} {when}")
                    np.testing.assert_allclose(r, _gaze_matrix(point), atol=1e-5)
                    d = r @ [0, 0, -1]                             # where a symmetric view projects it
                    np.testing.assert_allclose(-d[:2] / d[2], np.tan(np.radians(point)), atol=1e-5)
                    np.testing.assert_allclose(_position(location), 0, atol=1e-6)
                    # a still head: LOCAL and VIEW agree
                    in_local = _locate(gaze, local, t)[0]
                    np.testing.assert_allclose(_matrix(in_local.pose.orientation), r, atol=1e-5)
                    if when == "after wait":
                        frames.begin()
                frames.end(t)
            assert frames.ended == len(PATH) + 3
            assert frames.states[-1] == "FOCUSED"


def test_a_turning_head_carries_the_gaze_in_local_space(x_display, out, monkeypatch):
    monkeypatch.setenv("XRTEST_GAZE_DEG", _path_text(PATH))
    monkeypatch.setenv("XRTEST_YAW_MRAD", "100")
    with _instance("XR_KHR_opengl_enable", GAZE_EXT) as (instance, system):
        actions = Actions(instance, {"eyes": ["gaze"]})
        actions.suggest(PROFILE, {"gaze": GAZE_POSE})
        with _session(instance, system) as session:
            frames = Frames(instance, session)
            actions.attach(session)
            local = _reference(session, xr.ReferenceSpaceType.LOCAL)
            view = _reference(session, xr.ReferenceSpaceType.VIEW)
            gaze = actions.space(session, "gaze")
            frames.poll()
            frames.frame()
            assert frames.states[-1] == "FOCUSED"
            for frame in range(1, len(PATH) + 2):
                t = frames.wait()
                actions.sync(session, "eyes")
                point = PATH[min(frame, len(PATH) - 1)]
                head = _about_y(0.1 * frame)                       # turned left 100 mrad per ended frame
                head_location = _locate(view, local, t)[0]
                np.testing.assert_allclose(_matrix(head_location.pose.orientation), head, atol=1e-5)
                location = _locate(gaze, local, t)[0]
                assert int(location.location_flags) == int(ALL_LOCATED)
                r = _matrix(location.pose.orientation)
                np.testing.assert_allclose(r, head @ _gaze_matrix(point), atol=1e-5, err_msg=str(frame))
                np.testing.assert_allclose(r @ [0, 0, -1], head @ _direction(point), atol=1e-5)
                # relative to the head, the turning cancels
                np.testing.assert_allclose(_matrix(_locate(gaze, view, t)[0].pose.orientation), _gaze_matrix(point),
                                           atol=1e-5)
                frames.begin()
                frames.end(t)


def test_a_pose_in_the_gaze_space_and_the_gaze_as_the_base(x_display, out, monkeypatch):
    monkeypatch.setenv("XRTEST_GAZE_DEG", "0,0;20,-10")
    with _instance("XR_KHR_opengl_enable", GAZE_EXT) as (instance, system):
        actions = Actions(instance, {"eyes": ["gaze"]})
        actions.suggest(PROFILE, {"gaze": GAZE_POSE})
        with _session(instance, system) as session:
            frames = Frames(instance, session)
            actions.attach(session)
            view = _reference(session, xr.ReferenceSpaceType.VIEW)
            gaze = actions.space(session, "gaze")
            # 2 m along the gaze, turned 90 degrees about it
            ahead = actions.space(session, "gaze", xr.Posef(
                orientation=xr.Quaternionf(0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)),
                position=xr.Vector3f(0, 0, -2)))
            frames.poll()
            frames.frame()
            t = frames.wait()
            actions.sync(session, "eyes")
            g = _gaze_matrix((20, -10))
            location = _locate(ahead, view, t)[0]
            assert int(location.location_flags) == int(ALL_LOCATED)
            np.testing.assert_allclose(_position(location), 2 * _direction((20, -10)), atol=1e-5)
            np.testing.assert_allclose(_matrix(location.pose.orientation), g @ _about_z(math.pi / 2), atol=1e-5)
            # VIEW seen from the gaze: the inverse turn
            back, sampled = _locate(view, gaze, t)
            assert int(back.location_flags) == int(ALL_LOCATED) and sampled == t
            np.testing.assert_allclose(_matrix(back.pose.orientation), g.T, atol=1e-5)
            np.testing.assert_allclose(_position(back), 0, atol=1e-6)
            # one gaze space from another: the pose in the action space alone
            between = _locate(ahead, gaze, t)[0]
            np.testing.assert_allclose(_position(between), [0, 0, -2], atol=1e-5)
            np.testing.assert_allclose(_matrix(between.pose.orientation), _about_z(math.pi / 2), atol=1e-5)


def test_only_the_latest_sync_and_the_latest_suggestion_count(x_display, out, monkeypatch):
    monkeypatch.setenv("XRTEST_GAZE_DEG", "10,10")
    with _instance("XR_KHR_opengl_enable", GAZE_EXT) as (instance, system):
        actions = Actions(instance, {"eyes": ["first", "second"], "other": ["third"]},
                          subactions={"second": ["/user/eyes_ext", "/user/hand/left"]})
        actions.suggest(PROFILE, {"first": GAZE_POSE, "second": GAZE_POSE})
        actions.suggest(PROFILE, {"second": GAZE_POSE, "third": GAZE_POSE})      # replaces the first
        with _session(instance, system) as session:
            frames = Frames(instance, session)
            actions.attach(session)
            view = _reference(session, xr.ReferenceSpaceType.VIEW)
            spaces = {name: actions.space(session, name) for name in ("first", "second", "third")}
            frames.poll()
            frames.frame()
            assert frames.states[-1] == "FOCUSED"
            t = frames.wait()

            def live() -> dict[str, tuple[bool, bool]]:
                return {name: (actions.active(session, name),
                               int(_locate(space, view, t)[0].location_flags) == int(ALL_LOCATED))
                        for name, space in spaces.items()}

            assert live() == {"first": (False, False), "second": (False, False), "third": (False, False)}
            actions.sync(session, "other")
            assert live() == {"first": (False, False), "second": (False, False), "third": (True, True)}
            actions.sync(session, "eyes")                           # replaces the previous sync's sets
            assert live() == {"first": (False, False), "second": (True, True), "third": (False, False)}
            actions.sync(session, "eyes", "other")
            assert live() == {"first": (False, False), "second": (True, True), "third": (True, True)}
            actions.sync(session)
            assert live() == {"first": (False, False), "second": (False, False), "third": (False, False)}
            # a set active only for a hand's subaction path does not carry the gaze
            xr.sync_actions(session, xr.ActionsSyncInfo(active_action_sets=[
                xr.ActiveActionSet(actions.sets["eyes"], _path(instance, "/user/hand/left"))]))
            assert live()["second"] == (False, False)
            xr.sync_actions(session, xr.ActionsSyncInfo(active_action_sets=[
                xr.ActiveActionSet(actions.sets["eyes"], _path(instance, "/user/eyes_ext"))]))
            assert live()["second"] == (True, True)
