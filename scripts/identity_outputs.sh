#!/usr/bin/env bash
# Outputs of every job, hashed: run before and after a change that should not alter any output (a
# restructure) and compare the two lists (`diff`). Renders, gen shards, a short synthetic and supervised
# training, vo (default, network, epipolar), slam, tune-free stress --quick, KITTI 06.
#
#   bash scripts/identity_outputs.sh OUT > OUT.sha256        # about 4 minutes on 2 cores
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: identity_outputs.sh OUT}
DS="${DS:-.venv/bin/deepslam}"
DATA=${DATA:-../shared/data}
export MUJOCO_GL=${MUJOCO_GL:-egl} PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
rm -rf "$OUT" && mkdir -p "$OUT"
q=--quiet
$DS render --scene street --frames 30 --width 320 --moving-objects 2 --seed 5 --out "$OUT/street" $q >/dev/null
$DS render --scene room --trajectory drone --frames 20 --width 240 --seed 6 --out "$OUT/room" $q >/dev/null
$DS fit-motion --poses "$OUT/street/poses.txt" --out "$OUT/motion.json" >/dev/null
$DS gen --source "$OUT/street" --motion "$OUT/motion.json" --samples 256 --resolution 48x160 --out "$OUT/shards" \
    --workers 1 $q >/dev/null
$DS train --mode synthetic --net cpu --source "$OUT/street" --motion "$OUT/motion.json" --max-samples 2048 \
    --threads 2 --out "$OUT/nn_syn" $q >/dev/null
$DS train --mode supervised --net cpu --sequence "$OUT/street" --flow gt --max-samples 1024 --threads 2 \
    --out "$OUT/nn_sup" $q >/dev/null
$DS vo --sequence "$OUT/street" --out "$OUT/vo_default.txt" >/dev/null
$DS vo --sequence "$OUT/street" --pose net --out "$OUT/vo_net.txt" >/dev/null
$DS vo --sequence "$OUT/street" --model "$OUT/nn_syn/model.safetensors" --out "$OUT/vo_trained.txt" >/dev/null
$DS vo --sequence "$OUT/room" --out "$OUT/vo_room.txt" >/dev/null
$DS slam --sequence "$OUT/street" --out "$OUT/slam.txt" >/dev/null
$DS slam --sequence "$OUT/room" --out "$OUT/slam_room.txt" >/dev/null
$DS vo --sequence "$DATA/kitti/sequences/06" --out "$OUT/vo_kitti06.txt" >/dev/null
$DS stress --quick --out "$OUT/stress" >/dev/null
# records that name the machine or the time are left out; everything else is hashed
find "$OUT" -type f ! -name '*.log' ! -name 'summary.json' ! -name 'history.json' ! -name '*.png' \
    ! -name 'manifest.json' ! -path '*/tensorboard/*' -print0 | sort -z | xargs -0 sha256sum | sed "s#$OUT/##"
