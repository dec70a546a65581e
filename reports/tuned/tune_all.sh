#!/usr/bin/env bash
# The plan's tuning studies (README.md "Tuning"), one algorithm after another, two drivers on
# each study (the 2 cores); resumable: run it again and each study goes on where it stopped.
# Usage: bash reports/tuned/tune_all.sh mc ppo ddqn gru_ppo sac
set -u
cd "$(dirname "$0")/../.."
for algo in "$@"; do
  for driver in 1 2; do
    /usr/bin/time -f "%e s wall" nutribench tune --algo "$algo" --study "tuned_$algo" \
      --regimes run0,run1,run2,run4 --seeds 101,102 --days 500 --eval-every 50 --val-episodes 5 \
      --trials 24 --sampler-seed 0 --pruner median --db reports/tuned/data/tuning.db \
      >> "reports/tuned/logs/tune_${algo}_driver${driver}.log" 2>&1 &
    sleep 5  # the first driver creates the study
  done
  wait
done
