#!/usr/bin/env bash
# Protocol v2's studies (README.md, "Protocol v2"), one driver per agent, each from a frozen
# checkout of COMMIT (a git worktree under /work/frozen), so that work on main does not change a
# running study. Resumable: the same command with the same COMMIT goes on where a study stopped.
# Usage: bash reports/tuned_v2/tune_v2.sh COMMIT AGENT [AGENT ...]   (agents run side by side)
#   e.g. PYTHON=/work/venv/bin/python bash reports/tuned_v2/tune_v2.sh 1a2b3c4 ppo gru_ppo
#   (PYTHON: the interpreter of the project's environment; default: python on PATH)
#   DRIVERS="1 2": the drivers to start per agent, by number (default "1"; driver k > 1 logs to
#   logs/tune_<agent>.driver<k>.log); SAC's study runs two drivers from addendum 3 on
# Stop with SIGINT (kill -INT) before a session ends; commit data/tuning.db (an sqlite3 .backup
# copy) and the logs.
set -u
main="$(cd "$(dirname "$0")/../.." && pwd)"
commit="$(git -C "$main" rev-parse --verify "${1:?usage: tune_v2.sh COMMIT AGENT...}^{commit}")" || exit 2
shift
frozen="/work/frozen/$commit"
[ -d "$frozen" ] || git -C "$main" worktree add --detach "$frozen" "$commit" >/dev/null || exit 2
out="$main/reports/tuned_v2"
mkdir -p "$out/data" "$out/logs"
for agent in "$@"; do
 for driver in ${DRIVERS:-1}; do
  log="$out/logs/tune_$agent.log"
  [ "$driver" = 1 ] || log="$out/logs/tune_$agent.driver$driver.log"
  stack=4
  [ "$agent" = ddqn ] && stack=1  # DDQN's batched engine takes no per-agent settings
  [ "$agent" = sac ] && stack=1  # addendum 2: the replay minibatch drawn for every trial, as DDQN's
  {
    echo "$(date -u +%FT%TZ) start $agent (driver $driver): commit $commit, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores"
  } >> "$out/logs/code_version.txt"
  ( cd "$frozen" && PYTHONPATH="$frozen" /usr/bin/time -f "%e s wall" "${PYTHON:-python}" -m nutribench.cli tune \
      --algo "${agent}_v2" --study "v2_$agent" --regimes run0,run2,run4,run5 --seeds 101,102 \
      --days 1000 --eval-every 100 --val-episodes 5 --trials 24 --startup-trials 8 \
      --sampler-seed 0 --pruner none --objective late-mean --stack "$stack" \
      --db "$out/data/tuning.db" >> "$log" 2>&1 ) &
  sleep 5  # one study at a time creates its tables
 done
done
wait
