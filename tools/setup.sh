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

# Debian packages: the venv module (and, from the renderer on, GL/X libraries).
need_apt=()
"$PY" -c 'import ensurepip, venv' 2>/dev/null || need_apt+=(python3-venv)
if [ ${#need_apt[@]} -gt 0 ]; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "installing Debian packages: ${need_apt[*]}"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_apt[@]}" >/dev/null
  else
    echo "please install the Debian packages: ${need_apt[*]}" >&2
    exit 1
  fi
fi

[ -x .venv/bin/python ] || "$PY" -m venv .venv

# Reinstall only when the dependency list changed.
stamp=.venv/.vrcorrect-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "installing Python packages into .venv (first run takes a few minutes) ..."
  .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
  # torch==2.13.0 (CPU build) is pinned in the 'solve' extra: pip takes it from this machine's disk.
  .venv/bin/python -m pip install -q --disable-pip-version-check -e ".[solve,metrics,test]" 2>&1 \
    | grep -v -e "^WARNING: Location" -e "BuildBackendWarning" || true
  .venv/bin/python -c "import vrcorrect, numpy, scipy, colour, PIL, torch, pytest, hypothesis" \
    || { echo "installation failed" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
