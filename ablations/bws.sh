#!/usr/bin/env bash
# BWS against batch size, the stability section's "Without BWS" table and eval/bws.png: the explicit model at
# batch sizes 1, 5, 25 (BWS averages over the batch: a batch of 1 whitens each face's shading on its own), in three
# arms: with BWS (the defaults, bws); without it as the paper means it (+ablation=no_bws: the BWS term off and
# E_recon-L's raw L-hat target, bws_off_raw); and with only the BWS term off (loss.lhat_white=true keeps L-hat's
# target whitened, which keeps the shading white on its own, bws_off). One job at a time, 1 thread each.
#   ablations/bws.sh [ROOT] [overrides...]   # ROOT defaults to multirun; SEEDS=0,1,2 BATCHES=1,5,25 ARMS=bws,bws_off_raw,bws_off
# Every batch size trains STEPS=400 steps, so a small batch also sees fewer images. IMAGES=N instead trains every
# batch size on N images (N / batch steps, validation and checkpoints 8 times a run), into ROOT/ARM/imagesN-bB:
#   IMAGES=10000 BATCHES=1 ablations/bws.sh ROOT     # batch 1 on the images batch 25 sees in 400 steps
# Then (the published study, 128 test images; --n is half the images):
#   python -m disent.eval.stability bws --n 64 --bws-roots ROOT/bws ROOT/bws_off ROOT/bws_off_raw
set -euo pipefail
ROOT=${1:-multirun}; shift || true
SEEDS=${SEEDS:-0,1,2}; STEPS=${STEPS:-400}; BATCHES=${BATCHES:-1,5,25}; ARMS=${ARMS:-bws,bws_off_raw,bws_off}
IMAGES=${IMAGES:-}
declare -A ARM=([bws]="" [bws_off_raw]="+ablation=no_bws" [bws_off]="+ablation=no_bws loss.lhat_white=true")
# a job's folder names its batch size and seed, so that a later sweep of more seeds adds folders beside the first's
# shellcheck disable=SC2016  # ${...} is Hydra's interpolation, not the shell's
B=(model=explicit seed=$SEEDS train.threads=1 train.time_limit_min=null train.progress=false
   'hydra.sweep.subdir=b${train.batch_size}-s${seed}')

sweep() {  # sweep SUBDIR OVERRIDES...: every arm of ARMS
    local sub=$1; shift
    for arm in ${ARMS//,/ }; do
        # shellcheck disable=SC2086  # an arm's overrides are words
        python -m disent -m "${B[@]}" ${ARM[$arm]} hydra.sweep.dir="$ROOT/$arm$sub" "$@"
    done
}

if [[ -z $IMAGES ]]; then
    sweep "" train.batch_size="$BATCHES" train.max_steps="$STEPS" "$@"
else
    for bs in ${BATCHES//,/ }; do
        steps=$((IMAGES / bs)); every=$(((steps + 7) / 8))
        sweep "/images$IMAGES-b$bs" train.batch_size="$bs" train.max_steps=$steps train.val_every=$every \
            train.checkpoint_every=$every "$@"
    done
fi
