#!/usr/bin/env bash
# The re-tuning study's held-out runs (README.md, "Held-out runs"): the agent files named, x run1,
# run3, run6 x seeds 5000-5009 x 5000 days, batched engine on the CPU, evaluation during training
# every 250 days (as the v2 grid), from the frozen checkout of COMMIT; then one archive per file
# in data/ and SHA256SUMS remade. Resumable: the database keeps finished batches.
# Usage: PYTHON=/work/venv/bin/python bash reports/retune/grid.sh COMMIT FILE [FILE ...]
#   e.g. ... grid.sh COMMIT ppo_tuned_v2 ppo_tuned_v2b ppo_tuned_v2c   (WORKERS=n, BATCH=n as
#   reports/tuned_v2/grid.sh)
set -eu
main="$(cd "$(dirname "$0")/../.." && pwd)"
commit="$(git -C "$main" rev-parse --verify "${1:?usage: grid.sh COMMIT FILE...}^{commit}")"
shift
[ $# -ge 1 ] || { echo "grid.sh: name the agent files to run (e.g. ppo_tuned_v2b)" >&2; exit 2; }
frozen="/work/frozen/$commit"
[ -d "$frozen" ] || git -C "$main" worktree add --detach "$frozen" "$commit" >/dev/null
out="$main/reports/retune"
py="${PYTHON:-python}"
export NUTRIBENCH_AGENTS="$out/agents:$main/reports/tuned_v2/agents"
DB="$out/grid.db"
algos=$(IFS=,; echo "$*")
mkdir -p "$out/logs/grid" "$out/data"
echo "$(date -u +%FT%TZ) start $algos: commit $commit, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores${BATCH:+, batches of at most $BATCH}" >> "$out/logs/grid/code_version.txt"
cd "$frozen"
PYTHONPATH="$frozen" nice -n 10 /usr/bin/time -f "%e s wall" "$py" -m nutribench.cli run --algos "$algos" --regimes run1,run3,run6 \
  --seeds 5000,5001,5002,5003,5004,5005,5006,5007,5008,5009 --episodes 5000 --engine batched --device cpu --eval-every 250 \
  --db "$DB" ${WORKERS:+--workers "$WORKERS"} ${BATCH:+--batch-size "$BATCH"} \
  >> "$out/logs/grid/run_$(echo "$*" | tr ' ' '_').log" 2>&1
for a in "$@"; do
  PYTHONPATH="$frozen" "$py" -m nutribench.cli db export "$out/data/$a.npz" --db "$DB" --algos "$a"
done
(cd "$out/data" && sha256sum -- * | grep -v ' SHA256SUMS$' > SHA256SUMS)
