#!/usr/bin/env bash
# The paper's claims over the seeds of trained runs: the protocols that read run folders, then the report.
#   ablations/claims.sh ROOT...         # folders holding finished runs (e.g. the seeds of the budget ladder)
# Writes outputs/claims/<date>_<time>/{eval,edit} (claim 2: SH variance of every plain run, the published rows of
# other runs kept; claim 5 and the relighting: the editing measurements of every plain explicit and implicit run,
# tables and JSON only), then regenerates reports/README.md from ROOT... and publishes both folders.  EDIT=0 skips
# the editing measurements.
set -euo pipefail
[ $# -gt 0 ] || { echo "usage: ablations/claims.sh ROOT..." >&2; exit 2; }
OUT=outputs/claims/$(date +%Y-%m-%d_%H-%M-%S)
KEEP=reports/eval/sh_variance.json  # the published rows of runs not under ROOT... stay (their folders may be gone)
python -m disent.eval.protocols --every-run --roots "$@" --out "$OUT/eval" $([ -f "$KEEP" ] && echo --keep "$KEEP")
if [ "${EDIT:-1}" != 0 ]; then
  python - "$@" <<'PY' | while read -r run; do python -m disent.edit measure "$run" --threads 1 --no-figures --out "$OUT/edit"; done
import sys
from disent.runs import find_runs
for r in find_runs(sys.argv[1:]):
    if r.status == "ok" and r.checkpoint and r.plain and r.model in ("explicit", "implicit"):
        print(r.path)
PY
fi
python -m disent.report --roots "$@" --publish "$OUT/eval" $([ "${EDIT:-1}" != 0 ] && echo "$OUT/edit")
