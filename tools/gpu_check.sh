#!/usr/bin/env bash
# On a lent GPU machine (see tools/gpu_bundle.sh): installs the carried GL libraries and wheels where
# they are missing, then times the real-time default at headset size, one eye: the work-group shapes
# against each other (bench workgroups) and the frame's cost and pass times (bench cost). The JSON
# reports go to $OUT (default ./gpu-check); nothing in docs/ is written.
#   usage: bash tools/gpu_check.sh [--size WxH] [--frames N]
set -euo pipefail
cd "$(dirname "$0")/.."
size=1832x1920
frames=40
while [ $# -gt 0 ]; do
    case "$1" in
        --size) size="$2"; shift 2 ;;
        --frames) frames="$2"; shift 2 ;;
        *) echo "gpu_check.sh: unknown argument $1 (expected --size WxH or --frames N)" >&2; exit 2 ;;
    esac
done
out="${OUT:-gpu-check}"
mkdir -p "$out"
if ! ldconfig -p | grep -q 'libEGL.so.1 '; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
if ! python3 -c "import moderngl, glcontext, colour" 2>/dev/null; then
    python3 -m pip install -q --no-index --no-deps --target /tmp/vrcorrect-site .whl/*.whl
    export PYTHONPATH="/tmp/vrcorrect-site${PYTHONPATH:+:$PYTHONPATH}"
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv,noheader 2>/dev/null || true
python3 -m vrcorrect.apps.cli bench workgroups --size "$size" --frames "$frames" \
    --json "$out/workgroups.json" --no-write --force
python3 -m vrcorrect.apps.cli bench cost --size "$size" --frames "$frames" --json "$out/cost.json" --no-write --force
