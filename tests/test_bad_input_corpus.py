"""The bad-input corpus: what careful new users typed, each ending in a clear error (exit status
2, one ``vrcorrect: error:`` line naming the field or file - a prescription's problems each
listed below it - nothing written) or a correct result
(exit 0, the output written).  Runs in-process through ``vrcorrect.apps.cli.main``; the refusals come
before any kernel is built, so the corpus is quick."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps import cli

GOOD_RX = {"schema": "vrcorrect.prescription/1",
           "right": {"sphere_D": -1.0, "cylinder_D": -0.5, "axis_deg": 90, "pupil_diameter_mm": 3.0},
           "left": {"sphere_D": -1.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 3.0}}


def _rx(**right) -> str:
    doc = json.loads(json.dumps(GOOD_RX))
    doc["right"].update(right)
    return json.dumps(doc)


# name -> text of a prescription file that must be refused, and a word the error must hold
BAD_RX = {
    "sphere too strong": (_rx(sphere_D=-25), "sphere_D"),
    "cylinder too strong": (_rx(cylinder_D=-12), "cylinder_D"),
    "axis 181": (_rx(axis_deg=181), "axis_deg"),
    "axis negative": (_rx(axis_deg=-5), "axis_deg"),
    "pupil 0.5 mm": (_rx(pupil_diameter_mm=0.5), "pupil_diameter_mm"),
    "pupil 12 mm": (_rx(pupil_diameter_mm=12), "pupil_diameter_mm"),
    "sphere as text": (_rx(sphere_D="-2"), "sphere_D"),
    "sphere NaN": (_rx(sphere_D=float("nan")), "sphere_D"),
    "unknown field": (_rx(spehre_D=-1), "spehre_D"),
    "accommodation negative": (_rx(accommodation_D=-1), "accommodation_D"),
    "no schema": (json.dumps({k: v for k, v in GOOD_RX.items() if k != "schema"}), "schema"),
    "wrong schema": (json.dumps({**GOOD_RX, "schema": "vrcorrect.prescription/9"}), "schema"),
    "no left eye": (json.dumps({k: v for k, v in GOOD_RX.items() if k != "left"}), "left"),
    "a list": ("[1, 2, 3]", "object"),
    "empty file": ("", "empty"),
    "trailing comma": ('{"schema": "vrcorrect.prescription/1",\n "right": {"sphere_D": -1,\n },\n}', "line 2"),
    "duplicate key": ('{"schema": "vrcorrect.prescription/1", "schema": "x"}', "twice"),
    "not JSON": ("sphere -2, cylinder -1", "invalid JSON"),
}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("corpus")
    out = {"dir": d}
    Image.fromarray(np.full((12, 12, 3), 120, np.uint8)).save(d / "small.png")
    (d / "text.png").write_text("this is not a picture")
    (d / "empty.png").write_bytes(b"")
    (d / "folder.png").mkdir()
    Image.fromarray(np.full((6, 6, 3), 90, np.uint8)).save(d / "taken.png")
    (d / "good_rx.json").write_text(json.dumps(GOOD_RX))
    (d / "latin1_rx.json").write_bytes('{"schema": "vrcorrect.prescription/1", "notes": "\xe9"}'.encode("latin-1"))
    for name, (text, _) in BAD_RX.items():
        (d / (name.replace(" ", "_") + ".json")).write_text(text)
    return out


def _refused(argv: list[str], words: str, capsys, folder: Path) -> None:
    before = sorted(p.name for p in folder.iterdir())
    code = cli.main(argv)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, (argv, code, err)
    # one error line; a prescription with problems lists each below it ("  - field = value ...")
    assert lines[0].startswith("vrcorrect: error:") and all(line.startswith("  - ") for line in lines[1:]), err
    assert words.lower() in err.lower(), (words, err)
    assert "Traceback" not in err
    assert sorted(p.name for p in folder.iterdir()) == before, "something was written"


@pytest.mark.parametrize("name", sorted(BAD_RX))
def test_a_bad_prescription_is_refused_by_correct(name, files, capsys):
    d = files["dir"]
    _refused(["correct", str(d / "small.png"), "-o", str(d / "out.png"), "--rx",
              str(d / (name.replace(" ", "_") + ".json")), "--method", "wiener"], BAD_RX[name][1], capsys, d)


@pytest.mark.parametrize("name", sorted(BAD_RX))
def test_a_bad_prescription_is_refused_by_rx_validate(name, files, capsys):
    d = files["dir"]
    _refused(["rx", "validate", str(d / (name.replace(" ", "_") + ".json"))], BAD_RX[name][1], capsys, d)


CLI_CASES = [
    # (id, argv with {d} for the corpus folder, word the one-line error holds)
    ("missing input", ["correct", "{d}/nope.png", "-o", "{d}/out.png"], "no such file"),
    ("input is a text file", ["correct", "{d}/text.png", "-o", "{d}/out.png"], "text.png"),
    ("input is empty", ["correct", "{d}/empty.png", "-o", "{d}/out.png"], "empty.png"),
    ("input is a folder", ["correct", "{d}/folder.png", "-o", "{d}/out.png"], "directory"),
    ("output exists", ["correct", "{d}/small.png", "-o", "{d}/taken.png"], "--force"),
    ("output is a jpeg", ["correct", "{d}/small.png", "-o", "{d}/out.jpg"], ".png"),
    ("output folder missing", ["correct", "{d}/small.png", "-o", "{d}/no/such/out.png"], "does not exist"),
    ("output in /proc", ["correct", "{d}/small.png", "-o", "/proc/out.png"], "cannot create"),
    ("report not json", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--report", "{d}/r.txt"], "--report"),
    ("report exists", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--report", "{d}/good_rx.json"], "--force"),
    ("contrast 0", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--contrast", "0"], "--contrast"),
    ("contrast 2", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--contrast", "2"], "--contrast"),
    ("iterations 0", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--iterations", "0"], "--iterations"),
    ("iterations for wiener", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--method", "wiener",
                               "--iterations", "5"], "--iterations"),
    ("tolerance 1.5", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--tolerance", "1.5"], "--tolerance"),
    ("tolerance for paper", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--method", "paper",
                             "--tolerance", "0.1"], "--tolerance"),
    ("model without learned", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--model", "{d}/m.onnx"],
     "--model"),
    ("learned model missing", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--method", "learned",
                               "--model", "{d}/m.onnx"], "m.onnx"),
    ("unknown display", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--display", "holodeck"], "holodeck"),
    ("display profile missing", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--display", "{d}/p.json"],
     "p.json"),
    ("rx missing", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--rx", "{d}/nope.json"], "nope.json"),
    ("rx not UTF-8", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--rx", "{d}/latin1_rx.json"], "UTF-8"),
    ("distance negative", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--distance-m", "-1"], "distance"),
    ("energy fraction 2", ["correct", "{d}/small.png", "-o", "{d}/out.png", "--energy-fraction", "2"],
     "energy"),
    ("simulate output exists", ["simulate", "{d}/small.png", "-o", "{d}/taken.png"], "--force"),
    ("simulate missing input", ["simulate", "{d}/nope.png", "-o", "{d}/out.png"], "no such file"),
    ("render frames 0", ["render", "{d}/small.png", "-o", "{d}/out.png", "--frames", "0"], "--frames"),
    ("render frames text", ["render", "{d}/small.png", "-o", "{d}/out.png", "--frames", "many"], "--frames"),
    ("render k 65", ["render", "{d}/small.png", "-o", "{d}/out.png", "--iterations-per-frame", "65"],
     "--iterations-per-frame"),
    ("render k with fft", ["render", "{d}/small.png", "-o", "{d}/out.png", "--filter", "fft",
                           "--iterations-per-frame", "4"], "only with --filter admm or fista"),
    ("render cold iterations -1", ["render", "{d}/small.png", "-o", "{d}/out.png", "--cold-iterations", "-1"],
     "--cold-iterations"),
    ("render fovea too small", ["render", "{d}/small.png", "-o", "{d}/out.png", "--fovea", "0.1"], "--fovea"),
    ("render fovea as text", ["render", "{d}/small.png", "-o", "{d}/out.png", "--fovea", "wide"], "--fovea"),
    ("render fovea with fft", ["render", "{d}/small.png", "-o", "{d}/out.png", "--fovea", "10", "--filter", "fft"],
     "only with --filter admm"),
    ("render gaze without fovea", ["render", "{d}/small.png", "-o", "{d}/out.png", "--gaze", "3,0"], "--gaze"),
    ("render gaze one number", ["render", "{d}/small.png", "-o", "{d}/out.png", "--fovea", "10", "--gaze", "3"],
     "--gaze"),
    ("render gaze past 90", ["render", "{d}/small.png", "-o", "{d}/out.png", "--fovea", "10", "--gaze", "0,95"],
     "--gaze"),
    ("render fovea with a cold-start model", ["render", "{d}/small.png", "-o", "{d}/out.png", "--fovea", "10",
                                              "--cold-start", "{d}/small.png"], "--cold-start"),
    ("bench cost fovea 0", ["bench", "cost", "--dry-run", "--fovea", "0", "--no-write"], "--fovea"),
    ("render periphery without fovea", ["render", "{d}/small.png", "-o", "{d}/out.png", "--periphery", "half"],
     "--periphery"),
    ("render budget zero", ["render", "{d}/small.png", "-o", "{d}/out.png", "--budget-ms", "0"], "--budget-ms"),
    ("render budget as text", ["render", "{d}/small.png", "-o", "{d}/out.png", "--budget-ms", "fast"], "--budget-ms"),
    ("render budget with fft", ["render", "{d}/small.png", "-o", "{d}/out.png", "--budget-ms", "5", "--filter",
                                "fft"], "only with --filter admm or fista"),
    ("layer install budget nan", ["layer", "install", "--budget-ms", "nan"], "--budget-ms"),
    ("render cold iterations with fista", ["render", "{d}/small.png", "-o", "{d}/out.png", "--filter", "fista",
                                           "--cold-iterations", "4"], "only with --filter admm"),
    ("render cold start missing", ["render", "{d}/small.png", "-o", "{d}/out.png", "--cold-start", "{d}/none.onnx"],
     "--cold-start"),
    ("render cold start with fista", ["render", "{d}/small.png", "-o", "{d}/out.png", "--filter", "fista",
                                      "--cold-start", "{d}/small.png"], "only with --filter admm"),
    ("render cold start not a model", ["render", "{d}/small.png", "-o", "{d}/out.png", "--cold-start",
                                       "{d}/small.png"], "small.png"),
    ("render model without onnx", ["render", "{d}/small.png", "-o", "{d}/out.png", "--model", "{d}/m.onnx"],
     "--backend onnx"),
    ("render output not png", ["render", "{d}/small.png", "-o", "{d}/out.bmp"], ".png"),
    ("acuity contrast 0", ["acuity", "--contrast", "0"], "contrast"),
    ("acuity unknown method", ["acuity", "--methods", "magic"], "magic"),
    ("acuity trials 0", ["acuity", "--trials", "0"], "trials"),
    ("evaluate size 0", ["evaluate", "--size", "0", "--out", "{d}/eval"], "size"),
    ("evaluate images missing", ["evaluate", "--images", "{d}/no_images", "--out", "{d}/eval"], "no_images"),
    ("mirror size 0", ["mirror", "--size", "0x10"], "--size"),
    ("mirror missing source", ["mirror", "--source", "{d}/nope.png"], "no such file"),
    ("overlay region without screen", ["overlay", "--source", "{d}/small.png", "--region", "0,0,4,4"],
     "--region"),
    ("xr frames 0", ["xr", "--frames", "0"], "--frames"),
    ("displays plot without fit", ["displays", "--plot", "{d}/fit.png"], "--fit"),
]


@pytest.mark.parametrize("argv, words", [c[1:] for c in CLI_CASES], ids=[c[0] for c in CLI_CASES])
def test_a_bad_command_line_is_one_clear_line_and_writes_nothing(argv, words, files, capsys):
    d = files["dir"]
    _refused([a.replace("{d}", str(d)) for a in argv], words, capsys, d)


GOOD_CASES = [
    ("1x1 image", (1, 1, 3), "uint8"),
    ("grey image", (10, 7), "uint8"),
    ("16-bit image", (9, 9, 3), "uint16"),
    ("transparent image", (8, 8, 4), "uint8"),
]


@pytest.mark.parametrize("shape, dtype", [c[1:] for c in GOOD_CASES], ids=[c[0] for c in GOOD_CASES])
def test_unusual_but_valid_images_are_corrected(shape, dtype, tmp_path, capsys):
    values = np.linspace(0, 1, int(np.prod(shape))).reshape(shape)
    scale = 65535 if dtype == "uint16" else 255
    array = np.round(values * scale).astype(dtype)
    path = tmp_path / "in.png"
    if dtype == "uint16":
        Image.fromarray(array[..., 0].astype(np.uint16)).save(path)        # Pillow writes 16-bit grey
    else:
        Image.fromarray(array).save(path)
    out = tmp_path / "out.png"
    assert cli.main(["correct", str(path), "-o", str(out), "--method", "wiener", "--display", "desktop"]) == 0
    written = np.asarray(Image.open(out))
    assert written.shape[:2] == shape[:2] and written.ndim == 3
    assert "Traceback" not in capsys.readouterr().err
