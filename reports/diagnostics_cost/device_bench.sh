#!/usr/bin/env bash
# whole_runs.py (once `bench train --diagnostics-cost`) for the five algorithms at once on a 16-core machine (the lent GPU
# machine's CPU, nothing else running there), one process per algorithm pinned to its own core.
# Usage (on that machine, the dependencies as wheels in .whl/): OUT=<folder> bash reports/diagnostics_cost/device_bench.sh
# SPECS="algo days repeats,..." and LIMIT (seconds per process) change the runs (defaults below).
set -uo pipefail
export PYTHONUNBUFFERED=1 COLUMNS=200
if [ -d .whl ] && [ -z "${NO_WHEELS:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD PATH=/tmp/site/bin:$PATH
fi
{ date -u +%FT%TZ; nproc; lscpu | grep -i "model name"; uptime
  python3 -c "import torch, numpy, stable_baselines3 as s; print('torch', torch.__version__, 'numpy', numpy.__version__, 'sb3', s.__version__)"; } \
  > "$OUT/machine.txt" 2>&1
SPECS=${SPECS:-"mc 40 15,ppo 40 15,gru_ppo 40 9,ddqn 40 9,sac 20 9"}
LIMIT=${LIMIT:-380}
i=0
IFS=, read -r -a specs <<<"$SPECS"
for spec in "${specs[@]}"; do
  read -r algo days reps <<<"$spec"
  ( t0=$SECONDS
    taskset -c $((2 * i)) timeout "$LIMIT" python3 reports/diagnostics_cost/whole_runs.py --algos "$algo" --days "$days" \
      --repeats "$reps" > "$OUT/bench_$algo.txt" 2>&1
    echo "exit $? after $((SECONDS - t0)) s" >> "$OUT/bench_$algo.txt" ) &
  i=$((i + 1))
done
wait
uptime >> "$OUT/machine.txt"
