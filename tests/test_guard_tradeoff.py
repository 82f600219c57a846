"""The study tool of the guard's trade (tools/guard_tradeoff.py): its summary of falls lifted and gain
kept, and its refusals before any work."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    """tools/guard_tradeoff.py as a module; it imports robust_band_choice from its folder, which is
    loaded the same way (sys.path is left alone)."""
    for name in ("robust_band_choice", "guard_tradeoff"):
        if name not in sys.modules:
            spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
    return sys.modules["guard_tradeoff"]


def _scores(jod: list[float], flip: float = -0.01, objective: float = 0.5) -> dict:
    """Six seen eyes' scores: the JOD gains given, every FLIP change and objective ratio alike but the last."""
    return dict(jod=jod, flip=[-0.02] * 5 + [flip], objective=[0.4] * 5 + [objective])


def _case(eye: str, display: str, unguarded: dict, ceiling: float) -> dict:
    return dict(eye=eye, display_name=display, scores=unguarded, ceiling=ceiling)


def test_the_summary_counts_falls_lifted_and_the_share_of_the_3mm_gain_kept():
    tool = _tool()
    cases = [_case("bench", "desktop", _scores([0.5, 0.8, 0.3, 0.1, 0.2, -0.12], 0.03, 1.4), 1.0),   # a fall
             _case("bench", "quest2", _scores([0.5, 0.9, 0.3, 0.1, 0.2, 0.3]), 1.0),
             _case("-1.00", "desktop", _scores([0.1, 0.05, 0.0, 0.0, -0.8, 0.1], 0.004, 1.2), 0.08),  # too small to read
             _case("-1.00", "quest2", _scores([0.3, 0.4, 0.2, 0.1, 0.1, -0.04]), 0.5)]      # not a fall: within 0.05
    guarded = {id(cases[0]): _scores([0.4, 0.6, 0.2, 0.1, 0.1, 0.00], 0.001, 0.9),          # lifted, 60 % kept
               id(cases[1]): cases[1]["scores"],                                             # untouched
               id(cases[2]): _scores([0.0, 0.0, 0.0, 0.0, -0.06, 0.0], 0.006, 1.05),         # not lifted
               id(cases[3]): _scores([0.1, 0.1, 0.1, 0.0, 0.0, 0.0])}                        # 20 % kept
    s = tool._summary(cases, lambda c: guarded[id(c)])
    assert (s["falls"], s["lifted"]) == (2, 1)
    assert s["worst"] == pytest.approx(-0.06)
    assert s["median"] == pytest.approx(0.6) and s["least"] == pytest.approx(0.2)        # 0.6, 0.9, 0.2
    assert s["bench"] == pytest.approx({"desktop": 0.6, "quest2": 0.9})
    # FLIP and the objective beside the JOD: one case each left worse than none (0.006 > 0.005; x1.05)
    assert (s["flip_falls"], s["objective_falls"]) == (1, 1)
    assert s["flip_worst"] == pytest.approx(0.006) and s["objective_worst"] == pytest.approx(1.05)
    none = tool._summary(cases, lambda c: c["scores"])
    assert (none["falls"], none["lifted"]) == (2, 0) and none["worst"] == pytest.approx(-0.8)
    assert np.isclose(none["median"], 0.8)
    assert (none["flip_falls"], none["objective_falls"]) == (1, 2)       # FLIP +0.004 is within 0.005
    assert none["flip_worst"] == pytest.approx(0.03) and none["objective_worst"] == pytest.approx(1.4)
    assert "by FLIP 1 (worst +0.030), by the objective 2 (worst x1.40)" in tool._line("unguarded", none)


@pytest.mark.parametrize("extra, said", [(["--rho", "0.5"], "--rho: factors from 1 to 10"),
                                         (["--image", "missing.png"], "--image missing.png"),
                                         (["--image", "no_such_picture"], "nor a scikit-image picture"),
                                         (["--image", "motorcycle"], "held out for vrcorrect bench robust"),
                                         (["--measure", "jod"], "invalid choice")])
def test_the_tool_refuses_bad_input_in_one_line_before_any_work(tmp_path, extra, said):
    picture = ROOT / "vrcorrect" / "data" / "sample.png"
    args = ["--image", str(picture)] if "--image" not in extra else []
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "guard_tradeoff.py"), *args, *extra],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 2, done.stderr
    assert said in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize("tool", ["guard_tradeoff", "bars_frontier"])
def test_an_existing_plot_is_kept_without_force(tmp_path, tool):
    plot = tmp_path / "trade.png"
    plot.write_bytes(b"mine")
    done = subprocess.run([sys.executable, str(ROOT / "tools" / f"{tool}.py"), "--image", "x.png",
                           "--plot", str(plot)], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 2 and "--force" in done.stderr and plot.read_bytes() == b"mine"


@pytest.mark.parametrize("tool", ["bars_frontier", "expected_gain"])
@pytest.mark.parametrize("extra, said", [(["--image", "missing.png"], "--image missing.png"),
                                         (["--image", "no_such_picture"], "nor a scikit-image picture"),
                                         (["--image", "motorcycle"], "held out for vrcorrect bench robust"),
                                         (["--rx", "missing.json"], "--rx missing.json")])
def test_the_other_studies_refuse_bad_input_in_one_line_before_any_work(tmp_path, tool, extra, said):
    """tools/bars_frontier.py and tools/expected_gain.py read --image and --rx as guard_tradeoff does."""
    picture = ROOT / "vrcorrect" / "data" / "sample.png"
    args = ["--image", str(picture)] if "--image" not in extra else []
    done = subprocess.run([sys.executable, str(ROOT / "tools" / f"{tool}.py"), *args, *extra],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 2, done.stderr
    assert said in done.stderr and "Traceback" not in done.stderr


def test_the_frontier_reads_where_a_path_first_keeps_80_percent_and_how_far_it_stays_safe():
    """bars_frontier's verdict on a path of blends: the 3 mm eye (the second seen eye) gains the blend
    times the ceiling; the least seen eye 0.1 - 0.2 x blend, below the floor (-0.05) past 0.75."""
    _tool()
    spec = importlib.util.spec_from_file_location("bars_frontier", ROOT / "tools" / "bars_frontier.py")
    frontier = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(frontier)
    path = [(b, [0.5, b * 0.6, 0.4, 0.1 - 0.2 * b, 0.3, 0.2]) for b in frontier.BETAS]
    said = frontier._verdict(path, 0.6)
    assert "80 % from blend 0.8, least there -0.06" in said and "safe up to 0.7, 3 mm share there  70%" in said
    weak = [(b, [0.1, b * 0.1, 0.1, 0.1, 0.1, 0.1]) for b in frontier.BETAS]     # never 80 % of 0.6, always safe
    assert frontier._verdict(weak, 0.6).startswith("never 80 %") and "safe up to 1.0" in frontier._verdict(weak, 0.6)

