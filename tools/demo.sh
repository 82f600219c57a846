#!/usr/bin/env bash
# The main job on the bundled default: what the sample prescription's eyes see of the
# bundled sample image on a Meta Quest 2, written as PNGs into ./out (or the folder given).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
exec .venv/bin/vrcorrect demo --out "${1:-out}" --force
