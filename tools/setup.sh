#!/usr/bin/env bash
# Installs everything vrcorrect needs into ./.venv (idempotent; quick when nothing changed).
# Used by tools/demo.sh and tools/test.sh; safe to run by hand.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  echo "vrcorrect needs Python >= 3.11 (found: $("$PY" --version 2>&1))" >&2
  exit 1
fi

# Debian packages: the venv module; for the real-time renderer's tests, Mesa's EGL and GL with
# the llvmpipe software rasteriser (moderngl's headless context: libEGL.so.1 + libEGL_mesa,
# libGL.so.1 + libGLX_mesa, swrast_dri.so; libOpenGL.so.0: the frame budget's GL timestamps), and Xvfb with the X libraries the glfw wheel's
# libglfw.so loads at run time (X11, X11-xcb, Xext, Xrender, Xrandr, Xinerama, Xcursor, Xi,
# Xxf86vm); gcc and libc6-dev: the headset tests compile a small OpenXR runtime (tests/xr_runtime/);
# libopenxr-dev (OpenXR headers), libx11-dev, libgl-dev, libglx-dev, libvulkan-dev (Vulkan headers):
# `vrcorrect layer install` and its tests compile the OpenXR API layer (layer/), the test runtime
# (tools/xr_test_runtime.sh) and C test applications (tests/xr_gl_app/, tests/xr_vk_app/);
# libvulkan1, mesa-vulkan-drivers and vulkan-validationlayers: the Vulkan loader, Mesa's lavapipe (the
# Vulkan device of the layer's Vulkan tests) and Khronos's validation, which those tests run; libopenxr-utils: Khronos's sample application hello_xr, which the layer tests
# run unmodified; xserver-xorg-core and xserver-xorg-video-dummy: an X server without a screen for
# hello_xr's OpenGL window (it needs XFree86-VidModeExtension, which Xvfb lacks).
# One dpkg-query for all of them, so a set-up that changed nothing stays quick.
need_apt=()
"$PY" -c 'import ensurepip, venv' 2>/dev/null || need_apt+=(python3-venv)
# the OpenXR layer embeds this Python: its headers and shared libpython (Debian's python3-dev)
"$PY" -c 'import os, sys, sysconfig; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' \
  2>/dev/null || need_apt+=(python3-dev)
gl_debs=(libegl1 libegl-mesa0 libgl1 libopengl0 libglx-mesa0 libgl1-mesa-dri xvfb
         libx11-6 libx11-xcb1 libxext6 libxrender1 libxrandr2 libxinerama1 libxcursor1 libxi6 libxxf86vm1
         gcc libc6-dev libopenxr-dev libx11-dev libgl-dev libglx-dev libvulkan-dev
         libvulkan1 mesa-vulkan-drivers vulkan-validationlayers libopenxr-utils xserver-xorg-core
         xserver-xorg-video-dummy)
if command -v dpkg-query >/dev/null; then
  have=$(dpkg-query -W -f='${Package} ${db:Status-Abbrev}\n' "${gl_debs[@]}" 2>/dev/null | awk '$2 == "ii" {print $1}' || true)
  for p in "${gl_debs[@]}"; do
    grep -qx "$p" <<<"$have" || need_apt+=("$p")
  done
else
  echo "note: not a Debian/Ubuntu system; the GL tests need Mesa EGL/GL (llvmpipe), Xvfb and the X11 libraries GLFW loads" >&2
fi
if [ ${#need_apt[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "installing Debian packages: ${need_apt[*]}"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
  else
    echo "please install the Debian packages: ${need_apt[*]}" >&2
    echo "  (as root: apt-get install --no-install-recommends ${need_apt[*]})" >&2
    exit 1
  fi
fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv

# Reinstall only when the dependency list or the build changed: setup.py compiles the OpenXR layer
# (layer/, with layer/build_flags.py's -Werror flags) into the package, in place for this editable
# install, so an edited layer source is rebuilt here too.
stamp=.venv/.vrcorrect-installed
want=$(cat pyproject.toml setup.py layer/*.c layer/*.h layer/build_flags.py | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "installing Python packages into .venv (first run takes a few minutes) ..."
  .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
  # a setuptools that builds this project (the same as pyproject's build-system): the wheel test
  # (tests/test_xr_layer_wheel.py) runs `pip wheel --no-build-isolation` with it
  .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade "setuptools>=77" 2>&1 \
    | grep -v "^WARNING: Location" || true
  # torch==2.13.0 (CPU build) is pinned in the 'solve' extra: pip takes it from this machine's disk.
  # setuptools warns at every editable install that a folder named like the package may shadow it
  # (a generic banner: this checkout's vrcorrect/ is the package itself); silenced by its message
  PYTHONWARNINGS="ignore:Editable installation" \
    .venv/bin/python -m pip install -q --disable-pip-version-check -e ".[solve,learn,metrics,test,realtime,ray]" 2>&1 \
    | grep -v -e "^WARNING: Location" || true
  [ -f vrcorrect/runtime/layer/libvrcorrect_layer.so ] \
    || { echo "installation failed: the OpenXR layer (vrcorrect/runtime/layer/libvrcorrect_layer.so) was not built" >&2; exit 1; }
  .venv/bin/python -c "import vrcorrect, numpy, scipy, colour, PIL, torch, pytest, hypothesis, moderngl, glfw, onnxruntime, onnx, onnxscript, imageio_ffmpeg, mss, xr, ray" \
    || { echo "installation failed" >&2; exit 1; }
  # ColorVideoVDP (the primary perceptual score) must import beside the CPU build of torch.
  .venv/bin/python -c "from vrcorrect.vision.vdp import _import_cvvdp; _import_cvvdp()" \
    || { echo "installation failed: ColorVideoVDP (cvvdp) does not import" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
