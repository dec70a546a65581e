#!/usr/bin/env bash
# The engines comparison of this folder's plan, run on a 16-core machine with one NVIDIA H100
# (the SB3 engine's 10 jobs on 10 cores; the batched engine's PPO and DDQN batches on the GPU,
# beside them), then the batched engine's CUDA tests and its training rate on the GPU.
# Usage: OUT=<folder for the results> bash reports/engines_run3/device.sh
# The machine had no network: the dependencies came as wheels in .whl/ (not committed).
set -uo pipefail
export PYTHONUNBUFFERED=1
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD PATH=/tmp/site/bin:$PATH
fi
nb() { python3 -m nutribench.cli "$@"; }
start=$SECONDS
{ nproc; nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
  python3 -c "import torch, numpy, pandas; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__, 'pandas', pandas.__version__)"
  git log -1 --format='commit %H' 2>/dev/null; } 2>&1 | tee "$OUT/machine.txt"
# (1) the comparison, in the background
python3 benchmarks/engines.py --algos ppo,ddqn --regimes run3 --seeds 0,1,2,3,4 --episodes 5000 --eval-episodes 10 \
  --device cuda --concurrent --workers 10 --save "$OUT/engines_run3.json" --markdown > "$OUT/engines_run3.md" 2>&1 &
pid=$!
# (2) meanwhile the CUDA tests of the batched engine (they never ran on a GPU before)
timeout 240 python3 -m pytest -q -p no:cacheprovider tests/test_engine_device.py 2>&1 | tail -n 15 > "$OUT/device_tests.txt"
wait $pid; echo "engines: exit $? after $((SECONDS - start)) s" | tee -a "$OUT/engines_run3.md"
# (3) with what time is left, the batched engine's rate at K = 35 on the GPU (the paper grid's GPU time)
left=$((540 - (SECONDS - start)))
if [ "$left" -gt 45 ]; then
  timeout "$left" python3 -m nutribench.cli bench train --engine batched --device cuda --algos all --episodes 20 --repeats 3 \
    > "$OUT/bench_train_cuda.txt" 2>&1
  echo "bench train: exit $? after $((SECONDS - start)) s" >> "$OUT/bench_train_cuda.txt"
fi
