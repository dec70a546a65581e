#!/usr/bin/env bash
# Part 4 on a lent GPU machine: measure_cost.py's batches timed for DAYS days on CUDA, one after
# another, and on the same machine's CPU (one thread each, as the plan's --workers 1 batches run,
# side by side on its spare cores). Not a run of the plan. On the GPU machine, from the
# repository root, OUT set to a results folder (WHL: wheels of what the machine lacks):
#   OUT=<folder> WHL=.whl DAYS=20 bash reports/tuned_v2/gpu_cost.sh
set -uo pipefail
: "${OUT:?OUT: a results folder}"
W="$(mktemp -d)"  # the rows and logs; $OUT gets three files
DAYS="${DAYS:-20}" DEADLINE="${DEADLINE:-360}"
BATCHES="grid_gru part3_gru part3_ppo sac_trial_b32 sac_trial_b256 grid_sac"
if [ -n "${WHL:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$WHL"/*.whl || exit 1
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
{ date -u +%FT%TZ; nproc; nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>&1
  python3 -c "import torch, numpy, stable_baselines3 as sb3; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__, 'sb3', sb3.__version__)"
  git rev-parse HEAD 2>/dev/null; } > "$OUT/machine.txt" 2>&1
for b in $BATCHES; do
  timeout "$DEADLINE" python3 reports/tuned_v2/measure_cost.py --days "$DAYS" --batches "$b" --device cpu \
    --out "$W/cpu_$b.md" > /dev/null 2> "$W/cpu_$b.err" &
done
timeout "$DEADLINE" python3 reports/tuned_v2/measure_cost.py --days "$DAYS" --batches "${BATCHES// /,}" --device cuda \
  --out "$W/cuda.md" > /dev/null 2> "$W/cuda.err"
wait
{ cat "$W/cuda.md"; for b in $BATCHES; do tail -n +3 "$W/cpu_$b.md" 2>/dev/null; done; } > "$OUT/cost_gpu.md"
for f in "$W"/*.err; do [ -s "$f" ] && { echo "== $f"; tail -5 "$f"; }; done > "$OUT/errors.txt"
cat "$OUT/errors.txt"
cat "$OUT/machine.txt" "$OUT/cost_gpu.md"
