#!/usr/bin/env bash
# Builds vrcorrect's test OpenXR runtime (tests/xr_runtime/xr_test_runtime.c: test equipment that
# hosts unmodified OpenXR applications, OpenGL and Vulkan, and writes every submitted view to a .npy
# file) into OUTDIR, writes its runtime manifest there, and prints the manifest's path as its last
# line. Run any OpenXR application against it, with or without the vrcorrect layer:
#
#   XR_RUNTIME_JSON=$(tools/xr_test_runtime.sh /tmp/rt | tail -1) hello_xr -g Vulkan
#
# The runtime's environment variables (XRTEST_OUT_DIR, XRTEST_VIEW_SIZE, XRTEST_FORMATS,
# XRTEST_STOP_AFTER, ...) are described at the top of its source. Needs a C compiler and the
# OpenXR, Vulkan, GL and X11 headers (tools/setup.sh installs them).
set -euo pipefail
if [ $# -ne 1 ] || [ -z "$1" ]; then
  echo "usage: $0 OUTDIR   (builds the test OpenXR runtime there; prints its manifest's path last)" >&2
  exit 2
fi
here=$(cd "$(dirname "$0")/.." && pwd)
source="$here/tests/xr_runtime/xr_test_runtime.c"
mkdir -p "$1"
out=$(cd "$1" && pwd)
cc=${CC:-cc}
command -v "$cc" >/dev/null || cc=gcc
command -v "$cc" >/dev/null || { echo "$0: no C compiler (cc or gcc): apt-get install gcc libc6-dev" >&2; exit 1; }
library="$out/libvrcorrect_xr_test_runtime.so"
if ! "$cc" -std=c11 -O2 -Wall -Wextra -Werror -shared -fPIC -fvisibility=hidden -o "$library.tmp" "$source" -ldl -lm; then
  echo "$0: building $source failed (the headers come from libopenxr-dev libvulkan-dev libgl-dev libx11-dev)" >&2
  exit 1
fi
mv "$library.tmp" "$library"
manifest="$out/vrcorrect_xr_test_runtime.json"
escaped=$(printf '%s' "$library" | sed 's/\\/\\\\/g; s/"/\\"/g')   # a JSON string
cat > "$manifest.tmp" <<JSON
{
    "file_format_version": "1.0.0",
    "runtime": {
        "name": "vrcorrect test runtime",
        "library_path": "$escaped"
    }
}
JSON
mv "$manifest.tmp" "$manifest"
echo "built $library"
echo "$manifest"
