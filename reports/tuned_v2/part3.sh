#!/usr/bin/env bash
# Part 3 of the plan (README.md, "Memory or settings?"): each named agent file on run5 and run6
# x the fresh seeds 3900-3909 x 5000 days, batched engine on the CPU, evaluation during training
# every 250 days (as the grid), from the frozen checkout of COMMIT (the studies' code), one arm
# after another in the order given; then one archive per arm, data/part3_<agent>.npz. An agent
# file in agents/ (the v2 files, arm C's copy without memory) is taken from there, any other
# name (arm D: the paper's gru_ppo) from the frozen checkout's regimes/agents/. Resumable: the
# database keeps finished batches, a batch's checkpoint its days so far.
# Usage: bash reports/tuned_v2/part3.sh COMMIT AGENT [AGENT ...]
#   e.g. PYTHON=/work/venv/bin/python bash reports/tuned_v2/part3.sh 58584e9 gru_ppo_tuned_v2 gru_ppo_tuned_v2_nomem
set -eu
main="$(cd "$(dirname "$0")/../.." && pwd)"
commit="$(git -C "$main" rev-parse --verify "${1:?usage: part3.sh COMMIT AGENT...}^{commit}")"
shift
[ $# -ge 1 ] || { echo "part3.sh: name the agent files to run (e.g. gru_ppo_tuned_v2)" >&2; exit 2; }
frozen="/work/frozen/$commit"
[ -d "$frozen" ] || git -C "$main" worktree add --detach "$frozen" "$commit" >/dev/null
out="$main/reports/tuned_v2"
py="${PYTHON:-python}"
DB="$out/part3.db"
mkdir -p "$out/logs/part3" "$out/data"
cd "$frozen"
for a in "$@"; do
  if [ -f "$out/agents/$a.toml" ]; then agents="$out/agents"; else agents="$frozen/regimes/agents"; fi
  echo "$(date -u +%FT%TZ) start $a ($agents): commit $commit, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores" >> "$out/logs/part3/code_version.txt"
  NUTRIBENCH_AGENTS="$agents" PYTHONPATH="$frozen" /usr/bin/time -f "%e s wall" "$py" -m nutribench.cli run --algos "$a" \
    --regimes run5,run6 --seeds 3900,3901,3902,3903,3904,3905,3906,3907,3908,3909 --episodes 5000 \
    --engine batched --device cpu --eval-every 250 --db "$DB" --workers 1 >> "$out/logs/part3/run_$a.log" 2>&1
  NUTRIBENCH_AGENTS="$agents" PYTHONPATH="$frozen" "$py" -m nutribench.cli db export "$out/data/part3_$a.npz" --db "$DB" --algos "$a"
  echo "$(date -u +%FT%TZ) done $a" >> "$out/logs/part3/code_version.txt"
done
