"""The layering of docs/architecture.md ('Layers'), read from the folder structure: every module
of ``vrcorrect`` lives in a layer folder whose ``__init__`` docstring opens with "Layer N"; a module
imports only from its own folder or from lower layers, and nothing on the model or real-time path
imports torch."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "vrcorrect"
DATA_FOLDERS = {"data", "shaders", "__pycache__"}   # package data, not code
# The one same-layer import across folders: learning uses fast's corrections as targets and
# wiener's pre-correction as an input channel (docs/architecture.md, 'Layers': layer 4).
ALLOWED_SIBLINGS = {("learn", "solvers")}


def _layer_of_folder(folder: Path) -> int:
    doc = ast.get_docstring(ast.parse((folder / "__init__.py").read_text())) or ""
    m = re.match(r"Layer (\d)\b", doc)
    assert m, f"vrcorrect/{folder.name}/__init__.py: docstring must open with 'Layer N' (found {doc[:40]!r})"
    return int(m.group(1))


def _folders() -> dict[str, int]:
    return {p.name: _layer_of_folder(p) for p in sorted(PKG.iterdir())
            if p.is_dir() and p.name not in DATA_FOLDERS}


LAYERS = _folders()


def _modules() -> list[Path]:
    return sorted(p for p in PKG.rglob("*.py") if p.parent != PKG and "__pycache__" not in p.parts)


def _package(path: Path) -> str:
    parts = ("vrcorrect",) + path.relative_to(PKG).with_suffix("").parts
    return ".".join(parts if path.name == "__init__.py" else parts[:-1]).removesuffix(".__init__")


def _absolute_imports(path: Path) -> set[str]:
    """Every module name a file imports, relative imports resolved, including imports inside
    functions (lazy imports count)."""
    package = _package(path)
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
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


def _rel(path: Path) -> str:
    return str(path.relative_to(PKG.parent))


def test_the_top_level_holds_only_layer_folders():
    loose = sorted(p.name for p in PKG.glob("*.py") if p.name != "__init__.py")
    assert not loose, f"modules outside a layer folder: {loose}"
    assert sorted(set(LAYERS.values())) == list(range(8)), LAYERS


def test_the_package_docstring_lists_the_folders_in_layer_order():
    doc = ast.get_docstring(ast.parse((PKG / "__init__.py").read_text()))
    listed = {}
    for line in doc.splitlines():
        m = re.match(r"(\d)\. (.*)", line)
        if m:
            for name in re.findall(r"``(\w+)``", m.group(2).split(":")[0]):
                listed[name] = int(m.group(1))
    assert listed == LAYERS


@pytest.mark.parametrize("path", _modules(), ids=_rel)
def test_imports_go_down_the_layers(path):
    folder = path.relative_to(PKG).parts[0]
    own = LAYERS[folder]
    for name in _absolute_imports(path):
        parts = name.split(".")
        if parts[0] != "vrcorrect" or len(parts) < 2 or parts[1] in ("__version__", folder):
            continue
        dep = parts[1]
        assert dep in LAYERS, f"{_rel(path)} imports {name}: not in a layer folder"
        assert LAYERS[dep] < own or (folder, dep) in ALLOWED_SIBLINGS, \
            f"{_rel(path)} (layer {own}) imports {name} (layer {LAYERS[dep]})"


def test_wiener_is_torch_free():
    """The GLSL fallback's mathematics must be usable on the real-time path."""
    code = ("import sys; import vrcorrect.solvers.wiener; from vrcorrect.solvers import solve, make_problem; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_fast_and_wiener_solve_without_torch():
    """fast (ADMM) and wiener are numpy only: a real solve of each leaves torch unimported."""
    code = ("import sys, numpy as np; from vrcorrect.specs.display import get_display; "
            "from vrcorrect.physics.kernel import build_kernel; from vrcorrect.specs.prescription import EyeRx; "
            "from vrcorrect.solvers import make_problem, solve; "
            "k = build_kernel(EyeRx(sphere_D=-2.0, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0), "
            "get_display('quest2')); t = np.random.default_rng(0).random((80, 80, 3)).astype(np.float32); "
            "p = make_problem(t, k); r = solve(p, 'fast'); w = solve(p, 'wiener'); "
            "assert r.objective < solve(p, 'none').objective; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_building_the_command_line_loads_no_heavy_stack():
    """Every ``vrcorrect`` run builds the whole parser: it must not wait for the physics, the
    solvers, the metrics, torch or GL (apps/__init__: imports "on use")."""
    heavy = ("scipy", "colour", "torch", "moderngl", "glfw", "xr", "matplotlib", "onnxruntime",
             "vrcorrect.physics.kernel", "vrcorrect.solvers", "vrcorrect.vision.metrics")
    code = ("import sys; from vrcorrect.apps.cli import build_parser; build_parser(); "
            f"print(' '.join(m for m in {heavy!r} if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "", f"building the parser imported: {result.stdout}"


def test_model_path_does_not_import_torch():
    code = ("import sys; import vrcorrect.apps.cli, vrcorrect.vision.forward, vrcorrect.physics.kernel, "
            "vrcorrect.apps.demo; from vrcorrect.apps.cli import build_parser; build_parser(); "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# --------------------------------------------------------------------------
# The real-time path (layer 5): never torch, never the torch solvers, even lazily
# --------------------------------------------------------------------------

RUNTIME = PKG / "runtime"
RUNTIME_FORBIDDEN = ("torch", "vrcorrect.solvers.iterative")


def _runtime_modules() -> list[str]:
    """Every module of the runtime, its packages' included, as a dotted path below ``runtime``."""
    return sorted(".".join(p.relative_to(RUNTIME).with_suffix("").parts)
                  for p in RUNTIME.rglob("*.py") if "__pycache__" not in p.parts)


@pytest.mark.parametrize("module", _runtime_modules())
def test_runtime_never_imports_torch(module):
    for name in _absolute_imports(RUNTIME.joinpath(*module.split(".")).with_suffix(".py")):
        assert not any(name == f or name.startswith(f + ".") for f in RUNTIME_FORBIDDEN), \
            f"runtime/{module} imports {name} (the real-time path must not import torch)"


def test_runtime_imports_no_torch_at_run_time():
    """Importing the sub-package and every module in it, in a fresh interpreter."""
    modules = ["vrcorrect.runtime"] + [f"vrcorrect.runtime.{m}".removesuffix(".__init__")
                                       for m in _runtime_modules() if m != "__init__"]
    code = ("import importlib, sys\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            f"bad = [m for m in {RUNTIME_FORBIDDEN!r} if m in sys.modules]\n"
            "print(' '.join(bad)); sys.exit(1 if bad else 0)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, f"importing {modules} imported: {result.stdout}{result.stderr}"


# --------------------------------------------------------------------------
# Inside the runtime: the plugin, the shells and the API layer (runtime/__init__.py)
# --------------------------------------------------------------------------

RUNTIME_PACKAGES = ("shell", "layer")
"""The runtime's packages above the plugin (the runtime folder's own modules and ``strategies``)."""


def _runtime_part(module: str) -> str:
    head = module.split(".")[0]
    return head if head in RUNTIME_PACKAGES else "plugin"


def _runtime_part_of_import(name: str) -> str | None:
    parts = name.split(".")
    if parts[:2] != ["vrcorrect", "runtime"] or len(parts) < 3:
        return None
    return parts[2] if parts[2] in RUNTIME_PACKAGES else "plugin"


def test_the_runtime_has_its_three_parts():
    parts = {_runtime_part(m) for m in _runtime_modules()}
    assert parts == {"plugin", "shell", "layer"}, parts
    assert {"corrector", "strategies.admm", "shell.mirror", "shell.xr.app", "layer.engine", "layer.build"} <= \
        set(_runtime_modules())


@pytest.mark.parametrize("module", _runtime_modules())
def test_the_shells_and_the_layer_never_import_each_other_and_the_plugin_neither(module):
    """The plugin imports neither the shells nor the layer; a shell never imports the layer, nor the
    layer a shell (lazy imports count)."""
    own = _runtime_part(module)
    for name in _absolute_imports(RUNTIME.joinpath(*module.split(".")).with_suffix(".py")):
        dep = _runtime_part_of_import(name)
        if dep is None or dep == own or dep == "plugin":
            continue
        raise AssertionError(f"runtime/{module} ({own}) imports {name} ({dep}): "
                             + ("the plugin imports no shell and no layer" if own == "plugin"
                                else "the shells and the API layer never import each other"))


def test_learn_conditioning_is_torch_free():
    code = ("import sys; import vrcorrect.learn, vrcorrect.learn.conditioning, vrcorrect.learn.dataset; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# --------------------------------------------------------------------------
# The house's sizes and names (issue 47)
# --------------------------------------------------------------------------

MAX_MODULE_LINES = 600


@pytest.mark.parametrize("path", sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts), ids=_rel)
def test_no_module_is_over_600_lines_unless_its_first_line_says_why(path):
    lines = path.read_text().splitlines()
    if len(lines) > MAX_MODULE_LINES:
        assert "lines" in lines[0] and ("because" in lines[0] or "on purpose" in lines[0]), \
            f"{_rel(path)}: {len(lines)} lines (> {MAX_MODULE_LINES}) and its first line does not say why"


def test_no_two_classes_share_a_name():
    """One name, one class: a reader who meets a class's name knows which one it is."""
    where: dict[str, list[str]] = {}
    for path in sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(_rel(path))
    shared = {name: paths for name, paths in where.items() if len(paths) > 1}
    assert not shared, shared


def _imports_inside_functions(path: Path):
    lines = path.read_text().splitlines()
    for fn in ast.walk(ast.parse("\n".join(lines))):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    yield node.lineno, lines[node.lineno - 1:node.end_lineno]


@pytest.mark.parametrize("path", sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts), ids=_rel)
def test_an_import_inside_a_function_says_why_on_its_line(path):
    """Imports sit at the top of a module, except where an optional dependency, a measured start-up
    cost (the CLI's parser and the runtime load no heavy stack: the tests above) or an import cycle
    needs them inside a function; the reason is then written on the import."""
    silent = [f"{_rel(path)}:{n}: {text[0].strip()}" for n, text in _imports_inside_functions(path)
              if not any("#" in line for line in text)]
    assert not silent, "imports inside functions without their reason:\n" + "\n".join(silent)
