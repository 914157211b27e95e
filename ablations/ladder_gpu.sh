#!/usr/bin/env bash
# The long rung of the budget ladder (conf/experiment/long.yaml) for the three models side by side on one GPU:
# one process each (a step is a few thousand small kernels, so three share the card), each rendering its batches
# on WORKERS CPU cores (train.prefetch_workers).
#   ablations/ladder_gpu.sh ROOT [SEED [OVERRIDE...]]   # runs in ROOT/{explicit,implicit,baseline}_sSEED
# A finished run (eval.json) is skipped; an interrupted one resumes. Then: python -m disent.report --roots ROOT
set -euo pipefail
ROOT=${1:?usage: ablations/ladder_gpu.sh ROOT [SEED [OVERRIDE...]]}
SEED=${2:-0}
shift $(($# < 2 ? $# : 2))
pids=()
for model in explicit implicit baseline; do
  dir="$ROOT/${model}_s$SEED"
  [ -f "$dir/eval.json" ] && continue
  mkdir -p "$dir"
  ${PYTHON:-python} -m disent model="$model" +experiment=long seed="$SEED" device="${DEVICE:-cuda}" train.progress=false \
    train.prefetch=8 train.prefetch_workers="${WORKERS:-4}" "$@" hydra.run.dir="$dir" >>"$dir/train.log" 2>&1 &
  pids+=($!)
done
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=1; done
exit $status
