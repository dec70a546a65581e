#!/usr/bin/env bash
# What a lent GPU would change for this study's batches (and the tuned grid's SAC batch): the
# plan's batches of 30 jobs (run0/run3/run6 x seeds 3800-3809) timed for DAYS training days on
# CUDA, one after another, and on the same machine's CPU (one thread each, as the plan's
# `--workers 1` batches run, side by side on its spare cores), beside the CUDA tests of
# tests/test_engine_device.py (skipped where there is no GPU). Not a run of the plan.
# Usage, on the GPU machine, from the repository root, OUT set to a results folder:
#   DAYS=20 bash reports/ladder/gpu_speed.sh
# The optional WHL folder holds wheels of the dependencies the machine lacks (it has no network).
set -uo pipefail
: "${OUT:?OUT: a results folder}"
DAYS="${DAYS:-20}" DEADLINE="${DEADLINE:-300}"
RUNS="${RUNS:-ppo:1,ppo:4,gru_ppo:1,gru_ppo:4,reports/tuned/agents/sac_tuned.toml:1}"
if [ -n "${WHL:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$WHL"/*.whl || exit 1
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
{ date -u +%FT%TZ; nproc; nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>&1
  python3 -c "import torch, numpy, stable_baselines3 as sb3; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__, 'sb3', sb3.__version__)"
  git rev-parse HEAD 2>/dev/null || cat COMMIT 2>/dev/null; } > "$OUT/machine.txt" 2>&1
timeout "$DEADLINE" python3 -m pytest -q -p no:cacheprovider tests/test_engine_device.py > "$OUT/pytest_device.txt" 2>&1 &
i=0
for run in ${RUNS//,/ }; do
  i=$((i + 1))
  timeout "$DEADLINE" python3 reports/ladder/measure_speed.py --days "$DAYS" --runs "$run" --device cpu \
    --out "$OUT/cpu_$i.md" > /dev/null 2> "$OUT/cpu_$i.err" &
done
timeout "$DEADLINE" python3 reports/ladder/measure_speed.py --days "$DAYS" --runs "$RUNS" --device cuda \
  --out "$OUT/cuda.md" > /dev/null 2> "$OUT/cuda.err"
wait
{ cat "$OUT/cuda.md"; for f in "$OUT"/cpu_*.md; do tail -n +3 "$f"; done; } > "$OUT/speed_gpu.md"
tail -3 "$OUT/pytest_device.txt"
cat "$OUT/speed_gpu.md"
