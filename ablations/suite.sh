#!/usr/bin/env bash
# The ablation suite in one command: the three models and the explicit model with each ablation, 3 seeds.
#   ablations/suite.sh                       # +experiment=ablation_budget, 2 local jobs, into multirun/ablation*
#   ablations/suite.sh ablation_tiny         # the committed report's budget
#   LAUNCHER=slurm ablations/suite.sh default   # a SLURM cluster (hydra-submitit-launcher), full default budget
# Extra arguments go to both sweeps (e.g. device=cuda).  Then: python -m disent.eval.ablation
set -euo pipefail
EXP=${1:-ablation_budget}; shift || true
LAUNCHER=${LAUNCHER:-local}
SEEDS=${SEEDS:-0,1,2}
ABLATIONS=no_bws,no_smooth_a,no_smooth_s,no_smooth,no_matting,no_adv,no_pseudo_normal,no_pseudo_light
EXTRA=(hydra/launcher=$LAUNCHER)
[ "$EXP" != default ] && EXTRA+=(+experiment=$EXP)
python -m disent -m "${EXTRA[@]}" model=baseline,explicit,implicit seed=$SEEDS \
    hydra.sweep.dir=multirun/ablation "$@"
python -m disent -m "${EXTRA[@]}" model=explicit seed=$SEEDS +ablation=$ABLATIONS \
    hydra.sweep.dir=multirun/ablation_explicit "$@"
