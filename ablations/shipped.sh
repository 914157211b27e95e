#!/usr/bin/env bash
# Everything the report measures on the shipped weights (disent/weights/), run again after new weights are shipped
# (python -m disent.models.shipped RUN NAME):
#   ablations/shipped.sh ROOT...    # ROOT...: the run folders the report reads (as for ablations/claims.sh)
# Writes outputs/shipped/<date>_<time>/{edit,photos,eval}: the editing measurements with their figures and the
# background diagnostic (claim 5's `shipped` rows, relighting), the photos' domain gap (needs dlib), the methods
# on one plane of the shipped models, and the out-of-distribution curves (of the longest-trained plain run of each
# model under ROOT..., lowest seed first); then regenerates reports/README.md from ROOT... with the three published.
set -euo pipefail
[ $# -gt 0 ] || { echo "usage: ablations/shipped.sh ROOT..." >&2; exit 2; }
OUT=outputs/shipped/$(date +%Y-%m-%d_%H-%M-%S)
for model in explicit implicit; do
  python -m disent.edit measure "$model" --threads 1 --out "$OUT/edit"
  python -m disent.edit measure "$model" --threads 1 --background --out "$OUT/edit"
done
python -m disent.eval.photos --run explicit implicit --workers 1 --out "$OUT/photos"
python -m disent.eval.methods --runs explicit implicit baseline --out "$OUT/eval"
python -m disent.eval.stability ood --roots "$@" --out "$OUT/eval"
python -m disent.report --roots "$@" --publish "$OUT/edit" "$OUT/photos" "$OUT/eval"
