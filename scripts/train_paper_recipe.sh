#!/usr/bin/env bash
# The paper's recipe at scale on the cpu preset: NN_cons trained (a) synthetically from the single frames of
# two rendered towns and (b) supervised on the same renders' frame pairs (exact flow, ground-truth poses),
# each for the same budget of samples (default 2,000,000), strides 1 and 2 mixed, the paper's L1 loss with
# rotations x50, Adam (amsgrad), batch 128, cyclic learning rate 1e-4..1e-3 (half-cycle 1000 steps) halved
# after 10 epochs without a held-out improvement, stopped under 1e-5; then the uncertainty heads on the 10 %
# hold-out with the pose frozen. The synthetic motions are drawn from kernel density fits of the training renders'
# own motions at strides 1 and 2 (the paper's "statistics of the training data's motion"; only their
# distribution is used, never a pair's pose). Not the paper's Student-t per DoF: on these routes (straight
# runs with exactly zero rotation, then turns) its fit degenerates (df 0.05, scale 1e-20: exact zeros with
# enormous tails), where the joint KDE keeps both the straight runs and the turns.
#
#   bash scripts/train_paper_recipe.sh [OUT] [SAMPLES] [SEEDS]     # OUT = out/paper_recipe, SEEDS = "0"
#   BF16=off bash scripts/train_paper_recipe.sh ...                  # bf16 autocast: auto (default), on, off
#   NET=paper bash scripts/train_paper_recipe.sh out/paper_recipe_paper   # the paper's 96x320 network
#   PARALLEL=1 EXTRA="--max-minutes 6" bash scripts/train_paper_recipe.sh ...   # on a GPU: every model at once
#   SYNTH_FLOW=dis bash scripts/train_paper_recipe.sh bench/paper_recipe      # the synthetic model on DIS flow
#   SPEED_SCALE=0.4,1.5 SYNTH_FLOW=dis bash scripts/train_paper_recipe.sh ...  # ... with the turn radius freed
#   MIRROR=0 bash scripts/train_paper_recipe.sh ...                  # the towns' own motions, turning one way
#   BODY=1 SYNTH_FLOW=dis bash scripts/train_paper_recipe.sh ...     # ... with KITTI's body pitch and roll added
#   MIRROR_FRAMES=0 SYNTH_FLOW=dis bash scripts/train_paper_recipe.sh ...  # street frames not flipped left-right
#   SAMEPATIENCE=0 bash scripts/train_paper_recipe.sh OUT 2000000 "1 2"  # more seeds: no supervised_samepatience
#   SCENE=room DEPTH=1 bash scripts/train_paper_recipe.sh ...        # RGB-D: the frame's depth as an input channel
#   SCENE=room DEPTH=1 SPEED_SCALE=0.15,1.0 bash scripts/train_paper_recipe.sh ...  # ... the rooms' speed freed
#   SCENE=room TRAJECTORY=handheld DEPTH=1 bash scripts/train_paper_recipe.sh ...  # ... rooms walked hand-held
#
# bf16 autocast is on by default where the CPU computes bf16 natively (AVX-512 BF16); on a CPU without it,
# autocast is emulated and ~10x slower than float32 (measured: 389 against 40 s for 10,240 samples on an
# AVX2-only EPYC), so auto turns it off there. A run resumes only at the precision it started with.
#
# Resumable: every step whose output exists is skipped and a training folder with a checkpoint continues
# with --resume (a killed run loses at most one epoch). About 45 minutes per model on 2 idle cores at
# 2,000,000 samples. docs/training.md says how the figures are read (bench.results_repro).
# On a GPU the synthetic flow is made on the GPU too (`train --synth-device auto`), a model takes minutes, and
# PARALLEL=1 trains every model of every seed at once; EXTRA adds flags to each `train` (a time cap, say).
# SYNTH_FLOW=dis trains the synthetic model on DIS flow of views rendered from the single frames
# (synthetic_dis_cons_sSEED; POOL samples made once, POOL_PATIENCE passes without improvement halve the rate) and
# the supervised model on DIS flow of the renders' own pairs (supervised_dis_cons_sSEED); SKIP_SYNTHETIC=1 trains
# the supervised ones only, on either flow (more seeds of them in minutes, where each synthetic one takes an hour on
# 2 cores).
# SCENE=room makes the RGB-D rows instead: the same recipe on two simulated rooms rendered as a Kinect would
# see them (640x480, f = 537 px, 30 Hz; `render --scene room`, exact depth), motions fitted on the rooms' own
# camera motion, the network's input 96 x 128 (the frames' 4:3 aspect; the cpu preset's 48 x 160 is the street
# camera's): room_train_sK, motion_room..._sK.json, room_synthetic..._cons_sSEED, room_supervised_cons_sSEED.
# SPEED_SCALE=LO,HI draws the synthetic motions from the same fits with each translation scaled by a log-uniform
# factor in [LO, HI] (`fit-motion --speed-scale`: the towns' car takes every corner on one arc; this frees the
# turn radius) into motion_speedscale_sK.json, and the synthetic models go to ..._speedscale_cons_sSEED.
# The motions are fitted with their left-right mirror images (`fit-motion --mirror`: the towns turn one way only;
# docs/experiments/2026-12-06_turn_radius_prior.md, section 6) into motion[_speedscale]_mirror_sK.json, the
# synthetic models into ..._mirror_cons_sSEED; MIRROR=0 fits the towns' own motions (motion_sK.json, the models
# without the suffix). BODY=1 adds to each drawn motion the frame-to-frame pitch and roll of KITTI 00-05 and 08-10's
# ground truth (`fit-motion --body-from`, from KITTI_POSES, default ../shared/data/kitti/poses; never 06 or 07, the
# validation slices): the car body's motion on its suspension, which the towns' car lacks (suffix _body). The
# supervised models do not depend on the prior. DEPTH=1 (with SCENE=room) gives every model the first frame's
# inverse depth as a third input channel (`train --depth-channel`; `vo` then reads each frame's depth), the
# folders' suffix _depth before _cons. The training rooms' depth is exact; the unseen room's and TUM's are a
# sensor's, with holes. TRAJECTORY=handheld (with SCENE=room) renders the training rooms walked hand-held
# (`render --trajectory handheld`: a walking pace and the hand's sway, as a hand-held RGB-D camera moves) into
# room_handheld_train_sK, fits the motions on them (motion_room_handheld..._sK.json) and names the models
# room_handheld_...: the prior then holds a hand-held camera's motion, drawn from the training data as the paper's.
# LEVER=M (SCENE=street; default 0.84, KITTI's) renders the training towns with the camera M metres ahead of the rear
# axle (`render --camera-ahead M`), so that it slides sideways into a turn as KITTI's camera does and the prior fitted
# on them holds that slide: renders street_lever_train_sK, fits motion_lever..._sK.json, models lever_...
# (docs/experiments/2026-12-07_lever_arm_training.md: with the turn radius freed it halves KITTI 07's drift). With
# SPEED_SCALE the factor then scales the axle's motion and keeps the slide (`fit-motion --speed-scale-lever`; fits
# and models named _axlescale instead of _speedscale). LEVER=0 trains on the axle-camera towns (the models without
# the lever_ prefix, as every street model trained before the lever was the default). MIRROR_FRAMES=1 (SCENE=street's
# default; 0 for the rooms) trains the synthetic models on every single frame and its left-right mirror image
# (`train --mirror-frames`; models named _mirrorframes before _cons): the towns' car keeps right, and a network
# trained on their frames alone reads its distance from where their open road lies (bench.results_layout). The
# street models named without _mirrorframes were trained with MIRROR_FRAMES=0.
# PP_CROP=1 (SCENE=street with SYNTH_FLOW=dis) renders the training towns on a wider canvas at the 414 px camera's focal
# length (428 x 129: street_lever_wide_train_sK) and trains the synthetic model on a 640 x 193 window of each frame as
# read (`train --crop-window 640,193`) at a random place, so the principal point of its samples spreads over +-7 px of
# 414 as real cameras place it, with the network told where it lies (`--coord-channels`): models named _ppcrop
# before _cons (docs/experiments/2026-12-08_principal_point_offset.md). The supervised twin is not trained again.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/paper_recipe}
SAMPLES=${2:-2000000}
SEEDS=${3:-0}
SYNTH_FLOW=${SYNTH_FLOW:-exact}
DS="${DS:-.venv/bin/deepslam}"
export MUJOCO_GL=${MUJOCO_GL:-egl} PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
SCENE=${SCENE:-street}
case "$SCENE" in
  street) RENDER="--scene street --frames 300 --width 414"; PFX=""; INPUT="" ;;
  room) RENDER="--scene room --frames 300 --width 640 --height 480 --focal-px 537 --rate 30 --stereo-baseline 0"
        PFX=room_; INPUT="--height 96 --width 128"
        # the RGB-D rows are the recipe on exact flow with the rooms' own motions (bench.results_repro_rgbd),
        # their speed freed with SPEED_SCALE (the rooms' drone flies at 1-2 m/s, a hand-held camera walks);
        # KITTI's body motion does not belong to a hand-held camera
        if [ "${SYNTH_FLOW:-exact}" != exact ] || [ "${BODY:-0}" = 1 ]; then
          echo "SCENE=room trains the exact-flow recipe only: unset SYNTH_FLOW and BODY" >&2; exit 2
        fi ;;
  *) echo "SCENE must be street or room, not '$SCENE'" >&2; exit 2 ;;
esac
TRAJ_SFX=""  # the training renders' and fits' infix of TRAJECTORY=handheld or LEVER (PFX: the models' prefix)
case "${TRAJECTORY:-}" in
  "") ;;
  handheld) [ "$SCENE" = room ] || { echo "TRAJECTORY=handheld is for SCENE=room" >&2; exit 2; }
            RENDER="$RENDER --trajectory handheld"; PFX=room_handheld_; TRAJ_SFX=_handheld ;;
  *) echo "TRAJECTORY must be handheld or unset (the scene's own), not '$TRAJECTORY'" >&2; exit 2 ;;
esac
[ "$SCENE" = street ] && LEVER=${LEVER-0.84}  # KITTI's camera mount, unless set (LEVER=0: on the axle)
if [ -n "${LEVER:-}" ] && ! [[ "$LEVER" =~ ^0+(\.0*)?$ ]]; then  # 0, 0.0, ...: the axle camera
  [ "$SCENE" = street ] || { echo "LEVER is for SCENE=street (the car's camera)" >&2; exit 2; }
  [[ "$LEVER" =~ ^[0-9]+(\.[0-9]+)?$ ]] || { echo "LEVER must be metres ahead of the rear axle, e.g. 0.84, not '$LEVER'" >&2; exit 2; }
  RENDER="$RENDER --camera-ahead $LEVER"; PFX=lever_; TRAJ_SFX=_lever
fi
if [ "${DEPTH:-0}" = 1 ] && [ "$SCENE" != room ]; then
  # the rows that score depth-reading models are the RGB-D ones (bench.results_repro_rgbd), on exact flow
  echo "DEPTH=1 is for SCENE=room (the RGB-D rows)" >&2; exit 2
fi
RENDER_SFX=""
if [ "${PP_CROP:-0}" = 1 ]; then
  { [ "$SCENE" = street ] && [ "$SYNTH_FLOW" != exact ]; } || { echo "PP_CROP=1 is for SCENE=street with SYNTH_FLOW=dis" >&2; exit 2; }
  RENDER="${RENDER/--width 414/--width 428 --height 129 --focal-px 238.98138297872342}"; RENDER_SFX=_wide
fi
mkdir -p "$OUT"
RENDERS="$OUT/${SCENE}${TRAJ_SFX}${RENDER_SFX}_train"  # the training renders, without the seed
for s in 1 2; do
  [ -f "${RENDERS}_s$s/poses.txt" ] || $DS render $RENDER --seed $s --out "${RENDERS}_s$s" --quiet
done
TRAIN="${RENDERS}_s1 ${RENDERS}_s2"
PRIOR=""      # the motion fits' and synthetic models' name suffix
PRIOR_FIT=""  # ... and the fit-motion flags that make it
if [ -n "${SPEED_SCALE:-}" ]; then PRIOR=_speedscale; PRIOR_FIT="--speed-scale $SPEED_SCALE"; fi
if [ "$TRAJ_SFX" = _lever ] && [ -n "${SPEED_SCALE:-}" ]; then
  # the speed scale applied to the axle's motion, the lever's slide into a turn kept (it does not grow with speed)
  PRIOR=_axlescale; PRIOR_FIT="$PRIOR_FIT --speed-scale-lever $LEVER"
fi
if [ "${MIRROR:-1}" = 1 ]; then PRIOR="${PRIOR}_mirror"; PRIOR_FIT="$PRIOR_FIT --mirror"; fi
if [ "${BODY:-0}" = 1 ]; then
  KITTI_POSES=${KITTI_POSES:-../shared/data/kitti/poses}
  PRIOR="${PRIOR}_body"
  PRIOR_FIT="$PRIOR_FIT --body-from $(for n in 00 01 02 03 04 05 08 09 10; do printf '%s ' "$KITTI_POSES/$n.txt"; done)"
fi
SYNTH_ONLY=""; FRAMES_SFX=""  # flags and name suffix of the synthetic models only
[ "$SCENE" = street ] && MIRROR_FRAMES=${MIRROR_FRAMES-1}  # on for the towns, unless set (MIRROR_FRAMES=0: off)
if [ "${MIRROR_FRAMES:-0}" = 1 ]; then
  # every training frame also flipped left-right (`train --mirror-frames`): the towns' car keeps right, so without
  # it the network learns where the open road lies in the image and reads a street laid out otherwise long
  # (KITTI 07's drift 18.2 -> 4.9 %: docs/experiments/2026-12-07_lever_arm_training.md, sections 9 and 11)
  FRAMES_SFX=_mirrorframes; SYNTH_ONLY="--mirror-frames"
fi
if [ "${PP_CROP:-0}" = 1 ]; then FRAMES_SFX="${FRAMES_SFX}_ppcrop"; SYNTH_ONLY="$SYNTH_ONLY --crop-window 640,193 --coord-channels"; fi
DEPTH_SFX=""  # the models' name suffix of DEPTH=1
if [ "${DEPTH:-0}" = 1 ]; then DEPTH_SFX=_depth; INPUT="$INPUT --depth-channel"; fi
SCENE_SFX=""; [ "$SCENE" = room ] && SCENE_SFX=_room
FIT="motion$SCENE_SFX$TRAJ_SFX$PRIOR"  # the motion fits' name, without the stride
for k in 1 2; do
  [ -f "$OUT/${FIT}_s$k.json" ] || $DS fit-motion --poses ${RENDERS}_s1/poses.txt \
      ${RENDERS}_s2/poses.txt --stride $k --consecutive kde $PRIOR_FIT --out "$OUT/${FIT}_s$k.json"
done
MOTION="--motion $OUT/${FIT}_s1.json@1 --motion $OUT/${FIT}_s2.json@1"

RECIPE="--net ${NET:-cpu} --loss l1 --rot-weight 50 --batch 128 --lr-min 1e-4 --lr-max 1e-3 --half-cycle-steps 1000 \
  --patience 10 --lr-stop 1e-5 --max-epochs 100000 --max-samples $SAMPLES --holdout 0.1 --nll-epochs 20 --threads 2 --bf16 ${BF16:-auto} --quiet $INPUT ${EXTRA:-}"
PIDS=""
train() {
  local out=$1; shift
  [ -f "$out/model.safetensors" ] && return 0
  local cmd=($DS train $RECIPE "$@" --out "$out" $([ -f "$out/checkpoint.safetensors" ] && echo --resume))
  if [ "${PARALLEL:-0}" = 1 ]; then
    "${cmd[@]}" &
    PIDS="$PIDS $!"
  else
    "${cmd[@]}"
  fi
}
for seed in $SEEDS; do
  if [ "$SYNTH_FLOW" != exact ]; then
    # the synthetic model on the flow it is given at test: the second view rendered from each single frame,
    # read at 640 px as `deepslam vo` reads a 414 px frame (1.5459 = 640 / 414), DIS medium on the pair; DIS makes
    # ~50 samples/s on 2 cores, so a pool of POOL samples is made once and trained on in passes (an epoch), with
    # the recipe's patience matched in samples (10 x 20,000 = 2 passes of 100,000)
    [ "${SKIP_SYNTHETIC:-0}" = 1 ] || train "$OUT/${PFX}synthetic_${SYNTH_FLOW}${PRIOR}${FRAMES_SFX}${DEPTH_SFX}_cons_s$seed" --mode synthetic --seed $seed --source $TRAIN \
        $MOTION --synthetic-flow "$SYNTH_FLOW" $SYNTH_ONLY \
        --dis-preset medium --frame-scales 1.5459 --sample-pool "${POOL:-100000}" --patience "${POOL_PATIENCE:-2}" \
        --data-threads 2
    [ "${PP_CROP:-0}" = 1 ] && continue  # the supervised twin reads the renders' own frames: the recipe's without the crop
    # and supervised on the same renders' pairs with the same DIS flow (frames read at 640 px as `vo` reads them:
    # `train --read-width`), the comparison at equal flow
    train "$OUT/${PFX}supervised_${SYNTH_FLOW}${DEPTH_SFX}_cons_s$seed" --mode supervised --seed $seed \
        --sequence $TRAIN --flow "$SYNTH_FLOW" --dis-preset medium --strides 1,2
    continue
  fi
  [ "${SKIP_SYNTHETIC:-0}" = 1 ] || train "$OUT/${PFX}synthetic${PRIOR}${FRAMES_SFX}${DEPTH_SFX}_cons_s$seed" --mode synthetic \
      --seed $seed --source $TRAIN $MOTION --samples-per-epoch 20000 $SYNTH_ONLY
  train "$OUT/${PFX}supervised${DEPTH_SFX}_cons_s$seed" --mode supervised --seed $seed --sequence $TRAIN --flow gt --strides 1,2
  [ "$SCENE" = room ] && continue
  [ "${SAMEPATIENCE:-1}" = 1 ] || continue  # SAMEPATIENCE=0: more seeds without the hours-long third model
  # the recipe's patience is 10 epochs; a supervised epoch is ~1,100 pairs, a synthetic one 20,000 samples, so
  # the supervised run stops after ~120,000 samples: once more with the patience matched in samples (186 epochs)
  train "$OUT/${PFX}supervised_samepatience${DEPTH_SFX}_cons_s$seed" --mode supervised --seed $seed --sequence $TRAIN --flow gt \
      --strides 1,2 --patience 186
done
for pid in $PIDS; do wait "$pid"; done  # PARALLEL=1: every training started above, failing if one failed
echo "done: $OUT"
