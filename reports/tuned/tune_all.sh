#!/usr/bin/env bash
# The plan's tuning studies (README.md "Tuning"), one algorithm after another, two drivers on
# each study (the 2 cores); resumable: run it again and each study goes on where it stopped.
# Usage: bash reports/tuned/tune_all.sh mc ppo ddqn gru_ppo sac
#   SET=1 (default): the plan's first studies, tuned_<algo>, sampler seed 0, logs in logs/
#   SET=2: addendum 1's second studies, tuned2_<algo>, sampler seed 1, logs in logs/set2/
set -u
cd "$(dirname "$0")/../.."
SET="${SET:-1}"
case "$SET" in
  1) prefix=tuned_;  seed=0; logs=reports/tuned/logs ;;
  2) prefix=tuned2_; seed=1; logs=reports/tuned/logs/set2 ;;
  *) echo "tune_all.sh: SET must be 1 or 2, not '$SET'" >&2; exit 2 ;;
esac
mkdir -p "$logs"
{ date -u +%FT%TZ; git rev-parse HEAD; git status --porcelain -- nutribench regimes; } >> "$logs/code_version.txt"
for algo in "$@"; do
  for driver in 1 2; do
    /usr/bin/time -f "%e s wall" nutribench tune --algo "$algo" --study "${prefix}$algo" \
      --regimes run0,run1,run2,run4 --seeds 101,102 --days 500 --eval-every 50 --val-episodes 5 \
      --trials 24 --sampler-seed "$seed" --pruner median --db reports/tuned/data/tuning.db \
      >> "$logs/tune_${algo}_driver${driver}.log" 2>&1 &
    sleep 5  # the first driver creates the study
  done
  wait
done
