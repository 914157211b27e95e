#!/usr/bin/env bash
# The long-rung suite on one GPU in one command: the three models and the explicit model without each of the
# paper's eight toggles, SEEDS seeds each (3 x 11 = 33 runs at +experiment=long), JOBS runs side by side on the card
# (a 64x64 step is a few thousand small kernels: one run leaves it mostly idle), then the report.
#   ablations/suite_gpu.sh ROOT [OVERRIDE...]   # runs in ROOT/<setting>_s<seed>, then python -m disent.report --roots ROOT
# A finished run (eval.json) is skipped and an interrupted one resumes in its folder, so the same command picks up
# where a lost session stopped.  JOBS (default 6), SEEDS ("0 1 2"), MODELS, ABLATIONS, DEVICE (cuda), WORKERS (CPU
# cores rendering each run's batches, 2), EXPERIMENT (long), REPORT=0 (no report) and PYTHON change it; OVERRIDE...
# go to every run.
set -euo pipefail
ROOT=${1:?usage: ablations/suite_gpu.sh ROOT [OVERRIDE...]}
shift
ABLATIONS=${ABLATIONS-no_bws no_smooth_a no_smooth_s no_smooth no_matting no_adv no_pseudo_normal no_pseudo_light}
jobs=()  # "folder|overrides"
for seed in ${SEEDS:-0 1 2}; do
  for model in ${MODELS-explicit implicit baseline}; do jobs+=("$ROOT/${model}_s$seed|model=$model seed=$seed"); done
  for ablation in $ABLATIONS; do jobs+=("$ROOT/explicit_${ablation}_s$seed|model=explicit +ablation=$ablation seed=$seed"); done
done
run() {  # one run in its folder, skipped where it finished
  local dir=${1%%|*} overrides=${1#*|}
  [ -f "$dir/eval.json" ] && return 0
  mkdir -p "$dir"
  # shellcheck disable=SC2086  # the overrides are words
  ${PYTHON:-python} -m disent $overrides +experiment="${EXPERIMENT:-long}" device="${DEVICE:-cuda}" \
    train.progress=false train.prefetch=8 train.prefetch_workers="${WORKERS:-2}" "${@:2}" hydra.run.dir="$dir" \
    >>"$dir/train.log" 2>&1
}
status=0
running=0
for job in "${jobs[@]}"; do
  run "$job" "$@" &
  running=$((running + 1))
  if [ "$running" -ge "${JOBS:-6}" ]; then wait -n || status=1; running=$((running - 1)); fi
done
while [ "$running" -gt 0 ]; do wait -n || status=1; running=$((running - 1)); done
[ "${REPORT:-1}" = 0 ] || ${PYTHON:-python} -m disent.report --roots "$ROOT"
exit $status
