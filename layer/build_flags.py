"""How vrcorrect's OpenXR layer (this folder's C shim) is compiled: one list of flags for every route
that builds it, so that a warning fails each of them alike.

Read (as a plain file, never imported as part of the package) by ``setup.py`` (setuptools' extension
building: ``pip install .``, ``pip wheel .``, the editable install of ``tools/setup.sh``, which CI
runs) and by ``vrcorrect/runtime/layer/build.py`` (the fallback of ``vrcorrect layer install`` in a
source checkout without a built library, and the layer tests' own build).
"""

SOURCES = ("vrcorrect_layer.c", "vrcorrect_vulkan.c", "vrcorrect_gaze.c")
HEADERS = ("vrcorrect_layer.h",)
# -Werror: warnings are errors on every route (the wheel, the install fallback, CI)
CFLAGS = ("-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", "-fvisibility=hidden")
LIBRARIES = ("dl", "m", "pthread")
LIBRARY = "libvrcorrect_layer.so"
PACKAGE_DIR = "vrcorrect/runtime/layer"     # where the built library lies inside the package (and the wheel)
