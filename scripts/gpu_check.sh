#!/usr/bin/env bash
# The GPU path, checked in one short script on a machine with a CUDA GPU (docs/performance.md,
# "On a GPU"). Needs metadagger and its dependencies importable by python3 beside a CUDA build of
# torch. Writes what it finds under ${OUT:-runs/gpu-check}:
#   1. the tests marked for a GPU (lanes, batched head fits, whole-network fits: deterministic,
#      and near the CPU's numbers);
#   2. the CarRacing ci preset made twice on the GPU: every artifact but the timings and the
#      journals' row order byte-identical;
#   3. pi*'s whole-network fit on the Fetch paper preset, seconds per step on this host's CPU and GPU;
#   4. this host's CPU kernel fingerprint against the recorded AMD EPYC's.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${OUT:-runs/gpu-check}"
mkdir -p "$out"
export MUJOCO_GL="${MUJOCO_GL:-egl}" PYTHONUNBUFFERED=1
python3 -c "import torch; assert torch.cuda.is_available(), 'torch sees no CUDA GPU'; print('torch', torch.__version__, torch.cuda.get_device_name(0))"
python3 -m pytest -q -p no:cacheprovider tests/utils/test_device.py 2>&1 | tee "$out/tests.log"
for copy in a b; do
  python3 -m metadagger.cli reproduce --task carracing --preset ci --device cuda --workers 4 \
    --out "$out/ci-$copy" >"$out/ci-$copy.log" 2>&1
done
python3 - "$out/ci-a" "$out/ci-b" <<'EOF' | tee "$out/compare.txt"
import pathlib, sys
a, b = (pathlib.Path(p) for p in sys.argv[1:])
skip = {"stage_times.json", "report.md"}
files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.name not in skip and p.suffix != ".jsonl")
differ = [str(f) for f in files if not (b / f).is_file() or (a / f).read_bytes() != (b / f).read_bytes()]
print(f"{len(files) - len(differ)} of {len(files)} files byte-identical; differ: {differ}")
sys.exit(1 if differ else 0)
EOF
python3 -m metadagger.cli bench fit --task fetch --preset paper --steps 200 --out "$out/fit-fetch.json"
python3 -m metadagger.cli bench ops --out "$out/ops.json" --compare results/machines/amd-epyc-zen3.json >/dev/null
python3 -c "import json; print(json.load(open('$out/ops.json'))['compared'])"
