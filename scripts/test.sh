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
# Two test processes (pytest-xdist), each module's tests in one of them so that a module's
# fixtures are made once: most tests run one process at a time, and this keeps both cores busy.
exec .venv/bin/python -m pytest -m "not slow" -n 2 --dist loadfile "$@"
