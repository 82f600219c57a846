"""Building the OpenXR API layer: the C shim in ``layer/`` (``vrcorrect_layer.c`` and
``vrcorrect_vulkan.c``, which embed this Python and run :mod:`vrcorrect.runtime.xrlayer`), compiled
with the machine's C compiler, and the loader's manifest that names it. ``vrcorrect layer install``
(:mod:`vrcorrect.apps.layer`), ``vrcorrect bench layer`` and the layer's tests build it here."""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import sysconfig
from pathlib import Path

from ..plumbing.errors import InputError
from .xrlayer import DISABLE_ENV, LAYER_NAME

ROOT = Path(__file__).resolve().parents[2]              # the checkout (layer/ beside vrcorrect/)
SOURCES = (ROOT / "layer" / "vrcorrect_layer.c", ROOT / "layer" / "vrcorrect_vulkan.c")
LIBRARY = "libvrcorrect_layer.so"
MARK = "written by vrcorrect layer install"   # marks the files install wrote (it replaces only those)


def build_layer(folder: Path, *, cc: str | None = None) -> Path:
    """Compile the layer into ``folder`` and write its ``vrcorrect_layer.cfg``; returns the library.

    Raises
    ------
    InputError
        No C compiler, no OpenXR or Vulkan headers (Debian: ``libopenxr-dev``, ``libvulkan-dev``),
        no shared libpython, or a compiler error (its first lines)."""
    compiler = shutil.which(cc or os.environ.get("CC", "cc")) or shutil.which("gcc")
    if compiler is None:
        raise InputError("no C compiler (cc or gcc) to build the OpenXR layer: install gcc")
    if not sysconfig.get_config_var("Py_ENABLE_SHARED"):
        raise InputError(f"{sys.executable} has no shared libpython to embed in the OpenXR layer; "
                         "use a Python built with --enable-shared")
    include = sysconfig.get_paths()["include"]
    libdir = sysconfig.get_config_var("LIBDIR")
    version = sysconfig.get_config_var("LDVERSION") or sysconfig.get_python_version()
    folder.mkdir(parents=True, exist_ok=True)
    library = folder / LIBRARY
    tmp = folder / (LIBRARY + ".tmp")
    cmd = [compiler, "-std=c11", "-O2", "-Wall", "-Wextra", "-Wno-format-truncation", "-shared", "-fPIC",
           "-fvisibility=hidden", f"-I{include}", "-o", str(tmp), *map(str, SOURCES), f"-L{libdir}", f"-lpython{version}",
           f"-Wl,-rpath,{libdir}", "-ldl", "-lm", "-lpthread"]
    build = subprocess.run(cmd, capture_output=True, text=True)
    if build.returncode != 0:
        first = " ".join(build.stderr.strip().splitlines()[:3])
        hint = (" (install the OpenXR and Vulkan headers: apt-get install libopenxr-dev libvulkan-dev)"
                if "openxr" in build.stderr or "vulkan" in build.stderr else "")
        raise InputError(f"building the OpenXR layer ({SOURCES[0].parent}) failed{hint}: {first}")
    tmp.replace(library)
    paths = [str(ROOT), *site.getsitepackages()]
    lines = [f"# {MARK}", f"home={sys.base_prefix}", *(f"path={p}" for p in paths)]
    (folder / "vrcorrect_layer.cfg").write_text("\n".join(lines) + "\n")
    return library


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
