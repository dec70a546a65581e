#!/usr/bin/env bash
# Addendum 2: start several batches of the plan side by side on a lent GPU, in one call of the
# device tool, and bring back what resumes them on the CPU. Each batch: the plan's RUN with
# --device cuda, its own database, a checkpoint every $EVERY seconds (default 60), stopped by
# SIGINT at $DEADLINE seconds (default 420). What comes back in OUT: machine.txt (date, GPU,
# packages, the copy's commit, each batch's rc and seconds) and start.tgz.part-* (the
# databases, run logs and checkpoints under /tmp/ladder, split in 15 MiB pieces). The tool
# brings back 64 MiB at most: one GRU batch (30 networks and optimisers, about 58 MB compressed).
# Usage, on the GPU machine, from the repository root:
#   OUT=<results folder> WHL=.whl CODE=<commit sent> bash reports/ladder/gpu_start.sh gru_ppo:1 gru_ppo:4
# Then here: cat start.tgz.part-* | tar xz -C /tmp/ladder; rename_checkpoints.py; cpu_batch.sh.
set -uo pipefail
: "${OUT:?OUT: a results folder}"
[ $# -ge 1 ] || { echo "gpu_start.sh: give agent:level pairs, e.g. gru_ppo:1 gru_ppo:4" >&2; exit 2; }
DEADLINE="${DEADLINE:-420}" W=/tmp/ladder
if [ -n "${WHL:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$WHL"/*.whl || exit 1
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 NUTRIBENCH_AGENTS=reports/ladder/agents
export NUTRIBENCH_CHECKPOINT_SECONDS="${EVERY:-60}" OMP_NUM_THREADS="${THREADS:-4}"
mkdir -p "$W"
{ date -u +%FT%TZ; echo "batches $*, device cuda (addendum 2), side by side, deadline $DEADLINE s"; nproc
  nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>&1
  python3 -c "import torch, numpy, stable_baselines3 as sb3; print('torch', torch.__version__, 'numpy', numpy.__version__, 'sb3', sb3.__version__)"
  echo "code sent: ${CODE:-unknown (set CODE)}; the copy's git rev-parse HEAD: $(git rev-parse HEAD 2>&1)"; } > "$W/machine.txt" 2>&1
for job in "$@"; do
  a=${job%%:*} l=${job##*:} folder=regimes
  [ "$l" = 1 ] || folder=reports/ladder/regimes_obs$l
  ( start=$SECONDS
    NUTRIBENCH_REGIMES=$folder timeout -s INT -k 30 "$DEADLINE" python3 -m nutribench.cli run --engine batched --device cuda \
      --regimes run0,run3,run6 --seeds 3800,3801,3802,3803,3804,3805,3806,3807,3808,3809 --episodes 5000 \
      --eval-episodes 10 --eval-every 100 --workers 1 --algos "$a" --db "$W/obs${l}_$a.db" > "$W/obs${l}_${a}_gpu_run.log" 2>&1
    echo "obs${l}_$a run rc $? after $((SECONDS - start)) s" >> "$W/machine.txt" ) &
done
wait
ls -la "$W" "$W/models/checkpoints" >> "$W/machine.txt" 2>&1
(cd "$W" && tar czf - machine.txt ./*.db ./*_gpu_run.log models/checkpoints) | split -b 15m - "$OUT/start.tgz.part-"
cp "$W/machine.txt" "$OUT/"
cat "$W/machine.txt"; tail -n 3 "$W"/*_gpu_run.log
