"""The OpenXR API layer's library: the C shim in ``layer/`` (``vrcorrect_layer.c`` and
``vrcorrect_vulkan.c``, which embed this Python and run :mod:`vrcorrect.runtime.layer.engine`), the file
that tells it which Python to start (``vrcorrect_layer.cfg``), and the loader's manifest that names it.

The library is compiled when vrcorrect is built (``setup.py``: ``pip install .``, ``pip wheel .``, the
editable install of ``tools/setup.sh``) and lies inside the package (:func:`packaged_library`), so
``vrcorrect layer install`` (:mod:`vrcorrect.apps.layer`) only writes the manifest and the
configuration.  :func:`build_layer` compiles it with the machine's C compiler, with the same flags
(``layer/build_flags.py``): the fallback of ``layer install`` in a source checkout that has no built
library (or one older than its sources), ``vrcorrect bench layer`` and the layer's tests."""

from __future__ import annotations

import json
import os
import runpy
import shutil
import site
import subprocess
import sys
import sysconfig
from pathlib import Path
from typing import Any

from ...plumbing.errors import InputError
from .config import DISABLE_ENV, LAYER_NAME

PACKAGE = Path(__file__).resolve().parents[2]          # vrcorrect/
ROOT = PACKAGE.parent                                   # a checkout (layer/ beside vrcorrect/), or site-packages
SOURCE_DIR = ROOT / "layer"
LIBRARY = "libvrcorrect_layer.so"
CFG = "vrcorrect_layer.cfg"
MARK = "written by vrcorrect layer install"   # marks the files install wrote (it replaces only those)


def build_flags() -> dict[str, Any]:
    """``layer/build_flags.py`` of the checkout (sources, compiler flags, libraries), as ``setup.py``
    reads it.  Raises :class:`InputError` where there are no sources (an installed wheel)."""
    path = SOURCE_DIR / "build_flags.py"
    if not path.is_file():
        raise InputError(f"the OpenXR layer's sources are not here ({SOURCE_DIR}): this installation has no layer "
                         "library and cannot build one; reinstall vrcorrect (pip install builds the layer)")
    return runpy.run_path(str(path))


def packaged_library() -> Path | None:
    """The library built into the package (``vrcorrect/runtime/layer/libvrcorrect_layer.so``), or ``None``."""
    path = Path(__file__).resolve().parent / LIBRARY
    return path if path.is_file() else None


def stale_sources(library: Path) -> list[Path]:
    """In a source checkout: the layer's sources newer than ``library`` (an editable install built it
    before they were edited); none in an installed wheel."""
    if not SOURCE_DIR.is_dir():
        return []
    built = library.stat().st_mtime
    return sorted(p for p in SOURCE_DIR.iterdir() if p.suffix in (".c", ".h", ".py") and p.stat().st_mtime > built)


def compiler_command(output: Path, *, cc: str | None = None) -> list[str]:
    """The command that compiles the layer into ``output`` (the flags of ``layer/build_flags.py``).

    Raises
    ------
    InputError
        No sources, no C compiler, or no shared libpython."""
    flags = build_flags()
    compiler = shutil.which(cc or os.environ.get("CC", "cc")) or shutil.which("gcc")
    if compiler is None:
        raise InputError("no C compiler (cc or gcc) to build the OpenXR layer: install gcc, or install vrcorrect "
                         "with pip, which builds the layer into the package")
    if not sysconfig.get_config_var("Py_ENABLE_SHARED"):
        raise InputError(f"{sys.executable} has no shared libpython to embed in the OpenXR layer; "
                         "use a Python built with --enable-shared")
    include = sysconfig.get_paths()["include"]
    libdir = sysconfig.get_config_var("LIBDIR")
    version = sysconfig.get_config_var("LDVERSION") or sysconfig.get_python_version()
    sources = [str(SOURCE_DIR / name) for name in flags["SOURCES"]]
    return [compiler, *flags["CFLAGS"], "-shared", "-fPIC", f"-I{include}", "-o", str(output), *sources,
            f"-L{libdir}", f"-lpython{version}", f"-Wl,-rpath,{libdir}", *(f"-l{lib}" for lib in flags["LIBRARIES"])]


def build_layer(folder: Path, *, cc: str | None = None) -> Path:
    """Compile the layer into ``folder`` and write its ``vrcorrect_layer.cfg``; returns the library.

    Raises
    ------
    InputError
        No sources, no C compiler, no OpenXR or Vulkan headers (Debian: ``libopenxr-dev``,
        ``libvulkan-dev``), no shared libpython, or a compiler error or warning (its first lines)."""
    folder.mkdir(parents=True, exist_ok=True)
    library = folder / LIBRARY
    tmp = folder / (LIBRARY + ".tmp")
    build = subprocess.run(compiler_command(tmp, cc=cc), capture_output=True, text=True)
    if build.returncode != 0:
        tmp.unlink(missing_ok=True)
        first = " ".join(build.stderr.strip().splitlines()[:3])
        hint = (" (install the OpenXR and Vulkan headers: apt-get install libopenxr-dev libvulkan-dev)"
                if "openxr" in build.stderr or "vulkan" in build.stderr else "")
        raise InputError(f"building the OpenXR layer ({SOURCE_DIR}) failed{hint}: {first}")
    tmp.replace(library)
    write_cfg(folder)
    return library


def cfg_text() -> str:
    """``vrcorrect_layer.cfg``: the Python home the layer starts and the ``sys.path`` entries that find
    vrcorrect and its dependencies (this interpreter's)."""
    paths = list(dict.fromkeys([str(ROOT), *site.getsitepackages()]))
    return "\n".join([f"# {MARK}", f"home={sys.base_prefix}", *(f"path={p}" for p in paths)]) + "\n"


def write_cfg(folder: Path) -> Path:
    """Write ``vrcorrect_layer.cfg`` into ``folder`` (the shim reads it beside its library, else in
    ``$XDG_DATA_HOME/vrcorrect/layer/``)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / CFG
    tmp = folder / (CFG + ".tmp")
    tmp.write_text(cfg_text())
    tmp.replace(path)
    return path


def manifest_text(library: Path) -> str:
    """The API-layer manifest (loader file format 1.0.0) naming ``library``."""
    return json.dumps({
        "file_format_version": "1.0.0",
        "api_layer": {
            "name": LAYER_NAME,
            "library_path": str(library),
            "api_version": "1.0",
            "implementation_version": "1",
            "description": f"vrcorrect: pre-corrects each eye's image for that eye's prescription ({MARK})",
            "disable_environment": DISABLE_ENV,
        },
    }, indent=4) + "\n"
