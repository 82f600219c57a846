#!/usr/bin/env bash
# Installs what the tests need (tools/setup.sh), then runs them:
#
#   bash tools/test.sh           ruff check, then the whole test suite (what CI runs: .ci/run): every
#                                test not marked serial on every core (pytest-xdist, a test file to a
#                                worker, so that a file's session fixtures are built once; a worker
#                                that dies ends the run rather than being replaced), then the serial
#                                ones (they read a clock, or load an OpenXR runtime in-process) alone.
#                                About 21 minutes from a fresh clone on 2 cores, set-up included
#   bash tools/test.sh --serial  ruff check, then the whole suite in one process (about 40 minutes on 2
#                                cores): the order of a plain pytest run
#   bash tools/test.sh --fast    the developer's loop: the tests that need no OpenGL, X display, OpenXR,
#                                torch or ColorVideoVDP and are not marked slow (tests/conftest.py marks
#                                them), on every core (pytest-xdist); about 660 tests in under 2 minutes
#                                on 2 cores. Extra arguments go to pytest.
#   bash tools/test.sh ARGS      pytest ARGS after the set-up (for example tests/test_budget.py -x)
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
if [ "${1:-}" = "--fast" ]; then
  shift
  exec .venv/bin/python -m pytest -q -p no:cacheprovider -n auto -m "not (gl or x or xr or torch or cvvdp or slow)" "$@"
fi
if [ "${1:-}" = "--serial" ]; then
  shift
  .venv/bin/ruff check .
  exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
fi
if [ $# -eq 0 ]; then
  .venv/bin/ruff check .
  status=0
  .venv/bin/python -m pytest -q -p no:cacheprovider -n auto --dist loadfile --max-worker-restart=0 -m "not serial" \
    || status=$?
  .venv/bin/python -m pytest -q -p no:cacheprovider -m serial || status=$?
  exit "$status"
fi
exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
