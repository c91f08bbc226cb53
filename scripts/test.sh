#!/usr/bin/env bash
# Quick start, command 2: set up and run the test suite (tests marked slow are left out).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh test,fetch,ray,minari,tensorboard,tune,video
export MUJOCO_GL="${MUJOCO_GL:-egl}"
exec .venv/bin/python -m pytest -m "not slow" "$@"
