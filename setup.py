"""Builds vrcorrect's OpenXR API layer (``layer/``, a C shim that embeds Python) into the package at
build time, with setuptools' own extension building: ``pip install .``, ``pip wheel .`` and the
editable install of ``tools/setup.sh`` all compile it, so ``vrcorrect layer install`` needs no C
compiler (it only writes the loader's manifest and its configuration).

Why setuptools and not scikit-build-core: setuptools is already the build backend, the layer is two C
files with no configure step, and ``build_ext`` compiles them with the machine's compiler with no new
build dependency (no CMake, no Ninja, nothing fetched for the build beyond setuptools itself).

The library is not a Python extension module (nothing imports it: the OpenXR loader ``dlopen``s it
and it embeds the interpreter), so it keeps the plain name the loader's manifest names,
``vrcorrect/runtime/layer/libvrcorrect_layer.so``, and links the shared libpython of the Python that builds
it; the wheel is tagged for that Python and platform.  Linux only (the layer corrects OpenGL/Xlib and
Vulkan sessions on Linux).  ``VRCORRECT_NO_LAYER=1`` builds vrcorrect without it (then ``layer
install`` can build it from a source checkout, and says so).  The flags come from
``layer/build_flags.py``, shared with the fallback build (``vrcorrect/runtime/layer/build.py``).
"""

from __future__ import annotations

import os
import runpy
import sys
import sysconfig
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

HERE = Path(__file__).resolve().parent
FLAGS = runpy.run_path(str(HERE / "layer" / "build_flags.py"))
NAME = FLAGS["PACKAGE_DIR"].replace("/", ".") + "." + FLAGS["LIBRARY"].removesuffix(".so")


class BuildLayer(build_ext):
    """build_ext that names the layer as the loader's manifest will (no ABI suffix) and says which
    Debian packages a failed build lacks."""

    def get_ext_filename(self, fullname: str) -> str:
        # called with the full dotted name and, by get_ext_fullpath, with its last part alone
        if fullname == NAME:
            return os.path.join(*FLAGS["PACKAGE_DIR"].split("/"), FLAGS["LIBRARY"])
        if fullname == NAME.rsplit(".", 1)[1]:
            return FLAGS["LIBRARY"]
        return super().get_ext_filename(fullname)

    def get_export_symbols(self, ext: Extension) -> list[str]:
        return [] if ext.name == NAME else super().get_export_symbols(ext)

    def build_extension(self, ext: Extension) -> None:
        try:
            super().build_extension(ext)
        except Exception as exc:
            if ext.name != NAME:
                raise
            raise SystemExit(
                f"building vrcorrect's OpenXR layer (layer/) failed: {exc}\n"
                "It needs a C compiler, Python's headers and shared libpython, and the OpenXR, Vulkan, GL and "
                "X11 headers (Debian: apt-get install gcc libc6-dev python3-dev libopenxr-dev libvulkan-dev "
                "libgl-dev libglx-dev libx11-dev; tools/setup.sh installs them). VRCORRECT_NO_LAYER=1 builds "
                "vrcorrect without the layer.") from None


def layer_extensions() -> list[Extension]:
    if not sys.platform.startswith("linux") or os.environ.get("VRCORRECT_NO_LAYER", "").strip() not in ("", "0"):
        return []
    if not sysconfig.get_config_var("Py_ENABLE_SHARED"):
        raise SystemExit(f"vrcorrect's OpenXR layer embeds Python and needs a shared libpython, which {sys.executable} "
                         "lacks (a Python built with --enable-shared); VRCORRECT_NO_LAYER=1 builds vrcorrect "
                         "without the layer")
    libdir = sysconfig.get_config_var("LIBDIR")
    version = sysconfig.get_config_var("LDVERSION") or sysconfig.get_python_version()
    return [Extension(
        NAME,
        sources=[f"layer/{name}" for name in FLAGS["SOURCES"]],
        depends=[f"layer/{name}" for name in FLAGS["HEADERS"]] + ["layer/build_flags.py"],
        extra_compile_args=list(FLAGS["CFLAGS"]),
        libraries=[f"python{version}", *FLAGS["LIBRARIES"]],
        library_dirs=[libdir],
        runtime_library_dirs=[libdir],
        py_limited_api=False,
    )]


setup(ext_modules=layer_extensions(), cmdclass={"build_ext": BuildLayer})
