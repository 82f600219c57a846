#!/usr/bin/env bash
# Installs what the tests need (tools/setup.sh), then runs them:
#
#   bash tools/test.sh           ruff check, then the whole test suite in one process (what CI runs:
#                                .ci/run; about 40 minutes on 2 cores)
#   bash tools/test.sh --parallel ruff check, then every test not marked serial on every core
#                                (pytest-xdist, a test file to a worker, so that a file's session
#                                fixtures are built once; a crashed worker ends the run rather than
#                                being replaced), then the serial ones (they read a clock) alone.
#                                Not yet CI's way: from a fresh clone on 2 idle cores it took 28.5 min
#                                (set-up included; serial about 40), and a worker died in an in-process
#                                GLFW window test (test_runtime_window.py) that passes in the serial run
#   bash tools/test.sh --fast    the developer's loop: the tests that need no OpenGL, X display, OpenXR,
#                                torch or ColorVideoVDP and are not marked slow (tests/conftest.py marks
#                                them), on every core (pytest-xdist); about 550 tests in under 2 minutes
#                                on 2 cores. Extra arguments go to pytest.
#   bash tools/test.sh ARGS      pytest ARGS after the set-up (for example tests/test_budget.py -x)
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
if [ "${1:-}" = "--fast" ]; then
  shift
  exec .venv/bin/python -m pytest -q -p no:cacheprovider -n auto -m "not (gl or x or xr or torch or cvvdp or slow)" "$@"
fi
if [ $# -eq 0 ]; then
  .venv/bin/ruff check .
  exec .venv/bin/python -m pytest -q -p no:cacheprovider
fi
if [ "${1:-}" = "--parallel" ]; then
  shift
  .venv/bin/ruff check .
  status=0
  .venv/bin/python -m pytest -q -p no:cacheprovider -n auto --dist loadfile --max-worker-restart=0 -m "not serial" || status=$?
  .venv/bin/python -m pytest -q -p no:cacheprovider -m serial || status=$?
  exit "$status"
fi
exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
