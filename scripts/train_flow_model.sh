#!/usr/bin/env bash
# Reproduces the shipped learned flow estimator (models/flow_learned.safetensors): trained only on renders.
# Data: 6 `deepslam dataset` sequences (street and room, 2-8 movers; forward + backward pairs) and the 12
# street renders of scripts/sim_to_real_experiment.sh (forward pairs); then fine-tuned with grainy-road streets
# added (stage 2). About 100 minutes on 2 cores (renders ~11 min, loading ~3+3 min, 14,500 steps ~60 min,
# 4,000 steps ~17 min); resumable (finished steps are skipped).
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl} PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
DS=.venv/bin/deepslam
S=out/s2r
CFG=$(mktemp); echo '{"moving_objects": [2, 8], "varied_layout_fraction": 0.5}' > "$CFG"
[ -f out/flow_data/manifest.json ] || $DS dataset --config "$CFG" --scenes street,room --sequences 6 --frames 150 \
  --width 640 --seed 11 --out out/flow_data --executor local --quiet $([ -d out/flow_data ] && echo --resume)
[ -f out/flow_held/manifest.json ] || $DS dataset --config "$CFG" --scenes street,room --sequences 2 --frames 60 \
  --width 640 --seed 21 --out out/flow_held --executor local --quiet $([ -d out/flow_held ] && echo --resume)
render() { [ -f "$2/poses.txt" ] || $DS render --scene street --frames 200 --width 640 --seed "$1" --out "$2" --quiet ${3:-}; }
for s in 1 2 3; do render $s $S/street_s$s; render $s $S/varied_s$s --varied-layout; done
for s in 4 5 6 7 8 9; do render $s $S/varied2_s$s --varied-layout; done
$DS train-flow --sequence out/flow_data $S/street_s1 $S/street_s2 $S/street_s3 $S/varied_s1 $S/varied_s2 $S/varied_s3 \
  $S/varied2_s4 $S/varied2_s5 $S/varied2_s6 $S/varied2_s7 $S/varied2_s8 $S/varied2_s9 \
  --out out/flow_model --max-steps 20000 --stop-after 14500 --quiet $([ -d out/flow_model ] && echo --resume)
# stage 2: fine-tuned on the same data plus six streets with grainy asphalt and three
# movers each (the learned flow read the grainy road at 3.2 m where it read the smooth one at 1.6); about 25 minutes
G=out/flowg
for s in 31 32 33; do render $s $G/varied_g$s "--varied-layout --grainy-road --moving-objects 3"; done
for s in 34 35 36; do render $s $G/narrow_g$s "--narrow-layout --grainy-road --moving-objects 3"; done
[ -f $G/held_g41/poses.txt ] || $DS render --scene street --frames 60 --width 640 --seed 41 --out $G/held_g41 --quiet \
  --grainy-road --moving-objects 8   # held out: evaluation only
$DS train-flow --init out/flow_model/flow.safetensors --lr 3e-4 --max-steps 4000 --quiet \
  --sequence out/flow_data $S/street_s1 $S/street_s2 $S/street_s3 $S/varied_s1 $S/varied_s2 $S/varied_s3 \
  $S/varied2_s4 $S/varied2_s5 $S/varied2_s6 $S/varied2_s7 $S/varied2_s8 $S/varied2_s9 \
  $G/varied_g31 $G/varied_g32 $G/varied_g33 $G/narrow_g34 $G/narrow_g35 $G/narrow_g36 \
  --out $G/ft $([ -d $G/ft ] && echo --resume)
cp $G/ft/flow.safetensors models/flow_learned.safetensors
.venv/bin/python -m bench.results_flow --held out/flow_held/seq_0000 out/flow_held/seq_0001 $G/held_g41 --pairs 20
