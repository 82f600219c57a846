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


def test_designs_run_off_the_callers_thread_and_polling_never_waits(rx, monkeypatch):
    """While the worker is held inside a design, poll returns at once, nothing installed; once let
    go, the design arrives."""
    entered, release = threading.Event(), threading.Event()
    real = ES.build_eye_model
    callers = []

    def held(eye, display, options):
        callers.append(threading.current_thread().name)
        entered.set()
        assert release.wait(60)
        return real(eye, display, options)

    monkeypatch.setattr(ES, "build_eye_model", held)
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.adjust("right", (0.25, 0.0, 0.0))
        assert entered.wait(60)
        for _ in range(20):
            assert source.poll() == ([], []) and source.busy
        release.set()
        assert source.wait(60)
        updates, _ = source.poll()
        assert [u.model.eye.sphere_D for u in updates] == [-1.75]
        assert callers == ["vrcorrect-eye-source"]
    finally:
        release.set()
        source.close()


def test_only_the_newest_of_queued_edits_is_designed(rx, monkeypatch):
    entered, release = threading.Event(), threading.Event()
    real = ES.build_eye_model
    designed = []

    def held(eye, display, options):
        entered.set()
        assert release.wait(60)
        designed.append(eye.sphere_D)
        return real(eye, display, options)

    monkeypatch.setattr(ES, "build_eye_model", held)
    source = EyeSource(rx, get_display("quest2"), OPTIONS, eyes=("right",))
    try:
        source.adjust("right", (0.25, 0.0, 0.0))             # holds the worker
        assert entered.wait(60)
        for sphere in (-3.0, -4.0, -5.0):
            doc = json.loads(json.dumps(RX))
            doc["right"]["sphere_D"] = sphere
            edit(rx, doc)
            source.poll()
        release.set()
        assert source.wait(120)
        assert designed == [-1.75, -4.75]                    # the live change, then only the last edit
    finally:
        release.set()
        source.close()
