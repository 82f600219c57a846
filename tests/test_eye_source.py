"""The eye source: the prescription watched once, every eye designed off the caller's thread, the
last good prescription kept on a bad edit, a live change refused at once when out of range."""

from __future__ import annotations

import json
import os
import threading

import pytest

from vrcorrect.plumbing.errors import VrcorrectError
from vrcorrect.runtime import eye_source as ES
from vrcorrect.runtime.eye_model import CorrectorOptions
from vrcorrect.runtime.eye_source import EyeSource
from vrcorrect.specs.display import get_display

RX = {"schema": "vrcorrect.prescription/1",
      "right": {"sphere_D": -2.0, "cylinder_D": -1.0, "axis_deg": 30, "pupil_diameter_mm": 4.0},
      "left": {"sphere_D": 1.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 3.0}}
OPTIONS = CorrectorOptions(filter="admm")


@pytest.fixture
def rx(tmp_path, monkeypatch):
    monkeypatch.setattr(ES, "POLL_INTERVAL_S", 0.0)
    path = tmp_path / "rx.json"
    path.write_text(json.dumps(RX))
    return path


def edit(path, doc_or_text):
    path.write_text(doc_or_text if isinstance(doc_or_text, str) else json.dumps(doc_or_text))
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))     # visible on coarse clocks


def drain(source: EyeSource):
    """Poll once to start what is due, wait for the worker, poll again for the results."""
    first = source.poll()
    assert source.wait(120)
    second = source.poll()
    return first[0] + second[0], first[1] + second[1]


class Held:
    """``build_eye_model`` replaced by one that records each design (sphere, thread) and, from the
    ``hold_from``-th design on, signals ``entered`` and waits for ``release``."""

    def __init__(self, monkeypatch, hold_from: int = 1):
        self.entered, self.release = threading.Event(), threading.Event()
        self.designed: list[float] = []
        self.threads: list[str] = []
        real = ES.build_eye_model

        def held(eye, display, options, **kw):
            self.designed.append(eye.sphere_D)
            self.threads.append(threading.current_thread().name)
            if len(self.designed) >= hold_from:
                self.entered.set()
                assert self.release.wait(60)
            return real(eye, display, options, **kw)

        monkeypatch.setattr(ES, "build_eye_model", held)


def test_an_edit_is_designed_for_every_eye_and_a_bad_one_keeps_the_last_good(rx):
    source = EyeSource(rx, get_display("quest2"), OPTIONS)
    try:
        assert source.poll() == ([], [])                     # nothing changed
        doc = json.loads(json.dumps(RX))
        doc["right"]["sphere_D"] = -3.0
        edit(rx, doc)
        updates, messages = drain(source)
        assert messages == [] and sorted(u.eye for u in updates) == ["left", "right"]
        right = next(u for u in updates if u.eye == "right")
        assert right.model.eye.sphere_D == -3.0 and right.reason == "reload" and right.seconds > 0
        assert source.prescription.right.sphere_D == -3.0
        doc["right"]["sphere_D"] = "oops"
        edit(rx, doc)
        updates, messages = drain(source)
        assert updates == [] and len(messages) == 1 and "not reloaded" in messages[0] and "sphere_D" in messages[0]
        assert source.prescription.right.sphere_D == -3.0    # the last good one
        doc["right"]["sphere_D"] = -30.0                      # valid JSON, out of range: every eye or none
        edit(rx, doc)
        updates, messages = drain(source)
        assert updates == [] and "not reloaded" in messages[0]
    finally:
        source.close()


def test_a_live_change_is_refused_at_once_or_designed_on_the_worker(rx):
    source = EyeSource(rx, get_display("quest2"), OPTIONS)
    try:
        with pytest.raises(VrcorrectError, match="sphere"):
            source.adjust("right", (-30.0, 0.0, 0.0))
        assert not source.busy                                # nothing was queued
        e = source.adjust("right", (-0.5, 0.0, 190.0))
        assert e.sphere_D == -2.5 and e.axis_deg == pytest.approx(40.0)
        updates, messages = drain(source)
        assert messages == [] and [u.eye for u in updates] == ["right"] and updates[0].reason == "adjust"
        assert updates[0].model.eye == e and source.offsets["right"] == (-0.5, 0.0, 190.0)
        doc = json.loads(json.dumps(RX))
        doc["right"]["sphere_D"] = -1.0
        edit(rx, doc)                                         # a reload keeps the live change on top
        updates, _ = drain(source)
        assert next(u for u in updates if u.eye == "right").model.eye.sphere_D == -1.5
    finally:
        source.close()


def test_a_synchronous_source_designs_on_the_callers_thread_and_hands_over_at_once(rx, monkeypatch):
    """``worker=False`` (a library user's, and a corrector's own): no thread; a live change and a
    reload are designed inside the call and handed over by the next ``take``/``poll``; the offsets
    asked for and those handed over are told apart."""
    held = Held(monkeypatch, hold_from=10**6)                # records, never holds
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",), worker=False)
    try:
        assert source.synchronous and not source.busy and source.wait(0) and source.join(0)
        assert source.handed_offset("right") == (0.0, 0.0, 0.0)
        source.adjust("right", (0.25, 0.0, 0.0))
        assert held.threads == [threading.current_thread().name]
        assert source.offsets["right"] == (0.25, 0.0, 0.0) and source.handed_offset("right") == (0.0, 0.0, 0.0)
        updates, messages = source.take()
        assert messages == [] and [u.model.eye.sphere_D for u in updates] == [-1.75]
        assert source.handed_offset("right") == (0.25, 0.0, 0.0)
        doc = json.loads(json.dumps(RX))
        doc["right"]["sphere_D"] = -3.0
        edit(rx, doc)
        updates, messages = source.poll()                    # read and designed within the call
        assert messages == [] and [(u.reason, u.model.eye.sphere_D) for u in updates] == [("reload", -2.75)]
        assert source.prescription.right.sphere_D == -3.0 and held.threads[-1] == threading.current_thread().name
    finally:
        source.close()


def test_a_change_whose_design_fails_is_not_kept_for_the_next_reload(rx):
    """A live change in range whose design then fails leaves the offsets as they were, so that a
    later reload does not design the refused eye after all."""
    def design(eye, eye_rx, prescription):
        if eye_rx.sphere_D < -2.0:
            raise VrcorrectError(f"no design below -2 D (asked {eye_rx.sphere_D})")
        return ES.build_eye_model(eye_rx, get_display("quest2"), OPTIONS)

    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",), design=design, worker=False)
    try:
        source.adjust("right", (-0.5, 0.0, 0.0))
        updates, messages = source.take()
        assert updates == [] and messages == ["right eye unchanged: no design below -2 D (asked -2.5)"]
        assert source.offsets["right"] == (0.0, 0.0, 0.0)
    finally:
        source.close()


def test_the_wearers_age_comes_from_the_prescription_unless_the_options_give_it(rx, monkeypatch):
    """The default design passes the prescription's ``age_years`` (the pupil's formula), the
    options' when they give one: a reload and the start design what a corrector's own build does."""
    ages = []
    real = ES.build_eye_model

    def recording(eye, display, options, **kw):
        ages.append(kw.get("age_years"))
        return real(eye, display, options, **kw)

    monkeypatch.setattr(ES, "build_eye_model", recording)
    doc = json.loads(json.dumps(RX))
    doc["age_years"] = 63
    edit(rx, doc)
    for options, expected in ((OPTIONS, 63), (CorrectorOptions(filter="admm", age_years=30), 30)):
        source = EyeSource(rx, get_display("quest2"), options, eyes=("right",), worker=False)
        try:
            source.build("right")
            source.adjust("right", (0.25, 0.0, 0.0))
            assert ages[-2:] == [expected, expected]
        finally:
            source.close()


def test_the_options_age_gives_eyes_that_state_no_accommodation_that_ages_amplitude(rx, monkeypatch):
    """An age in the options (the OpenXR layer's ``age_years``) is the wearer's for the eyes' focus too:
    each eye that states no ``accommodation_D`` is designed with the amplitude expected at that age,
    at the start and after a reload; a stated amplitude stays."""
    eyes = []
    real = ES.build_eye_model

    def recording(eye, display, options, **kw):
        eyes.append((eye, kw.get("age_years")))
        return real(eye, display, options, **kw)

    monkeypatch.setattr(ES, "build_eye_model", recording)
    doc = json.loads(json.dumps(RX))
    doc["left"]["accommodation_D"] = 1.0                                  # stated: kept
    edit(rx, doc)
    source = EyeSource(rx, get_display("quest2"), CorrectorOptions(filter="admm", age_years=40),
                       eyes=("right", "left"), worker=False)
    try:
        assert source.prescription.right.accommodation_D == pytest.approx(6.5)   # 18.5 - 0.3 x 40
        assert source.prescription.left.accommodation_D == 1.0
        source.build("right")
        assert eyes[-1][0].accommodation_D == pytest.approx(6.5) and eyes[-1][1] == 40
        doc["right"]["sphere_D"] = -2.5                                   # an edit: the reload follows the age too
        edit(rx, doc)
        updates, messages = drain(source)
        assert not messages and {u.eye for u in updates} == {"right", "left"}
        assert [round(e.accommodation_D, 6) for e, _ in eyes[-2:]] in ([6.5, 1.0], [1.0, 6.5])
        assert source.prescription.right.sphere_D == -2.5 and source.prescription.right.accommodation_D == 6.5
    finally:
        source.close()
    without = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",), worker=False)   # no age anywhere: 0
    try:
        assert without.prescription.right.accommodation_D == 0.0
    finally:
        without.close()


def test_designs_run_off_the_callers_thread_and_polling_never_waits(rx, monkeypatch):
    """While the worker is held inside a design, poll returns at once, nothing installed; once let
    go, the design arrives."""
    held = Held(monkeypatch)
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.adjust("right", (0.25, 0.0, 0.0))
        assert held.entered.wait(60)
        for _ in range(20):
            assert source.poll() == ([], []) and source.busy
        held.release.set()
        assert source.wait(60)
        updates, _ = source.poll()
        assert [u.model.eye.sphere_D for u in updates] == [-1.75]
        assert held.threads == ["vrcorrect-eye-source"]
    finally:
        held.release.set()
        source.close()


def test_only_the_newest_of_queued_edits_is_designed(rx, monkeypatch):
    held = Held(monkeypatch)
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.adjust("right", (0.25, 0.0, 0.0))             # holds the worker
        assert held.entered.wait(60)
        for sphere in (-3.0, -4.0, -5.0):
            doc = json.loads(json.dumps(RX))
            doc["right"]["sphere_D"] = sphere
            edit(rx, doc)
            source.poll()
        held.release.set()
        assert source.wait(120)
        assert held.designed == [-1.75, -4.75]               # the live change, then only the last edit
    finally:
        held.release.set()
        source.close()


def test_design_all_designs_every_eye_on_the_worker_and_hands_them_over_together(rx, monkeypatch):
    """The start without waiting: the display (a function: loading one takes seconds) is chosen and
    every eye designed on the worker; poll hands over no eye until all are designed, then all at once."""
    held = Held(monkeypatch, hold_from=2)                   # the first eye designed, the second held
    display_threads = []

    def display():
        display_threads.append(threading.current_thread().name)
        return get_display("quest2")

    source = EyeSource(rx, display, OPTIONS)
    try:
        assert display_threads == [] and source.reloads_started == 0
        source.design_all()
        assert held.entered.wait(60)
        assert source.poll() == ([], []) and source.busy     # one eye ready: not handed over alone
        held.release.set()
        assert source.wait(120)
        updates, messages = source.poll()
        assert messages == [] and [u.eye for u in updates] == ["left", "right"]
        assert all(u.reason == "start" and u.offset == (0.0, 0.0, 0.0) for u in updates)
        assert [u.model.eye for u in updates] == [source.prescription.left, source.prescription.right]
        assert held.threads == ["vrcorrect-eye-source"] * 2
        assert display_threads == ["vrcorrect-eye-source"]  # once, on the worker
        assert source.display.name == "quest2" and len(display_threads) == 1
    finally:
        held.release.set()
        source.close()


def test_a_refused_start_is_one_message_and_no_eye_and_the_display_is_asked_again(rx):
    """Every eye or none: one eye refused by ``check`` refuses the start; a display that could not
    be loaded is asked for again by the next design."""
    def check(e):
        if e.sphere_D > 0:                                  # the left eye
            raise VrcorrectError("too strong")

    source = EyeSource(rx, get_display("quest2"), OPTIONS, check=check)
    try:
        source.design_all()
        assert source.wait(120)
        updates, messages = source.poll()
        assert updates == [] and len(messages) == 1 and "not designed" in messages[0] and "too strong" in messages[0]
    finally:
        source.close()

    attempts = []

    def display():
        attempts.append(1)
        if len(attempts) == 1:
            raise VrcorrectError("no such display")
        return get_display("quest2")

    source = EyeSource(rx, display, OPTIONS, eyes=("right",))
    try:
        source.design_all()
        updates, messages = drain(source)
        assert updates == [] and len(messages) == 1 and "no such display" in messages[0]
        source.design_all()
        updates, messages = drain(source)
        assert messages == [] and [u.eye for u in updates] == ["right"] and len(attempts) == 2
    finally:
        source.close()


def test_reloads_started_counts_the_changes_poll_saw(rx):
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.poll()
        assert source.reloads_started == 0
        edit(rx, "{ not json")
        source.poll()
        assert source.reloads_started == 1
        source.poll()                                       # the same file: no new reload
        assert source.reloads_started == 1
        assert source.wait(120)
    finally:
        source.close()


def test_close_drops_the_queued_designs(rx, monkeypatch):
    """``close(wait=False)`` returns with a design running; it finishes unused and what was queued
    behind it is never designed."""
    held = Held(monkeypatch)
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.adjust("right", (0.25, 0.0, 0.0))
        assert held.entered.wait(60)
        source.adjust("right", (0.5, 0.0, 0.0))             # queued behind the running one
        source.close(wait=False)
        assert source.busy                                  # still inside the first design
        held.release.set()
        assert source.wait(60)
        assert held.designed == [-1.75]                     # the queued one was dropped
    finally:
        held.release.set()
        source.close()


def test_join_waits_for_the_running_design_and_says_whether_the_worker_ended(rx, monkeypatch):
    held = Held(monkeypatch)
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.adjust("right", (0.25, 0.0, 0.0))
        assert held.entered.wait(60)
        source.close(wait=False)
        assert source.join(0.0) is False and source.join(0.2) is False    # held inside the design
        held.release.set()
        assert source.join(60) is True
    finally:
        held.release.set()
        source.close()


class LayerHeldInABuild:
    """A layer engine (logging to ``log``) whose eye source is held inside a design (``held``)."""

    def __init__(self, rx, monkeypatch, tmp_path):
        from vrcorrect.runtime.layer import engine as xrlayer
        from vrcorrect.runtime.layer.config import LOG_ENV

        self.held = Held(monkeypatch)
        self.log = tmp_path / "layer.log"
        self.engine = xrlayer.Engine(env={LOG_ENV: str(self.log)})
        self.source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
        self.engine._source = self.source
        self.source.adjust("right", (0.25, 0.0, 0.0))

    def release(self):
        self.held.release.set()
        self.source.close()


def test_the_layers_end_waits_for_a_build_it_let_go(rx, monkeypatch, tmp_path):
    """The layer lets its source go without waiting when a session ends; the instance's end
    (``Engine.close``) then waits for the design still running, so no worker outlives it."""
    layer = LayerHeldInABuild(rx, monkeypatch, tmp_path)
    engine, source, held, log = layer.engine, layer.source, layer.held, layer.log
    try:
        assert held.entered.wait(60)
        engine._close_source()                              # the session ends: let go, no wait
        assert engine._source is None and source.busy
        closing = threading.Thread(target=engine.close)
        closing.start()
        closing.join(0.5)
        assert closing.is_alive()                           # still waiting for the held design
        held.release.set()
        closing.join(60)
        assert not closing.is_alive() and source.join(0.0)
        text = log.read_text()
        assert "waiting for the eye models being built to finish" in text and "still running" not in text
    finally:
        layer.release()


def test_the_layers_end_gives_up_waiting_after_its_limit(rx, monkeypatch, tmp_path):
    from vrcorrect.runtime.layer import engine as xrlayer

    monkeypatch.setattr(xrlayer, "CLOSE_WAIT_S", 0.3)
    layer = LayerHeldInABuild(rx, monkeypatch, tmp_path)
    try:
        assert layer.held.entered.wait(60)
        layer.engine.close()                                # returns while the design is held
        assert layer.source.busy
        assert "still running after 0.3 s; closing anyway" in layer.log.read_text()
    finally:
        layer.release()


def test_an_edit_written_in_place_is_read_once_when_written(rx, monkeypatch):
    """An editor that saves in place truncates the file, then writes it. Seen while empty, the file
    is not read at once: the worker waits for its stamp to settle and reads it written, so a bad
    edit gives one message, about what was written, not a second one about an empty file."""
    monkeypatch.setattr(ES, "SETTLE_S", 0.3)
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.poll()
        edit(rx, "")                                        # truncated
        assert source.poll() == ([], [])                    # the change is seen; the worker settles
        doc = json.loads(json.dumps(RX))
        doc["right"]["sphere_D"] = "oops"
        edit(rx, doc)                                       # written, within the settling time
        updates, messages = drain(source)
        assert updates == [] and len(messages) == 1, messages
        assert "not reloaded" in messages[0] and "sphere_D" in messages[0], messages
        assert source.poll() == ([], [])                    # the file read is not read again
        assert source.wait(10) and source.poll() == ([], [])
    finally:
        source.close()
