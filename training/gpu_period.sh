#!/usr/bin/env bash
# One call of a GPU period (the device tool's `run`, at most 10 minutes each); docs/training.md has the plan.
#   bash training/gpu_period.sh bench [MINUTES]     # benches/train_throughput.py -> $OUT/train_throughput.json
#   bash training/gpu_period.sh compare [MINUTES]   # batch 256 against the paper's batch 32 on equal windows
#                                                   # (gpu12_long_cmp_*.json, each at most MINUTES) -> $OUT/cmp_*.log
#   bash training/gpu_period.sh ROLE MINUTES        # a whole schedule of gpu12_ROLE.json (short|long|repair)
#                                                   # in MINUTES of training -> $OUT/export/ROLE.safetensors
#   bash training/gpu_period.sh eval MINUTES [DIR]  # training.protocol on model directory DIR (default
#                                                   # gpu_carry/candidate), resumed from gpu_carry/protocol/NAME
#                                                   # -> $OUT/protocol/NAME/ (NAME: DIR's base name)
# Reads the carried folder gpu_carry/ (ignored by git), which `python3 -m training.gpu_carry` prepares:
# h36m_model_cache.npz (training data), h36m/ (S5, the evaluation protocol), init/ROLE.safetensors (the
# best full-size weights so far, to warm-start), candidate/ and protocol/ (for eval).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/gpu_out}
CARRY=${GPU_CARRY:-gpu_carry}
# Dry runs here (tests/test_gpu_period.py): GPU_DEVICE=cpu, GPU_CONFIG (another training config for
# short|long|repair), BENCH_ARGS and PROTOCOL_ARGS (options added to the benchmark and to training.protocol).
DEVICE=${GPU_DEVICE:-cuda}
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
    for b in b256 b32; do
      python3 -m training.train --config "training/configs/gpu12_long_cmp_$b.json" --out "$RUNS/cmp_$b" \
        --data "$CARRY/h36m_model_cache.npz" --device "$DEVICE" --max-minutes "${2:-3.5}" 2>&1 | tee "$OUT/cmp_$b.log"
    done
    ;;
  short|long|repair)
    role=$1; minutes=${2:?minutes of training}
    init=()
    if [ -f "$CARRY/init/$role.safetensors" ]; then init=(--init-from "$CARRY/init/$role.safetensors"); fi
    python3 -m training.gpu_session --config "${GPU_CONFIG:-training/configs/gpu12_$role.json}" --run "$RUNS/gpu12_$role" \
      --data "$CARRY/h36m_model_cache.npz" --budget-minutes "$minutes" --minutes "$minutes" "${init[@]}" \
      --call-minutes "${CALL_MINUTES:-9.5}" --device "$DEVICE" --copy-to "$OUT/$role" --export "$OUT/export" \
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
