#!/usr/bin/env bash
# The learned flow fine-tuned on real, unlabelled KITTI 06 pairs (both cameras; census loss with forward-backward
# occlusion masks and edge-aware smoothness, flow/unsup.py) beside rendered pairs with exact flow that keep it
# anchored (the stage-1 `deepslam dataset` sequences and the six grainy-road streets of scripts/train_flow_model.sh).
# KITTI 07 is never trained on: it is where the result is measured. About
# 90 minutes on 2 cores (renders ~5 min, 2,000 steps ~37 min, twice); resumable.
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl} PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
DS=.venv/bin/deepslam
KITTI=${KITTI:-../shared/data/kitti/sequences}
CFG=$(mktemp); echo '{"moving_objects": [2, 8], "varied_layout_fraction": 0.5}' > "$CFG"
[ -f out/flow_data/manifest.json ] || $DS dataset --config "$CFG" --scenes street,room --sequences 6 --frames 150 \
  --width 640 --seed 11 --out out/flow_data --executor local --quiet $([ -d out/flow_data ] && echo --resume)
[ -f out/flow_held/manifest.json ] || $DS dataset --config "$CFG" --scenes street,room --sequences 2 --frames 60 \
  --width 640 --seed 21 --out out/flow_held --executor local --quiet $([ -d out/flow_held ] && echo --resume)
G=out/flowg
render() { [ -f "$2/poses.txt" ] || $DS render --scene street --frames ${4:-200} --width 640 --seed "$1" --out "$2" --quiet $3; }
for s in 31 32 33; do render $s $G/varied_g$s "--varied-layout --grainy-road --moving-objects 3"; done
for s in 34 35 36; do render $s $G/narrow_g$s "--narrow-layout --grainy-road --moving-objects 3"; done
render 41 $G/held_g41 "--grainy-road --moving-objects 8" 60   # held out: evaluation only
$DS train-flow --init models/flow_learned.safetensors --lr 2e-4 --max-steps 2000 --quiet \
  --sequence out/flow_data $G/varied_g31 $G/varied_g32 $G/varied_g33 $G/narrow_g34 $G/narrow_g35 $G/narrow_g36 \
  --real $KITTI/06 --real-batch 4 --out out/flow_real $([ -d out/flow_real ] && echo --resume)
.venv/bin/python -m bench.results_flow --model out/flow_real/flow.safetensors \
  --held out/flow_held/seq_0000 out/flow_held/seq_0001 $G/held_g41 --pairs 20 --out out/results/flow_real
# the same with second-order smoothness (the first run over-moved the road: bench.results_road)
$DS train-flow --init models/flow_learned.safetensors --lr 2e-4 --max-steps 2000 --quiet \
  --sequence out/flow_data $G/varied_g31 $G/varied_g32 $G/varied_g33 $G/narrow_g34 $G/narrow_g35 $G/narrow_g36 \
  --real $KITTI/06 --real-batch 4 --smooth-order 2 --out out/flow_real2 $([ -d out/flow_real2 ] && echo --resume)
.venv/bin/python -m bench.results_flow --model out/flow_real2/flow.safetensors \
  --held out/flow_held/seq_0000 out/flow_held/seq_0001 $G/held_g41 --pairs 20 --out out/results/flow_real2
