#!/usr/bin/env bash
# Calibrate a variant of a task on pair seeds, never on evaluation seeds (docs/carracing-echo.md,
# "Calibration"): pi* as the quick preset trains it, then the benchmark's BC, BC refitted, DAgger
# and DART at DAgger's labels on the quick preset's pair seeds 1000-1019, into OUT, every fifth step
# of each demonstration held out to measure BC's and DAgger's loss on the expert's states. The calibration
# makes no pairs, so pairs.seeds is moved out of the way (1500-1501) for the config to take the pair
# seeds as the benchmark's. It resumes after a kill; another DART noise remakes the DART rows alone.
#
#   bash scripts/calibrate.sh TASK OUT 'TASK_OPTIONS' [DART_NOISE [--set KEY=VALUE ...]]
#   e.g. bash scripts/calibrate.sh carracing-echo runs/calibrate/echo-6 '{echo_rows: 6}' 0.2
#   (the --set arguments after the noise: other settings of the variant, e.g. BC's learning rate)
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 3 ] || { echo "usage: bash scripts/calibrate.sh TASK OUT 'TASK_OPTIONS' [DART_NOISE [--set KEY=VALUE ...]]" >&2; exit 2; }
task=$1 out=$2 options=$3 noise=${4:-0.2}
shift $(( $# < 4 ? $# : 4 ))
sets=(--set "task_options=$options" --set "pairs.seeds=1500-1501" --set "benchmark.seeds=1000-1019"
  --set "benchmark.methods=[bc, bc-refit, dagger, dart]" --set "benchmark.oracle=false"
  --set "benchmark.confirm_seeds=[]" --set "benchmark.dart_noise=$noise" --set "benchmark.held_out_every=5" "$@")
.venv/bin/metadagger pistar --task "$task" --preset quick --out "$out" "${sets[@]}"
.venv/bin/metadagger benchmark --out "$out" "${sets[@]}" --rebuild
