#!/usr/bin/env bash
# The flow network trained on a GPU machine in one call of under 10 minutes (docs/training.md, "On a GPU").
#
# On a bare NVIDIA machine whose python3 has torch with CUDA and no network: installs the project's missing
# dependencies from wheels carried in .whl/ (and headless GL from .gl/*.deb), then
#   1. renders 16 training sequences in parallel (MuJoCo on EGL; streets and rooms with movers, some at
#      3.33-5 Hz for large motions; seeds 101-116, none of them a held-out seed of bench.results_flow),
#   2. runs the CUDA tests (pytest -m cuda) and the device bench (bench/bench_device.py: NN_cons training
#      samples/s on cuda against this machine's CPU) beside the renders,
#   3. trains the flow network on the renders (bf16 autocast, batch 64, loader workers building the batches)
#      for the time left, the cosine schedule sized from a timed calibration run so that it ends decayed,
# and copies the log, the bench rows and the model (flow.safetensors, history.json, config.json, and the
# latest checkpoint while it trains) into $OUT (default out/device_flow).
#
#   bash scripts/device_flow_train.sh              # TOTAL_S=520: seconds the whole script may take
# Fixed seeds throughout; the GPU's sums (and its EGL renders) are not bit-for-bit the CPU's.
set -uo pipefail
cd "$(dirname "$0")/.."
export OUT=${OUT:-out/device_flow}
TOTAL_S=${TOTAL_S:-520}
FRAMES=${FRAMES:-150}
BATCH=${BATCH:-64}
DEVICE=${DEVICE:-cuda}
WORKERS=${WORKERS:-14}
mkdir -p "$OUT"
LOG="$OUT/log.txt"
exec > >(tee -a "$LOG") 2>&1
export PYTHONUNBUFFERED=1 MUJOCO_GL=egl PYOPENGL_PLATFORM=egl
say() { echo "== [$(printf '%4d' $SECONDS) s] $*"; }

say "setup"
if compgen -G ".gl/*.deb" >/dev/null; then for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; fi
PY=${PY:-python3}
if [ -z "${NO_INSTALL:-}" ]; then
if compgen -G ".whl/*.whl" >/dev/null; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "wheel install failed"; exit 2; }
fi
# the project pins Python 3.11 for its CPU stack; the GPU machine's python3 (3.12) holds the CUDA torch
$PY -m pip install -q --no-index --no-deps --no-build-isolation --no-compile --ignore-requires-python --upgrade --target /tmp/site . \
  || { echo "deepslam install failed"; exit 2; }
# the installed package (its folders mapped under deepslam.*) before the repository root, which holds bench/
export PYTHONPATH=/tmp/site:$PWD PYTHONSAFEPATH=1
fi
$PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
DS="$PY -m deepslam"

say "render check (EGL)"
if ! $DS render --scene street --frames 3 --width 320 --seed 1 --out /tmp/rcheck --quiet >/tmp/rcheck.log 2>&1; then
  tail -3 /tmp/rcheck.log
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  rm -rf /tmp/rcheck
  $DS render --scene street --frames 3 --width 320 --seed 1 --out /tmp/rcheck --quiet || { echo "no EGL rendering here"; exit 2; }
fi

say "renders (16 x $FRAMES frames, 12 at a time) beside the CUDA tests and the device bench"
R=/tmp/renders
JOBS=$(mktemp)
cat >"$JOBS" <<EOF
street 101 --moving-objects 3
street 102 --varied-layout --moving-objects 3
street 103 --narrow-layout --grainy-road --moving-objects 3
street 104 --varied-layout --grainy-road --moving-objects 5
street 105 --grainy-road --rate 5 --moving-objects 3
street 106 --varied-layout --grainy-road --rate 3.33
street 107 --narrow-layout --rate 5
street 108 --random-lighting --varied-layout --moving-objects 2
street 109 --grainy-road --sensor-noise 2 --moving-objects 4
street 110 --varied-layout --rate 3.33 --moving-objects 3
street 115 --narrow-layout --grainy-road --moving-objects 6
street 116 --varied-layout --grainy-road --rate 5 --moving-objects 2
room 111 --moving-objects 3
room 112 --moving-objects 6 --random-lighting
room 113
room 114 --moving-objects 2 --rate 10
EOF
(xargs -P 12 -L 1 sh -c 'scene=$0 seed=$1; shift 1; OMP_NUM_THREADS=1 '"$DS"' render --scene $scene --seed $seed \
   --frames '"$FRAMES"' --width 640 --out '"$R"'/${scene}_$seed --quiet "$@" >/tmp/render_$seed.log 2>&1 \
   && echo "rendered ${scene}_$seed $*" || echo "FAILED ${scene}_$seed: $(tail -1 /tmp/render_$seed.log)"' <"$JOBS") &
RENDER_PID=$!
(
  timeout 150 $PY -m pytest -q -p no:cacheprovider --import-mode=importlib -m cuda -rA tests/vo/test_flownet.py tests/vo/test_vo_train.py \
    >/tmp/cuda_tests.txt 2>&1; echo "pytest exit $?" >>/tmp/cuda_tests.txt
  OMP_NUM_THREADS=2 timeout 150 $PY - >"$OUT/bench_device.json" 2>/tmp/bench_device.err <<'EOF'
import json
from bench import bench_device
from bench.stamp import write_stamp
import os, torch
print(json.dumps(bench_device.run(quick=True), indent=1))
write_stamp(os.environ["OUT"])
EOF
  echo "bench exit $?" >>/tmp/cuda_tests.txt
) &
TEST_PID=$!
wait $RENDER_PID
say "renders done: $(ls $R | wc -l) sequences"
wait $TEST_PID
say "CUDA tests"; cat /tmp/cuda_tests.txt | tail -25; tail -3 /tmp/bench_device.err
say "device bench"; cat "$OUT/bench_device.json"

SEQS=$(ls -d $R/*/ 2>/dev/null | while read -r d; do [ -f "$d/poses.txt" ] && echo "$d"; done)
[ -n "$SEQS" ] || { echo "no finished renders"; exit 2; }
TRAIN="--crop 128x320 --batch $BATCH --lr 1e-3 --seed 0 --device $DEVICE --loader-workers $WORKERS --quiet"

say "calibration: 120 steps on one sequence"
$DS train-flow --sequence $(echo "$SEQS" | head -1) --out /tmp/flowcal --max-steps 120 $TRAIN >/dev/null
PER_STEP=$($PY -c "
from deepslam.flow.net import load_flow_model
_, m = load_flow_model('/tmp/flowcal/flow.safetensors'); print(m['train_seconds'] / m['steps'])")
LOAD_S=45   # reading the renders into memory, measured on this script's first runs
LOAD_S=${LOAD_S:-$LOAD_S}
LEFT=$((TOTAL_S - SECONDS - LOAD_S - 15)); [ "$LEFT" -ge 60 ] || LEFT=60
STEPS=$($PY -c "print(max(500, int($LEFT / $PER_STEP * 0.92)))")
say "training: $PER_STEP s/step (calibration, warm-up included) -> $STEPS steps in about $LEFT s"

(while sleep 30; do [ -f /tmp/flowrun/checkpoint.safetensors ] && cp /tmp/flowrun/checkpoint.safetensors "$OUT/.ck" \
   && mv "$OUT/.ck" "$OUT/checkpoint.safetensors"; done) &
COPY_PID=$!
$DS train-flow --sequence $SEQS --out /tmp/flowrun --max-steps "$STEPS" --max-minutes "$($PY -c "print(($LEFT + 20) / 60)")" $TRAIN
kill $COPY_PID 2>/dev/null
cp /tmp/flowrun/flow.safetensors /tmp/flowrun/history.json /tmp/flowrun/config.json "$OUT"/ 2>/dev/null
cp /tmp/flowrun/checkpoint.safetensors "$OUT"/ 2>/dev/null
ls $R > "$OUT/renders.txt"
say "done"; ls -la "$OUT"
$PY -c "
import json; h = json.load(open('$OUT/history.json')); print('history', h[-3:] if h else h)" || true
