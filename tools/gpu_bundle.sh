#!/usr/bin/env bash
# Gathers, on this machine, what a lent GPU machine needs to run vrcorrect's GL benches there: it has
# no network, a Python 3.12 with numpy, scipy, tqdm, pytest and PyTorch (CUDA; bench cost --peer torch
# uses that torch, so none is carried here), and no OpenGL dispatch libraries. The Debian packages go
# to .gl/ and the wheels to .whl/ (both listed in .git/info/exclude: pass them as the device call's
# `carry`). Then run tools/gpu_check.sh there (issue 43's checks, at most about 8 minutes), e.g.
#   run(command="bash tools/gpu_check.sh", carry=[".gl", ".whl"], timeout_s=560)
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p .gl .whl
for d in .gl .whl; do
    grep -qx "/$d/" .git/info/exclude 2>/dev/null || echo "/$d/" >> .git/info/exclude
done
ls /var/lib/apt/lists/*_Packages > /dev/null 2>&1 || apt-get update -qq      # a fresh machine has no package lists
(cd .gl && apt-get download libglvnd0 libegl1 libgl1 libglx0 libopengl0 libgles2)
python3 -m pip download -q --only-binary=:all: --no-deps --python-version 3.12 \
    --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 -d .whl \
    moderngl==5.13.0 glcontext==3.1.0 colour-science==0.4.7
du -sh .gl .whl
