#!/usr/bin/env bash
# Quick start, command 2: set up, check the format and lint (ruff), then run the test suite
# (tests marked slow are left out). The label page's browser test runs where Debian's chromium,
# chromium-driver and the browser extra are installed (.ci/run installs them) and is skipped,
# saying so, elsewhere.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test,fetch,ray,minari,tensorboard,tune,video,label
.venv/bin/ruff format --check --quiet . || { echo "ruff format: the files above need formatting; run .venv/bin/ruff format ." >&2; exit 1; }
.venv/bin/ruff check --quiet .
export MUJOCO_GL="${MUJOCO_GL:-egl}"
exec .venv/bin/python -m pytest -m "not slow" "$@"
