#!/usr/bin/env bash
# The long-rung suite on one GPU in one command: the three models and the explicit model without each of the
# paper's eight toggles, SEEDS seeds each (3 x 11 = 33 runs at +experiment=long), several runs side by side on the
# card (a 64x64 step is a few thousand small kernels: one run leaves it mostly idle), then the report.
#   ablations/suite_gpu.sh ROOT [OVERRIDE...]   # runs in ROOT/<setting>_s<seed>, then python -m disent.report --roots ROOT
# A finished run (eval.json) is skipped and an interrupted one resumes in its folder, so the same command picks up
# where a lost session stopped.  JOBS (processes side by side, default 6), TOGETHER=1 (each process trains one
# setting's seeds together: train.together=true, one CUDA stream each; with STACK=1 as one stacked model), SEEDS
# ("0 1 2"), MODELS, ABLATIONS, DEVICE (cuda), DATA_DEVICE (where batches are rendered: cpu, or cuda), WORKERS (CPU
# cores rendering each run's batches on the CPU, 2), EXPERIMENT (long), REPORT=0 (no report) and PYTHON change it;
# OVERRIDE... go to every run.
set -euo pipefail
ROOT=${1:?usage: ablations/suite_gpu.sh ROOT [OVERRIDE...]}
shift
ABLATIONS=${ABLATIONS-no_bws no_smooth_a no_smooth_s no_smooth no_matting no_adv no_pseudo_normal no_pseudo_light}
settings=()  # "name|overrides"
for model in ${MODELS-explicit implicit baseline}; do settings+=("$model|model=$model"); done
for ablation in $ABLATIONS; do settings+=("explicit_$ablation|model=explicit +ablation=$ablation"); done
common() {  # the overrides every run gets
  echo "+experiment=${EXPERIMENT:-long} device=${DEVICE:-cuda} data.device=${DATA_DEVICE:-cpu} train.progress=false" \
    "train.prefetch=8 train.prefetch_workers=${WORKERS:-2}"
}
run() {  # one setting's unfinished seeds: one process per run, or one for them all (TOGETHER=1)
  local name=${1%%|*} overrides=${1#*|} seeds=() seed
  for seed in ${SEEDS:-0 1 2}; do [ -f "$ROOT/${name}_s$seed/eval.json" ] || seeds+=("$seed"); done
  [ ${#seeds[@]} -gt 0 ] || return 0
  mkdir -p "$ROOT"
  if [ "${TOGETHER:-0}" = 1 ]; then
    local list stack=false
    list=$(IFS=,; echo "${seeds[*]}")
    [ "${STACK:-0}" = 1 ] && stack=true
    # shellcheck disable=SC2046,SC2086  # the overrides are words
    ${PYTHON:-python} -m disent -m $overrides seed="$list" train.together=true train.stack=$stack $(common) "${@:2}" \
      hydra.sweep.dir="$ROOT" hydra.sweep.subdir="${name}_s\${seed}" >>"$ROOT/$name.log" 2>&1
  else
    for seed in "${seeds[@]}"; do
      mkdir -p "$ROOT/${name}_s$seed"
      # shellcheck disable=SC2046,SC2086
      ${PYTHON:-python} -m disent $overrides seed="$seed" $(common) "${@:2}" hydra.run.dir="$ROOT/${name}_s$seed" \
        >>"$ROOT/${name}_s$seed/train.log" 2>&1 || return 1
    done
  fi
}
jobs=()  # one job per setting (TOGETHER=1) or per run
for setting in "${settings[@]}"; do
  if [ "${TOGETHER:-0}" = 1 ]; then jobs+=("$setting"); else
    for seed in ${SEEDS:-0 1 2}; do jobs+=("$setting|$seed"); done
  fi
done
status=0
running=0
for job in "${jobs[@]}"; do
  if [ "${TOGETHER:-0}" = 1 ]; then run "$job" "$@" & else
    SEEDS=${job##*|} run "${job%|*}" "$@" &
  fi
  running=$((running + 1))
  if [ "$running" -ge "${JOBS:-6}" ]; then wait -n || status=1; running=$((running - 1)); fi
done
while [ "$running" -gt 0 ]; do wait -n || status=1; running=$((running - 1)); done
[ "${REPORT:-1}" = 0 ] || ${PYTHON:-python} -m disent.report --roots "$ROOT"
exit $status
