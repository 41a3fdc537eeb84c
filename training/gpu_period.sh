#!/usr/bin/env bash
# One call of a GPU period (the device tool's `run`, at most 10 minutes each); docs/training.md has the plan.
#   bash training/gpu_period.sh bench [MINUTES]     # benches/train_throughput.py -> $OUT/train_throughput.json
#   bash training/gpu_period.sh compare [MINUTES]   # batch 256 against the paper's batch 32 on equal windows
#                                                   # (gpu12_long_cmp_*.json, each at most MINUTES and its share
#                                                   # of CALL_MINUTES) -> $OUT/cmp_*.log
#   bash training/gpu_period.sh ROLE MINUTES        # a whole schedule of gpu12_ROLE.json (short|long|repair)
#                                                   # in MINUTES of training -> $OUT/export/ROLE.safetensors
#   bash training/gpu_period.sh eval MINUTES [DIR]  # training.protocol on model directory DIR (default
#                                                   # gpu_carry/candidate), resumed from gpu_carry/protocol/NAME
#                                                   # -> $OUT/protocol/NAME/ (NAME: DIR's base name)
# Reads the carried folder gpu_carry/ (ignored by git), which `python3 -m training.gpu_carry` prepares:
# h36m_model_cache.npz (training data), h36m/ (S5, the evaluation protocol), init/ROLE.safetensors (the
# best full-size weights so far, to warm-start), candidate/ and protocol/ (for eval).
set -euo pipefail
T0=$(date +%s)   # the call's start: compare shares the call's minutes from here
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/gpu_out}
CARRY=${GPU_CARRY:-gpu_carry}
# Dry runs here (tests/test_gpu_period.py): GPU_DEVICE=cpu, GPU_CONFIG (another training config for
# short|long|repair), BENCH_ARGS and PROTOCOL_ARGS (options added to the benchmark and to training.protocol).
DEVICE=${GPU_DEVICE:-cuda}
CALL_MINUTES=${CALL_MINUTES:-9.5}   # wall clock a call may take (the device tool stops it at 10)
# Run directories. A warm device machine keeps ignored folders between calls: a second call of the same
# ROLE there resumes RUNS/gpu12_ROLE (the multi-call schedule); name another GPU_RUNS to start afresh.
RUNS=${GPU_RUNS:-runs}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.used,memory.total,clocks.sm --format=csv,noheader || true
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
case "${1:-}" in
  bench)
    # shellcheck disable=SC2086  # BENCH_ARGS is a list of options
    python3 benches/train_throughput.py --max-minutes "${2:-6}" --json "$OUT/train_throughput.json" ${BENCH_ARGS:-} \
      2>&1 | tee "$OUT/bench.log"
    ;;
  compare)
    # Each run compiles cold in its own process, which --max-minutes does not count: each also stops at its
    # share of what is left of the call (CALL_MINUTES), less 45 s for its last validation and exit, so that
    # the second run's log is not cut off at the device's 10 minutes. GPU_CMP_CONFIGS: other configs.
    # shellcheck disable=SC2206  # GPU_CMP_CONFIGS is a list of paths
    configs=(${GPU_CMP_CONFIGS:-training/configs/gpu12_long_cmp_b256.json training/configs/gpu12_long_cmp_b32.json})
    end=$(( T0 + $(python3 -c "print(int(60 * $CALL_MINUTES))") ))
    left=${#configs[@]}
    for config in "${configs[@]}"; do
      name=$(basename "$config" .json); name=${name#gpu12_long_}
      now=$(date +%s); stop=$(( now + (end - now) / left - 45 )); left=$(( left - 1 ))
      echo "$name: training stops by $(( stop - now )) s from now (or after ${2:-3.5} min of training)"
      python3 -m training.train --config "$config" --out "$RUNS/$name" --data "$CARRY/h36m_model_cache.npz" \
        --device "$DEVICE" --max-minutes "${2:-3.5}" --stop-at "$stop" 2>&1 | tee "$OUT/$name.log"
    done
    ;;
  short|long|repair)
    role=$1; minutes=${2:?minutes of training}
    init=()
    if [ -f "$CARRY/init/$role.safetensors" ]; then init=(--init-from "$CARRY/init/$role.safetensors"); fi
    python3 -m training.gpu_session --config "${GPU_CONFIG:-training/configs/gpu12_$role.json}" --run "$RUNS/gpu12_$role" \
      --data "$CARRY/h36m_model_cache.npz" --budget-minutes "$minutes" --minutes "$minutes" "${init[@]}" \
      --call-minutes "$CALL_MINUTES" --device "$DEVICE" --copy-to "$OUT/$role" --export "$OUT/export" \
      2>&1 | tee "$OUT/$role.log"
    ;;
  eval)
    minutes=${2:?minutes}; model=${3:-$CARRY/candidate}
    name=$(basename "$model"); results="$OUT/protocol/$name"
    mkdir -p "$results"
    if [ -d "$CARRY/protocol/$name" ]; then cp -r "$CARRY/protocol/$name"/. "$results"/; fi
    # shellcheck disable=SC2086
    python3 -m training.protocol --model "$model" --out "$results" --data "$CARRY/h36m" --device "$DEVICE" \
      --max-minutes "$minutes" ${PROTOCOL_ARGS:-} 2>&1 | tee "$OUT/eval_$name.log"
    ;;
  *)
    echo "usage: bash training/gpu_period.sh bench [MINUTES] | compare [MINUTES] | short|long|repair MINUTES" \
         "| eval MINUTES [DIR]" >&2; exit 2 ;;
esac
