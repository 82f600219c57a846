#!/usr/bin/env bash
# On a lent GPU machine (see tools/gpu_bundle.sh): installs the carried GL libraries and wheels where
# they are missing, then, each step under its own time limit (55 + 85 + 140 + 70 + 55 s, each killed
# at most 10 s after it: with the set-up, under 8 minutes even if every step runs to its limit), runs
# issue 43's GPU checks (the JSON reports and a log go to $OUT, default ./gpu-check;
# nothing in docs/ is written):
#   1. the line transforms and the real-time frame against numpy and the CPU twin on this driver
#      (tests/test_fft_line.py and the twin tests of tests/test_runtime_admm.py: float tolerance on the
#      GPU, at power-of-two, odd and past-2048 lengths);
#   2. bench workgroups at one Quest 2 eye (the work-group shapes, interleaved, GPU time);
#   3. bench cost at one Quest 2 eye, every method, with the torch/cuFFT peer (--peer torch: torch is
#      the machine's own, not carried) timed in the same run on the same GPU;
#   4. bench cost, the default and the peer, at a Quest 3 eye (2064x2208, quest3);
#   5. bench cost, the default, at a 3660x3200 eye (quest3).
# A step that fails or runs out of time is reported and the others still run; the exit status is
# the number of steps that failed.
#   usage: bash tools/gpu_check.sh [--size WxH] [--frames N] [--skip-tests]
set -uo pipefail
cd "$(dirname "$0")/.."
size=1832x1920
frames=40
tests=1
while [ $# -gt 0 ]; do
    case "$1" in
        --size) size="$2"; shift 2 ;;
        --frames) frames="$2"; shift 2 ;;
        --skip-tests) tests=0; shift ;;
        *) echo "gpu_check.sh: unknown argument $1 (expected --size WxH, --frames N or --skip-tests)" >&2; exit 2 ;;
    esac
done
out="${OUT:-gpu-check}"
mkdir -p "$out"
log="$out/gpu_check.log"
: > "$log"
if ! ldconfig -p | grep -q 'libEGL.so.1 '; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
nvidia_egl=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
if [ -z "${__EGL_VENDOR_LIBRARY_FILENAMES:-}" ] && [ -f "$nvidia_egl" ]; then
    export __EGL_VENDOR_LIBRARY_FILENAMES="$nvidia_egl"
fi
if ! python3 -c "import moderngl, glcontext, colour" 2>/dev/null; then
    python3 -m pip install -q --no-index --no-deps --target /tmp/vrcorrect-site .whl/*.whl
    export PYTHONPATH="/tmp/vrcorrect-site${PYTHONPATH:+:$PYTHONPATH}"
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,clocks.max.sm,memory.total --format=csv,noheader 2>&1 | tee -a "$log" || true
python3 -c "import torch; print('torch', torch.__version__, 'cuda' if torch.cuda.is_available() else 'no cuda')" 2>&1 \
    | tee -a "$log" || true

failed=0
step() {                      # step NAME SECONDS COMMAND...: run under a time limit, log, count failures
    local name="$1" limit="$2"; shift 2
    local t0=$SECONDS
    echo "== $name (at most ${limit} s): $*" | tee -a "$log"
    timeout --kill-after=10 "$limit" "$@" 2>&1 | tee -a "$log"
    local rc=${PIPESTATUS[0]}
    echo "== $name: exit $rc after $((SECONDS - t0)) s" | tee -a "$log"
    [ "$rc" -eq 0 ] || failed=$((failed + 1))
}
cli=(python3 -m vrcorrect.apps.cli bench)
if [ "$tests" -eq 1 ]; then
    step "tests on this driver" 55 python3 -m pytest -q -p no:cacheprovider -x tests/test_fft_line.py \
        tests/test_runtime_admm.py -k "line_transform or lines_side_by_side or links_up_to or iteration_by_iteration or wide_frame"
fi
step "bench workgroups" 85 "${cli[@]}" workgroups --size "$size" --frames 20 \
    --json "$out/workgroups.json" --no-write --force
step "bench cost, quest2, every method, peer torch" 140 "${cli[@]}" cost --size "$size" --frames "$frames" \
    --peer torch --json "$out/cost.json" --no-write --force
step "bench cost, quest3 eye, peer torch" 70 "${cli[@]}" cost --size 2064x2208 --display quest3 --frames 20 \
    --default-only --peer torch --json "$out/cost_quest3.json" --no-write --force
step "bench cost, 3660x3200 eye" 55 "${cli[@]}" cost --size 3660x3200 --display quest3 --frames 5 \
    --default-only --json "$out/cost_3660x3200.json" --no-write --force
echo "gpu_check.sh: $failed step(s) failed; reports in $out" | tee -a "$log"
exit "$failed"
