"""Interrupted commands leave nothing partial: SIGTERM (and SIGHUP) are treated like Ctrl-C, and
``correct``'s image and its ``--report`` appear together or not at all.  Also: a report whose
metric is infinite (PSNR of identical images) is still valid JSON."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
FRACTIONS = (0.15, 0.4, 0.6, 0.75, 0.85, 0.92, 0.97, 1.02)


def _command(folder: Path) -> list[str]:
    return [sys.executable, "-m", "vrcorrect.apps.cli", "correct", str(folder / "in.png"), "-o", str(folder / "out.png"),
            "--report", str(folder / "report.json"), "--method", "fast", "--display", "desktop"]


def _input(folder: Path) -> np.ndarray:
    from skimage import data

    image = data.astronaut()[100:164, 180:244]
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(folder / "in.png")
    return image


def _signal_at(folder: Path, seconds: float, sig: int) -> tuple[int, str]:
    """Run ``correct`` on ``folder``'s input, send ``sig`` after ``seconds``; (status, stderr)."""
    _input(folder)
    proc = subprocess.Popen(_command(folder), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    time.sleep(seconds)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=300)
    return proc.returncode, err


def _strict_json(path: Path) -> dict:
    def refuse(constant: str):
        raise ValueError(f"not JSON: {constant}")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_sigterm_at_any_point_of_correct_leaves_all_or_nothing(tmp_path):
    """A run is timed once; then SIGTERM is sent at fractions of that time (during imports, the
    kernel, the solve, the metrics and the writing).  Each run ends either terminated (status 143,
    one line, nothing but the input in the folder: no image, no report, no temporary file) or
    complete (a readable image of the input's size and a valid report)."""
    image = _input(tmp_path / "timing")
    t0 = time.perf_counter()
    done = subprocess.run(_command(tmp_path / "timing"), capture_output=True, text=True, cwd=ROOT, timeout=300)
    total = time.perf_counter() - t0
    assert done.returncode == 0, done.stderr
    outcomes, codes = [], []
    for fraction in FRACTIONS:
        folder = tmp_path / f"at_{fraction}"
        returncode, err = _signal_at(folder, fraction * total, signal.SIGTERM)
        names = sorted(p.name for p in folder.iterdir())
        codes.append(returncode)
        # 143: the command's handler ran; -15: Python's default (before the handler is installed, or
        # after the command returned, while the interpreter exits)
        assert returncode in (0, 128 + signal.SIGTERM, -signal.SIGTERM), (fraction, returncode, err)
        if returncode == 128 + signal.SIGTERM:
            assert err.rstrip().splitlines()[-1] == "vrcorrect: terminated (SIGTERM)", err
        if names == ["in.png"]:
            assert returncode != 0, (fraction, err)
            outcomes.append("terminated")
        else:
            assert names == ["in.png", "out.png", "report.json"], (fraction, names)
            assert np.asarray(Image.open(folder / "out.png")).shape == image.shape
            assert "metrics" in _strict_json(folder / "report.json")
            outcomes.append("complete")
    # the signal did land mid-command, in the command's own handler (not only during the imports)
    assert (128 + signal.SIGTERM, "terminated") in zip(codes, outcomes), list(zip(codes, outcomes))


def test_sighup_is_handled_like_sigterm(tmp_path):
    """SIGHUP (a closed terminal) mid-run: exit 129, one line, nothing written.  Sent at fractions
    of a measured run, later ones first, until one lands inside the command."""
    _input(tmp_path / "timing")
    t0 = time.perf_counter()
    assert subprocess.run(_command(tmp_path / "timing"), capture_output=True, cwd=ROOT, timeout=300).returncode == 0
    total = time.perf_counter() - t0
    for fraction in (0.6, 0.45, 0.3):
        folder = tmp_path / f"at_{fraction}"
        returncode, err = _signal_at(folder, fraction * total, signal.SIGHUP)
        if returncode == 128 + signal.SIGHUP:
            assert err.rstrip().splitlines()[-1] == "vrcorrect: terminated (SIGHUP)", err
            assert sorted(p.name for p in folder.iterdir()) == ["in.png"]
            return
    pytest.fail(f"SIGHUP never landed inside the command (run of {total:.1f} s)")


def test_report_of_an_identical_image_is_valid_json_with_null_and_a_note(tmp_path):
    """A black image is its own best correction: PSNR is infinite, which JSON cannot hold; the
    report writes null and says why.  (The pupil is fixed: from a black image's light it would be
    7.5 mm, a minute of kernels that this test is not about.)"""
    from vrcorrect.apps.cli import main

    Image.fromarray(np.zeros((32, 32, 3), np.uint8)).save(tmp_path / "black.png")
    assert main(["correct", str(tmp_path / "black.png"), "-o", str(tmp_path / "out.png"), "--report",
                 str(tmp_path / "r.json"), "--method", "wiener", "--display", "desktop", "--pupil", "4"]) == 0
    report = _strict_json(tmp_path / "r.json")
    assert report["metrics"]["psnr"] is None
    assert any(note.startswith("metrics.psnr: null (inf") for note in report["notes"]), report["notes"]


def test_a_signal_that_python_wraps_is_still_a_termination(monkeypatch, capsys):
    """A real SIGTERM delivered while a class is created (as when a library is imported) lands in a
    descriptor's ``__set_name__``; Python 3.11 re-raises it as a RuntimeError caused by it.  The
    command still ends as terminated (143, one line), not as an internal error (as one CI run did)."""
    import os

    class Descriptor:
        def __set_name__(self, owner, name):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises here, at the next bytecode

    def command(args):
        class Imported:  # noqa: F841 (its creation is the point)
            field = Descriptor()
        return 0

    cli = _cli_running(monkeypatch, command)
    before = signal.getsignal(signal.SIGTERM)
    assert cli.main([]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: terminated (SIGTERM)"]
    assert signal.getsignal(signal.SIGTERM) is before


def _cli_running(monkeypatch, command):
    """``vrcorrect.apps.cli`` whose parser runs ``command(args)`` for any arguments."""
    import argparse

    from vrcorrect.apps import cli

    def parser():
        ap = argparse.ArgumentParser(prog="vrcorrect")
        ap.set_defaults(func=command)
        return ap

    monkeypatch.setattr(cli, "build_parser", parser)
    return cli


def _command_importing(monkeypatch, module_dir: Path, module: str, after):
    """``cli.main`` with a command that imports ``module`` from ``module_dir``, then calls ``after``."""
    import importlib

    monkeypatch.syspath_prepend(str(module_dir))

    def command(args):
        importlib.import_module(module)
        after()
        return 0

    return _cli_running(monkeypatch, command)


def test_a_signal_during_an_import_acts_when_the_import_is_done(tmp_path, monkeypatch, capsys):
    """A SIGTERM that lands while a module is imported (an extension's initialisation may run Python
    under native code that cannot pass an exception on; one CI run aborted with status -6 and a
    pybind11 exception) is held until the import is done: the module is whole, and the command then
    ends as terminated (143, one line)."""
    (tmp_path / "slow_import_mod.py").write_text(
        "import os, signal, time\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "t = time.monotonic()\n"
        "while time.monotonic() - t < 0.4:\n"
        "    pass\n"
        "DONE = True\n")
    reached = []
    cli = _command_importing(monkeypatch, tmp_path, "slow_import_mod",
                             lambda: (reached.append(True), time.sleep(5)))
    try:
        before = signal.getsignal(signal.SIGTERM)
        assert cli.main([]) == 128 + signal.SIGTERM
        assert sys.modules["slow_import_mod"].DONE is True
        assert reached == [True]                  # the import returned; the signal acted after it
        assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: terminated (SIGTERM)"]
        assert signal.getsignal(signal.SIGTERM) is before
    finally:
        sys.modules.pop("slow_import_mod", None)


def test_ctrl_c_during_an_import_is_an_interruption_after_it(tmp_path, monkeypatch, capsys):
    (tmp_path / "slow_import_int.py").write_text(
        "import os, signal, time\n"
        "os.kill(os.getpid(), signal.SIGINT)\n"
        "t = time.monotonic()\n"
        "while time.monotonic() - t < 0.3:\n"
        "    pass\n"
        "DONE = True\n")
    cli = _command_importing(monkeypatch, tmp_path, "slow_import_int", lambda: time.sleep(5))
    try:
        assert cli.main([]) == 130
        assert sys.modules["slow_import_int"].DONE is True
        assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: interrupted"]
    finally:
        sys.modules.pop("slow_import_int", None)


def test_a_signal_the_process_ignores_stays_ignored(monkeypatch, capsys):
    """Started under ``nohup`` (SIGHUP ignored), a command is not ended by a hang-up."""
    import os

    def command(args):
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(0.3)
        return 0

    cli = _cli_running(monkeypatch, command)
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        assert cli.main([]) == 0
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)


def test_a_signal_in_a_librarys_code_acts_when_the_command_runs_again(tmp_path, monkeypatch, capsys):
    """A SIGTERM that lands in an installed library's Python code (which native code may have called,
    as torch's operators do) waits until the library returns to the command's own code."""
    library = tmp_path / "site-packages"
    library.mkdir()
    (library / "slow_library_mod.py").write_text(
        "import os, signal, time\n"
        "FINISHED = []\n"
        "def work():\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    t = time.monotonic()\n"
        "    while time.monotonic() - t < 0.4:\n"
        "        pass\n"
        "    FINISHED.append(True)\n")
    monkeypatch.syspath_prepend(str(library))
    import slow_library_mod

    reached = []
    cli = _command_importing(monkeypatch, library, "slow_library_mod",
                             lambda: (slow_library_mod.work(), reached.append(True), time.sleep(5)))
    try:
        assert cli.main([]) == 128 + signal.SIGTERM
        assert slow_library_mod.FINISHED == [True] and reached == [True]
        assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: terminated (SIGTERM)"]
    finally:
        sys.modules.pop("slow_library_mod", None)


def test_a_held_signal_acts_after_the_longest_hold(tmp_path, monkeypatch, capsys):
    """A library that never returns (a loop in its own code) is still ended: the signal is held at
    most ``HOLD_MAX_S``."""
    from vrcorrect.plumbing import signals

    monkeypatch.setattr(signals, "HOLD_MAX_S", 0.5)
    library = tmp_path / "site-packages"
    library.mkdir()
    (library / "endless_library_mod.py").write_text(
        "import os, signal, time\n"
        "def work():\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    t = time.monotonic()\n"
        "    while time.monotonic() - t < 60:\n"
        "        pass\n")
    monkeypatch.syspath_prepend(str(library))
    import endless_library_mod

    cli = _command_importing(monkeypatch, library, "endless_library_mod", endless_library_mod.work)
    try:
        t0 = time.monotonic()
        assert cli.main([]) == 128 + signal.SIGTERM
        assert time.monotonic() - t0 < 10
    finally:
        sys.modules.pop("endless_library_mod", None)


def test_vrcorrects_own_code_is_never_held_where_it_is_installed(monkeypatch):
    """Installed from a wheel, vrcorrect itself lives in site-packages: a signal in its own code still
    acts at once, one in another library's code waits."""
    from types import SimpleNamespace

    from vrcorrect.plumbing import signals

    monkeypatch.setattr(signals, "OWN_CODE", "/usr/lib/python3/site-packages/vrcorrect/")

    def frame(path):
        return SimpleNamespace(f_code=SimpleNamespace(co_filename=path), f_back=None)

    assert not signals.hold_here(frame("/usr/lib/python3/site-packages/vrcorrect/solvers/admm.py"))
    assert signals.hold_here(frame("/usr/lib/python3/site-packages/torch/nn/modules/module.py"))
    assert not signals.hold_here(frame("/usr/lib/python3.11/threading.py"))


def test_a_signal_held_while_outputs_are_written_leaves_none(tmp_path, monkeypatch, capsys):
    """A SIGHUP that lands while a library writes a command's outputs (an image encoder, say) is held
    there; the outputs are then not committed: the command ends as terminated (129) and leaves no
    output and no temporary file (one CI run found both outputs beside a 129)."""
    from vrcorrect.plumbing.fileio import write_together

    library = tmp_path / "site-packages"
    library.mkdir()
    (library / "slow_writer_mod.py").write_text(
        "import os, signal, time\n"
        "def write(path):\n"
        "    os.kill(os.getpid(), signal.SIGHUP)\n"
        "    t = time.monotonic()\n"
        "    while time.monotonic() - t < 0.3:\n"
        "        pass\n"
        "    path.write_text('written')\n")
    monkeypatch.syspath_prepend(str(library))
    import slow_writer_mod

    out = tmp_path / "out"
    out.mkdir()

    def command(args):
        write_together([(out / "a.txt", slow_writer_mod.write), (out / "b.txt", slow_writer_mod.write)])
        return 0

    cli = _cli_running(monkeypatch, command)
    try:
        assert cli.main([]) == 128 + signal.SIGHUP
        assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: terminated (SIGHUP)"]
        assert sorted(p.name for p in out.iterdir()) == []
    finally:
        sys.modules.pop("slow_writer_mod", None)


@pytest.fixture
def other_thread():
    """A running thread besides the main one (a BLAS worker's stand-in: a real thread a signal can be
    sent to with ``pthread_kill``), ended when the test is."""
    import threading

    release = threading.Event()
    worker = threading.Thread(target=release.wait, daemon=True)
    worker.start()
    yield worker
    release.set()
    worker.join(timeout=5)


def _writes_two(out: Path):
    """A command that writes ``a.txt`` and ``b.txt`` into ``out`` together (``write_together``)."""
    from vrcorrect.plumbing import fileio

    def command(args):
        fileio.write_together([(out / "a.txt", lambda p: p.write_text("a")),
                               (out / "b.txt", lambda p: p.write_text("b"))])
        return 0

    return command


def test_a_signal_delivered_to_another_thread_waits_for_the_renames(tmp_path, monkeypatch, capsys, other_thread):
    """The kernel may deliver a SIGTERM to any thread that does not block it (a BLAS worker, say);
    Python then runs the handler in the main thread, whose signal mask does not stop it.  While a
    command's outputs are renamed into place it still waits: both outputs appear, then the command
    ends as terminated (143).  Before, it acted between the two renames and left one output."""
    import os

    from vrcorrect.plumbing import fileio

    real_replace = os.replace
    renamed = []

    def replace(src, dst):
        real_replace(src, dst)
        renamed.append(Path(dst).name)
        if len(renamed) == 1:
            signal.pthread_kill(other_thread.ident, signal.SIGTERM)
            t = time.monotonic()
            while time.monotonic() - t < 0.3:  # the main thread runs bytecode: the handler's chance
                pass

    monkeypatch.setattr(fileio.os, "replace", replace)
    out = tmp_path / "out"
    out.mkdir()

    command = _writes_two(out)
    cli = _cli_running(monkeypatch, command)
    assert cli.main([]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: terminated (SIGTERM)"]
    assert renamed == ["a.txt", "b.txt"]
    assert sorted(p.name for p in out.iterdir()) == ["a.txt", "b.txt"]


def test_a_signal_in_the_renames_after_an_error_still_terminates(tmp_path, monkeypatch, capsys, other_thread):
    """A SIGTERM that arrived while the renames ran is not lost when they fail (an output appeared
    meanwhile): the command ends as terminated, not with the error, and a later command's renames
    are not cut short by it."""
    from vrcorrect.plumbing import fileio
    from vrcorrect.plumbing.signals import signals_deferred

    def command(args):
        with signals_deferred():
            signal.pthread_kill(other_thread.ident, signal.SIGTERM)
            time.sleep(0.2)
            raise fileio.InputError("out.txt: file exists; pass --force to overwrite it")

    cli = _cli_running(monkeypatch, command)
    assert cli.main([]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: terminated (SIGTERM)"]
    with signals_deferred():
        pass                                   # nothing left over to act on


@pytest.mark.parametrize("nth", [1, 2])
def test_a_signal_as_a_temporary_file_is_made_leaves_none(tmp_path, monkeypatch, capsys, nth):
    """A SIGTERM that lands just after the ``nth`` temporary output file is made (before it was listed
    for removal: one CI run found ``.out.png.*.png`` beside a 143) leaves no output and no temporary
    file: the command ends as terminated."""
    import os
    import tempfile

    from vrcorrect.plumbing import fileio

    real_mkstemp = tempfile.mkstemp
    made = []

    def mkstemp(*args, **kwargs):
        fd, name = real_mkstemp(*args, **kwargs)
        if not name.endswith(".probe"):
            made.append(name)
            if len(made) == nth:
                os.kill(os.getpid(), signal.SIGTERM)
                t = time.monotonic()
                while time.monotonic() - t < 0.2:  # bytecode runs: the handler's chance to act here
                    pass
        return fd, name

    monkeypatch.setattr(fileio.tempfile, "mkstemp", mkstemp)
    out = tmp_path / "out"
    out.mkdir()

    command = _writes_two(out)
    cli = _cli_running(monkeypatch, command)
    assert cli.main([]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip().splitlines() == ["vrcorrect: terminated (SIGTERM)"]
    assert len(made) == 2                      # both were made: the signal waited for the listing
    assert sorted(p.name for p in out.iterdir()) == []


def test_a_signal_as_the_probe_is_made_leaves_no_probe(tmp_path, monkeypatch, capsys):
    """The writability probe (made and removed before any work) is not stranded by a signal either."""
    import os
    import tempfile

    from vrcorrect.plumbing import fileio

    real_mkstemp = tempfile.mkstemp

    def mkstemp(*args, **kwargs):
        fd, name = real_mkstemp(*args, **kwargs)
        if name.endswith(".probe"):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.2)
        return fd, name

    monkeypatch.setattr(fileio.tempfile, "mkstemp", mkstemp)
    out = tmp_path / "out"
    out.mkdir()
    cli = _cli_running(monkeypatch, lambda args: fileio.write_text_atomic(out / "a.txt", "a") or 0)
    assert cli.main([]) == 128 + signal.SIGTERM
    assert sorted(p.name for p in out.iterdir()) == []
