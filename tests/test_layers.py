"""The layering of DESIGN.md: a module imports only from layers below it, and nothing on the
model or real-time path imports torch."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "vrcorrect"

LAYER = {
    "errors": 0, "fileio": 0,
    "prescription": 1, "display": 1, "imageio": 1, "charts": 1,
    "optics": 2, "perception": 2, "kernel": 2,
    "forward": 3, "metrics": 3, "acuity": 3,
    "solvers": 4, "learn": 4,
    "runtime": 5,
    "cli": 6, "demo": 6, "plots": 6, "bench": 6, "bench_kernel": 6, "bench_solvers": 6, "bench_render": 6, "bench_learned": 6, "bench_realtime": 6, "bench_xr": 6, "evaluate": 6,
    "learn_cli": 6, "acuity_cli": 6,
}


def _vrcorrect_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1 and node.module:
                names.add(node.module.split(".")[0])
            elif node.level == 1:
                names.update(a.name for a in node.names)
            elif node.module and node.module.startswith("vrcorrect."):
                names.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("vrcorrect."):
                    names.add(a.name.split(".")[1])
    return names


def test_every_module_has_a_layer():
    modules = {p.stem for p in PKG.glob("*.py") if p.stem != "__init__"}
    modules |= {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert modules <= set(LAYER), f"modules without a layer: {sorted(modules - set(LAYER))}"


@pytest.mark.parametrize("module", sorted(p.stem for p in PKG.glob("*.py") if p.stem != "__init__"))
def test_imports_go_down_the_layers(module):
    own = LAYER[module]
    for dep in _vrcorrect_imports(PKG / f"{module}.py"):
        assert LAYER[dep] < own or (LAYER[dep] == own and own in (0, 1, 2, 3, 6)), \
            f"{module} (layer {own}) imports {dep} (layer {LAYER[dep]})"


@pytest.mark.parametrize("module", sorted(p.stem for p in (PKG / "solvers").glob("*.py")))
def test_solvers_import_only_lower_layers(module):
    tree = ast.parse((PKG / "solvers" / f"{module}.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 2 and node.module:
            dep = node.module.split(".")[0]
            assert LAYER[dep] < LAYER["solvers"], f"solvers/{module} imports {dep}"


def test_wiener_is_torch_free():
    """The GLSL fallback's mathematics must be usable on the real-time path."""
    code = ("import sys; import vrcorrect.solvers.wiener; from vrcorrect.solvers import solve, make_problem; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_fast_and_wiener_solve_without_torch():
    """fast (ADMM) and wiener are numpy only: a real solve of each leaves torch unimported."""
    code = ("import sys, numpy as np; from vrcorrect.display import get_display; "
            "from vrcorrect.kernel import build_kernel; from vrcorrect.prescription import EyeRx; "
            "from vrcorrect.solvers import make_problem, solve; "
            "k = build_kernel(EyeRx(sphere_D=-2.0, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0), "
            "get_display('quest2')); t = np.random.default_rng(0).random((80, 80, 3)).astype(np.float32); "
            "p = make_problem(t, k); r = solve(p, 'fast'); w = solve(p, 'wiener'); "
            "assert r.objective < solve(p, 'none').objective; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_model_path_does_not_import_torch():
    code = ("import sys; import vrcorrect.cli, vrcorrect.forward, vrcorrect.kernel, vrcorrect.demo; "
            "from vrcorrect.cli import build_parser; build_parser(); "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# --------------------------------------------------------------------------
# The real-time sub-package (layer 5): layers 0-4 only, never torch, never the torch solvers
# --------------------------------------------------------------------------

RUNTIME = PKG / "runtime"
RUNTIME_FORBIDDEN = ("torch", "vrcorrect.solvers.iterative")


def _absolute_imports(path: Path, package: str) -> set[str]:
    """Every module name a file of ``package`` imports, relative imports resolved, including
    imports inside functions (lazy imports count)."""
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([node.module] if node.module else []))
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)  # 'from ..solvers import iterative'
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def _runtime_modules() -> list[str]:
    return sorted(p.stem for p in RUNTIME.glob("*.py"))


def test_runtime_package_exists_at_layer_5():
    assert (RUNTIME / "__init__.py").exists() and LAYER["runtime"] == 5


@pytest.mark.parametrize("module", _runtime_modules())
def test_runtime_imports_only_layers_up_to_4(module):
    for name in _absolute_imports(RUNTIME / f"{module}.py", "vrcorrect.runtime"):
        top = name.split(".")[0]
        assert not any(name == f or name.startswith(f + ".") for f in RUNTIME_FORBIDDEN), \
            f"runtime/{module} imports {name} (the real-time path must not import torch)"
        if top != "vrcorrect" or name == "vrcorrect":
            continue
        dep = name.split(".")[1]
        if dep == "runtime":
            continue  # within the sub-package
        assert dep in LAYER, f"runtime/{module} imports {name}: unknown module"
        assert LAYER[dep] <= 4, f"runtime/{module} (layer 5) imports {name} (layer {LAYER[dep]})"


def test_runtime_imports_no_torch_at_run_time():
    """Importing the sub-package and every module in it, in a fresh interpreter."""
    modules = ["vrcorrect.runtime"] + [f"vrcorrect.runtime.{m}" for m in _runtime_modules() if m != "__init__"]
    code = ("import importlib, sys\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            f"bad = [m for m in {RUNTIME_FORBIDDEN!r} if m in sys.modules]\n"
            "print(' '.join(bad)); sys.exit(1 if bad else 0)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, f"importing {modules} imported: {result.stdout}{result.stderr}"


# --------------------------------------------------------------------------
# The learned correction (layer 4, beside solvers): lower layers and solvers only; the
# conditioning the runtime feeds an exported model with never imports torch
# --------------------------------------------------------------------------

LEARN = PKG / "learn"
LEARN_SIBLINGS = ("solvers",)          # same layer: targets from fast, pre-correction from wiener


def _learn_modules() -> list[str]:
    return sorted(p.stem for p in LEARN.glob("*.py"))


def test_learn_package_exists_at_layer_4():
    assert (LEARN / "__init__.py").exists() and LAYER["learn"] == 4


@pytest.mark.parametrize("module", _learn_modules())
def test_learn_imports_only_lower_layers_and_solvers(module):
    for name in _absolute_imports(LEARN / f"{module}.py", "vrcorrect.learn"):
        parts = name.split(".")
        if parts[0] != "vrcorrect" or len(parts) < 2 or parts[1] in ("learn", "__version__"):
            continue
        dep = parts[1]
        assert dep in LAYER, f"learn/{module} imports {name}: unknown module"
        assert LAYER[dep] < 4 or dep in LEARN_SIBLINGS, f"learn/{module} (layer 4) imports {name} (layer {LAYER[dep]})"


def test_learn_conditioning_is_torch_free():
    code = ("import sys; import vrcorrect.learn, vrcorrect.learn.conditioning, vrcorrect.learn.dataset; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
