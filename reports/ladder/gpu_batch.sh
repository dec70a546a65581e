#!/usr/bin/env bash
# Addendum 1: one batch of the plan (an agent at a level) on a lent GPU, in one call of the
# device tool: the plan's RUN with --device cuda, its own database, then its archive. What comes
# back in OUT (the device tool's limit: 8 files of 16 MiB): the archive obs<level>_<agent>.npz,
# run.log and machine.txt (date, GPU, packages, code); the database stays on the machine.
# Usage, on the GPU machine, from the repository root (the plan's order: the next batch not run):
#   OUT=<results folder> WHL=.whl DEADLINE=540 bash reports/ladder/gpu_batch.sh ppo 4
# Measured (speed_gpu.md, an H200): a PPO batch trains 5000 days in about 7.5 minutes there;
# GRU-PPO's take about twice as long, more than one call: run those on the CPU. The tuned PPO
# makes twice the gradient steps (n_epochs 20): time it first (measure_speed.py --device cuda).
# A batch stopped at DEADLINE (SIGINT) is not a result (addendum 1): say so, keep its log.
set -uo pipefail
: "${OUT:?OUT: a results folder}"
[ $# -eq 2 ] || { echo "gpu_batch.sh: give the agent and the level, e.g. ppo 4" >&2; exit 2; }
agent=$1 level=$2 DEADLINE="${DEADLINE:-540}" W=/tmp/ladder
case "$level" in 1) folder=regimes ;; 2|3|4) folder=reports/ladder/regimes_obs$level ;;
  *) echo "gpu_batch.sh: level $level is not 1-4" >&2; exit 2 ;; esac
if [ -n "${WHL:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$WHL"/*.whl || exit 1
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
export NUTRIBENCH_AGENTS=reports/ladder/agents NUTRIBENCH_REGIMES=$folder
name=obs${level}_$agent
mkdir -p "$W"
{ date -u +%FT%TZ; echo "batch $name, device cuda (addendum 1)"; nproc
  nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>&1
  python3 -c "import torch, numpy, stable_baselines3 as sb3; print('torch', torch.__version__, 'numpy', numpy.__version__, 'sb3', sb3.__version__)"
  echo "code: ${CODE:-unknown (set CODE to the commit whose tree was sent)}"; } > "$W/machine.txt" 2>&1
start=$SECONDS
timeout -s INT -k 20 "$DEADLINE" python3 -m nutribench.cli run --engine batched --device cuda \
  --regimes run0,run3,run6 --seeds 3800,3801,3802,3803,3804,3805,3806,3807,3808,3809 --episodes 5000 \
  --eval-episodes 10 --eval-every 100 --workers 1 --algos "$agent" --db "$W/$name.db" > "$W/run.log" 2>&1
rc=$?
echo "run rc $rc after $((SECONDS - start)) s" >> "$W/machine.txt"
if [ "$rc" -eq 0 ]; then
  python3 -m nutribench.cli db export "$W/$name.npz" --db "$W/$name.db" --algos "$agent" >> "$W/run.log" 2>&1
  rc=$?
  echo "export rc $rc" >> "$W/machine.txt"
fi
cp "$W/$name.npz" "$W/run.log" "$W/machine.txt" "$OUT/" 2>/dev/null
cat "$W/machine.txt"; tail -4 "$W/run.log"
exit "$rc"
