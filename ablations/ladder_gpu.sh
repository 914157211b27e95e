#!/usr/bin/env bash
# The long rung of the budget ladder (conf/experiment/long.yaml) for the three models side by side on one GPU:
# one process each (a step is a few thousand small kernels, so three share the card), each rendering its batches
# on WORKERS CPU cores (train.prefetch_workers).
#   ablations/ladder_gpu.sh ROOT [SEED [OVERRIDE...]]   # runs in ROOT/{explicit,implicit,baseline}_sSEED
# MODELS and SEEDS pick other jobs to run side by side, e.g. an ablation's three seeds:
#   MODELS=explicit SEEDS="0 1 2" ablations/ladder_gpu.sh ROOT/no_smooth 0 +ablation=no_smooth
# A finished run (eval.json) is skipped; an interrupted one resumes. Then: python -m disent.report --roots ROOT
set -euo pipefail
ROOT=${1:?usage: ablations/ladder_gpu.sh ROOT [SEED [OVERRIDE...]]}
SEED=${2:-0}
shift $(($# < 2 ? $# : 2))
pids=()
for seed in ${SEEDS:-$SEED}; do
  for model in ${MODELS:-explicit implicit baseline}; do
    dir="$ROOT/${model}_s$seed"
    [ -f "$dir/eval.json" ] && continue
    mkdir -p "$dir"
    ${PYTHON:-python} -m disent model="$model" +experiment=long seed="$seed" device="${DEVICE:-cuda}" train.progress=false \
      train.prefetch=8 train.prefetch_workers="${WORKERS:-4}" "$@" hydra.run.dir="$dir" >>"$dir/train.log" 2>&1 &
    pids+=($!)
  done
done
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=1; done
exit $status
