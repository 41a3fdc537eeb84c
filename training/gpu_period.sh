#!/usr/bin/env bash
# One call of a GPU period (the device tool's `run`, at most 10 minutes each); docs/training.md has the plan.
#   bash training/gpu_period.sh bench [MINUTES]     # benches/train_throughput.py -> $OUT/train_throughput.json
#   bash training/gpu_period.sh compare [MINUTES]   # batch 256 against the paper's batch 32 on equal windows
#                                                   # (gpu12_long_cmp_*.json, each at most MINUTES) -> $OUT/cmp_*.log
#   bash training/gpu_period.sh ROLE MINUTES        # a whole schedule of gpu12_ROLE.json (short|long|repair)
#                                                   # in MINUTES of training -> $OUT/export/ROLE.safetensors
# Reads the carried folder gpu_carry/ (ignored by git): h36m_model_cache.npz (python3 -m training.train
# --write-cache gpu_carry/h36m_model_cache.npz) and, to warm-start, init/ROLE.safetensors (the best
# full-size weights so far).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/gpu_out}
CARRY=${GPU_CARRY:-gpu_carry}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.used,memory.total,clocks.sm --format=csv,noheader || true
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
case "${1:-}" in
  bench)
    python3 benches/train_throughput.py --max-minutes "${2:-6}" --json "$OUT/train_throughput.json" 2>&1 | tee "$OUT/bench.log"
    ;;
  compare)
    for b in b256 b32; do
      python3 -m training.train --config "training/configs/gpu12_long_cmp_$b.json" --out "runs/cmp_$b" \
        --data "$CARRY/h36m_model_cache.npz" --device cuda --max-minutes "${2:-4}" 2>&1 | tee "$OUT/cmp_$b.log"
    done
    ;;
  short|long|repair)
    role=$1; minutes=${2:?minutes of training}
    init=()
    if [ -f "$CARRY/init/$role.safetensors" ]; then init=(--init-from "$CARRY/init/$role.safetensors"); fi
    python3 -m training.gpu_session --config "training/configs/gpu12_$role.json" --run "runs/gpu12_$role" \
      --data "$CARRY/h36m_model_cache.npz" --budget-minutes "$minutes" --minutes "$minutes" "${init[@]}" \
      --copy-to "$OUT/$role" --export "$OUT/export" 2>&1 | tee "$OUT/$role.log"
    ;;
  *)
    echo "usage: bash training/gpu_period.sh bench [MINUTES] | compare [MINUTES] | short|long|repair MINUTES" >&2; exit 2 ;;
esac
