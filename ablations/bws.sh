#!/usr/bin/env bash
# BWS against batch size, the stability section's "Without BWS" table and eval/bws.png: the explicit model for the
# same number of steps at every batch size (BWS averages over the batch: a batch of 1 whitens each face's shading on
# its own), in three arms: with BWS (the defaults); without it as the paper means it (+ablation=no_bws: the BWS term
# off and E_recon-L's raw L-hat target); and with only the BWS term off (loss.lhat_white=true keeps L-hat's target
# whitened, which keeps the shading white on its own). One job at a time, 1 thread each.
#   ablations/bws.sh [ROOT] [overrides...]      # ROOT defaults to multirun; SEEDS=0,1,2 STEPS=400 BATCHES=1,5,25
# Then (the published study, 128 test images; --n is half the images):
#   python -m disent.eval.stability bws --n 64 --bws-roots ROOT/bws ROOT/bws_off ROOT/bws_off_raw
set -euo pipefail
ROOT=${1:-multirun}; shift || true
SEEDS=${SEEDS:-0,1,2}; STEPS=${STEPS:-400}; BATCHES=${BATCHES:-1,5,25}
B=(model=explicit seed=$SEEDS train.batch_size=$BATCHES train.max_steps=$STEPS train.threads=1
   train.time_limit_min=null train.progress=false)
python -m disent -m "${B[@]}" hydra.sweep.dir="$ROOT/bws" "$@"
python -m disent -m "${B[@]}" +ablation=no_bws hydra.sweep.dir="$ROOT/bws_off_raw" "$@"
python -m disent -m "${B[@]}" +ablation=no_bws loss.lhat_white=true hydra.sweep.dir="$ROOT/bws_off" "$@"
