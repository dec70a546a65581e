#!/usr/bin/env bash
# The tuned grid (README.md "The grid", addenda 1 and 2): the named tuned agent files of
# agents/, 7 regimes x the paper's 5 seeds x 5000 days, batched engine on the CPU, evaluation
# during training every 250 days; then one archive per agent in data/ and SHA256SUMS remade.
# Resumable (the database keeps finished batches; a stopped batch restarts from its checkpoint).
# Usage: bash reports/tuned/grid.sh mc_tuned ppo_tuned ddqn_tuned mc_tuned_set1
set -eu
cd "$(dirname "$0")/../.."
[ $# -ge 1 ] || { echo "grid.sh: name the agent files to run (e.g. mc_tuned ppo_tuned)" >&2; exit 2; }
export NUTRIBENCH_AGENTS=reports/tuned/agents
DB=reports/tuned/grid.db
algos=$(IFS=,; echo "$*")
mkdir -p reports/tuned/logs/grid
{ date -u +%FT%TZ; git rev-parse HEAD; git status --porcelain -- nutribench regimes reports/tuned/agents; } >> reports/tuned/logs/grid/code_version.txt
/usr/bin/time -f "%e s wall" nutribench run --algos "$algos" --regimes all --seeds 0,21,9,2003,1997 \
  --episodes 5000 --engine batched --device cpu --eval-every 250 --db "$DB" \
  >> "reports/tuned/logs/grid/run_$(echo "$*" | tr ' ' '_').log" 2>&1
for a in "$@"; do
  nutribench db export "reports/tuned/data/$a.npz" --db "$DB" --algos "$a"
done
(cd reports/tuned/data && sha256sum -- * | grep -v ' SHA256SUMS$' > SHA256SUMS)
