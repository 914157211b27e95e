#!/usr/bin/env bash
# The training recipe's leave-one-out A/B: the explicit model for 600 steps (cosine lr over them) with the
# recipe of conf/ (recipe/recipe), then once with each of its departures from the paper changed back.
# Two runs at a time on one thread each; a finished run (eval.json) is skipped, an interrupted one resumes.
#   ablations/recipe.sh [ROOT]          # default ROOT: multirun/recipe; then: python -m disent.report --roots ROOT
# Extra settings for every run: RECIPE_EXTRA="device=cuda" ablations/recipe.sh
set -euo pipefail
ROOT=${1:-multirun/recipe}
COMMON=(model=explicit train.max_steps=600 train.time_limit_min=null train.progress=false ${RECIPE_EXTRA:-})
VARIANTS=(
  "recipe"
  "norm_none model.norm=none"                    # no normalisation layers (the paper, the release)
  "norm_group model.norm=group"                  # GroupNorm instead of BatchNorm
  "centre_off model.centre_input=false"          # encoder input in [0,1]
  "normal_unit model.normal=unit"                # three free normal channels, normalised
  "z_relu model.z_act=relu"                      # ReLU on Z_I
  "z_sigmoid model.z_act=sigmoid"                # the release's sigmoid on Z_I
  "rmsprop train.optimizer=rmsprop"              # the release's optimiser
  "epoch_decay train.schedule=epoch_decay"       # the release's schedule (x0.99 per epoch)
  "train3000 data.train_size=3000 train.epochs=5" # the former default training set (5 epochs: the same 600 steps)
  "recN_0.2 loss.weights.recon_N=0.2"            # the release's E_recon-N weight
  "recN_10 loss.weights.recon_N=10"
)
for v in "${VARIANTS[@]}"; do
  read -r name overrides <<<"$v"
  [ -f "$ROOT/$name/eval.json" ] && continue
  while [ "$(jobs -rp | wc -l)" -ge 2 ]; do sleep 5; done
  mkdir -p "$ROOT"
  OMP_NUM_THREADS=1 python -m disent hydra.run.dir="$ROOT/$name" "${COMMON[@]}" $overrides > "$ROOT/$name.log" 2>&1 &
done
wait
