#!/usr/bin/env bash
# Part 2 of the plan (README.md, "Order and cost"): the <agent>_tuned_v2 files of agents/, 7
# regimes x the paper's 5 seeds x 5000 days, batched engine on the CPU, evaluation during
# training every 250 days (as v1's grid), from the frozen checkout of COMMIT (the studies'
# code); then one archive per agent in data/ and SHA256SUMS remade. Resumable: the database
# keeps finished batches. Usage: bash reports/tuned_v2/grid.sh COMMIT AGENT [AGENT ...]
#   (WORKERS=n: batches at once, default the cores; BATCH=n: at most n jobs a batch, default 35)  e.g. PYTHON=/work/venv/bin/python WORKERS=1 bash reports/tuned_v2/grid.sh 58584e9 ppo_tuned_v2 mc_tuned_v2
set -eu
main="$(cd "$(dirname "$0")/../.." && pwd)"
commit="$(git -C "$main" rev-parse --verify "${1:?usage: grid.sh COMMIT AGENT...}^{commit}")"
shift
[ $# -ge 1 ] || { echo "grid.sh: name the agent files to run (e.g. ppo_tuned_v2)" >&2; exit 2; }
frozen="/work/frozen/$commit"
[ -d "$frozen" ] || git -C "$main" worktree add --detach "$frozen" "$commit" >/dev/null
out="$main/reports/tuned_v2"
py="${PYTHON:-python}"
export NUTRIBENCH_AGENTS="$out/agents"
DB="$out/grid.db"
algos=$(IFS=,; echo "$*")
mkdir -p "$out/logs/grid" "$out/data"
echo "$(date -u +%FT%TZ) start $algos: commit $commit, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores${BATCH:+, batches of at most $BATCH}" >> "$out/logs/grid/code_version.txt"
cd "$frozen"
PYTHONPATH="$frozen" /usr/bin/time -f "%e s wall" "$py" -m nutribench.cli run --algos "$algos" --regimes all \
  --seeds 0,21,9,2003,1997 --episodes 5000 --engine batched --device cpu --eval-every 250 --db "$DB" ${WORKERS:+--workers "$WORKERS"} ${BATCH:+--batch-size "$BATCH"} \
  >> "$out/logs/grid/run_$(echo "$*" | tr ' ' '_').log" 2>&1
for a in "$@"; do
  PYTHONPATH="$frozen" "$py" -m nutribench.cli db export "$out/data/$a.npz" --db "$DB" --algos "$a"
done
(cd "$out/data" && sha256sum -- * | grep -v ' SHA256SUMS$' > SHA256SUMS)
