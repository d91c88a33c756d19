#!/usr/bin/env bash
# Issue 12's sim-to-real experiment (README "Sim-to-real"): four DIS-flow NN_cons recipes, then the
# real KITTI slices. About 50 minutes on 2 cores; resumable (finished steps are skipped).
#   A: 3 default streets   B: 3 varied streets   C: 3 default + 6 varied   D: C + KITTI 06's single frames
#   F: C with the training cameras tilted (pitch -1..3 deg, roll +-1 deg)   G: F + KITTI 06's single frames
# KITTI 06 is the validation slice of A-C (they never see a real frame); 07 is never trained on.
set -euo pipefail
cd "$(dirname "$0")/.."
export MUJOCO_GL=${MUJOCO_GL:-egl} PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl} OMP_NUM_THREADS=${OMP_NUM_THREADS:-2}
D=${1:-out/s2r}
K06=../shared/data/kitti/sequences/06
DS=.venv/bin/deepslam
render() { [ -f "$2/poses.txt" ] || $DS render --scene street --frames 200 --width 640 --seed "$1" --out "$2" --quiet ${3:-}; }
for s in 1 2 3; do render $s $D/street_s$s; render $s $D/varied_s$s --varied-layout; done
for s in 4 5 6 7 8 9; do render $s $D/varied2_s$s --varied-layout; done
DIS="--mode synthetic --synthetic-flow dis --dis-preset medium --frame-scales 1,0.65 --frame-step 2 --samples-per-epoch 20000
     --max-epochs 6 --nll-epochs 10 --threads 2 --data-threads 2 --seed 0 --net cpu --appearance-noise 6 --quiet
     --motion models/motion/kitti_s1.json"
train() { local out=$1; shift; [ -f "$out/model.safetensors" ] || $DS train $DIS "$@" --out "$out" $([ -d "$out" ] && echo --resume); }
MIX="$D/street_s1 $D/street_s2 $D/street_s3 $D/varied2_s4 $D/varied2_s5 $D/varied2_s6 $D/varied2_s7 $D/varied2_s8 $D/varied2_s9"
train $D/A_default --sample-pool 20000 --frames $D/street_s1 $D/street_s2 $D/street_s3
train $D/B_varied --sample-pool 20000 --frames $D/varied_s1 $D/varied_s2 $D/varied_s3
train $D/C_mixed --sample-pool 20000 --frames $MIX
train $D/D_mixed_06 --sample-pool 30000 --frames $MIX $K06
train $D/F_tilt --sample-pool 20000 --camera-tilt-deg=-1:3:1 --frames $MIX
train $D/G_tilt_06 --sample-pool 30000 --camera-tilt-deg=-1:3:1 --frames $MIX $K06
.venv/bin/python -m bench.results_real --out $D/real \
  --model "A=$D/A_default/model.safetensors" --model "B=$D/B_varied/model.safetensors" \
  --model "C=$D/C_mixed/model.safetensors" --model "D=$D/D_mixed_06/model.safetensors" \
  --model "F=$D/F_tilt/model.safetensors" --model "G=$D/G_tilt_06/model.safetensors"
