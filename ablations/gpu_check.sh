#!/usr/bin/env bash
# The checks a GPU session runs, as one call: the CUDA tests, the model and SynthFaces benchmarks on the card, and a
# slice of the long-rung suite (SETTINGS x 3 seeds, each setting's seeds trained as one stacked model, then side by
# side, batches rendered on the card) with the whole suite's projected time.  At most 8 files land in OUT (a device
# call brings back no more).
#   ablations/gpu_check.sh OUT [STEPS]      # STEPS: training steps of each slice run (default 1000)
# Where hydra-core is not installed (a bare GPU image), carry its wheels in .wheels/ (ignored by git), made here with
#   pip download --no-deps -d .wheels hydra-core==1.3.8 omegaconf==2.3.1 antlr4-python3-runtime==4.9.3 emcee==3.1.6
# SETTINGS (default "explicit"), JOBS (processes side by side, default 1), DEVICE (cuda), DATA_DEVICE (the DEVICE),
# BENCH=0 (no benchmarks), AMP=1 (the slice again with train.amp=true), EXTRA (overrides for the slice runs) and PYTHON
# change it.  The benchmark file, with the
# slice's figures as its "suite" section, is OUT/bench-DEVICE.json: copy it to reports/ (the benchmarks page reads it).
set -uo pipefail
OUT=${1:?usage: ablations/gpu_check.sh OUT [STEPS]}
STEPS=${2:-1000}
PY=${PYTHON:-python3}
DEVICE=${DEVICE:-cuda}
BENCH_JSON=/tmp/disent-bench/bench.json
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
if [ -d .wheels ]; then
  $PY -m pip install -q --no-index --no-deps --no-build-isolation --target /tmp/disent-site .wheels/* \
    && export PYTHONPATH=$PYTHONPATH:/tmp/disent-site
fi
{ $PY -c "import torch; print('torch', torch.__version__, torch.cuda.is_available())"; nvidia-smi; } >"$OUT/env.txt" 2>&1
$PY -m pytest -q -p no:cacheprovider tests/test_render.py tests/test_data.py -k "cuda or device" >"$OUT/cuda_tests.txt" 2>&1
if [ "${BENCH:-1}" = 1 ]; then
  bench="--models explicit --device $DEVICE"
  # shellcheck disable=SC2086  # words
  { $PY -m disent.bench peak models data stack $bench --out "$BENCH_JSON"
    $PY -m disent.bench models $bench --compile --no-bf16 --out /tmp/disent-bench-compiled/bench-compiled.json
  } >"$OUT/bench.txt" 2>&1
  cp /tmp/disent-bench-compiled/bench-compiled.json "$OUT/bench-$DEVICE-compiled.json" 2>/dev/null
fi
slice() {  # slice NAME "OVERRIDES" [SUITE_OPTION...]: SETTINGS x 3 seeds trained together, timed, into OUT/NAME.json
  local name=$1 overrides=$2 root=/tmp/disent-$1 start end
  shift 2
  rm -rf "$root"
  start=$(date +%s.%N)
  # shellcheck disable=SC2086  # EXTRA and the overrides: words
  MODELS=${SETTINGS:-explicit} ABLATIONS="" SEEDS="0 1 2" TOGETHER=1 JOBS=${JOBS:-1} DEVICE=$DEVICE \
    DATA_DEVICE=${DATA_DEVICE:-$DEVICE} REPORT=0 PYTHON=$PY \
    bash ablations/suite_gpu.sh "$root" train.max_steps="$STEPS" ${EXTRA:-} $overrides >>"$OUT/slice.txt" 2>&1
  end=$(date +%s.%N)
  cat "$root"/*.log >>"$OUT/slice.txt" 2>/dev/null
  $PY -m disent.bench.suite "$root" "$start" "$end" "$@" >"$OUT/$name.json"
}
STACK=1 slice slice "" --into "$BENCH_JSON"  # the seeds as one stacked model (train.stack): the suite's figures
cp "$BENCH_JSON" "$OUT/bench-$DEVICE.json" 2>/dev/null
STACK=0 slice slice_threads ""  # the same seeds side by side, one thread and CUDA stream each
[ "${AMP:-0}" = 1 ] && STACK=1 slice slice_amp train.amp=true  # stacked in bfloat16: its accuracy beside fp32's
cat "$OUT"/slice*.json
