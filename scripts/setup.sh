#!/usr/bin/env bash
# Create .venv (if missing) and install metadagger with the given extras.
# The CPU build of PyTorch is pinned in constraints.txt, the one place that pins it.
# Usage: bash scripts/setup.sh [EXTRAS]   e.g. bash scripts/setup.sh test,fetch,ray
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-}"
python="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$python" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
target="."
[ -n "$extras" ] && target=".[$extras]"
.venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt -e "$target"
