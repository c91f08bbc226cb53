#!/usr/bin/env bash
# Quick start, command 1: set up and run the main job on the small default preset.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/metadagger reproduce --task carracing --preset quick --out runs/quick "$@"
