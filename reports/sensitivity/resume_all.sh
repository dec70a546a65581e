#!/usr/bin/env bash
# 26 Nov session: clock resumed from its checkpoint, then DDQN's three levels (plan part 2 addendum)
set -u
LOG=/tmp/sens2/log.txt
log() { echo "$(date -u +%FT%TZ) $*" | tee -a "$LOG"; }
deadline_s=$(date -u -d "05:05" +%s)
left=$((deadline_s - $(date -u +%s)))
log "resume clock in /tmp/sens2_clock (d06a6ac), deadline 05:05"
(
  cd /tmp/sens2_clock || exit 1
  . /work/venv/bin/activate
  export NUTRIBENCH_AGENTS=reports/sensitivity/agents NUTRIBENCH_REGIMES=reports/sensitivity/regimes_clock
  python -c "import nutribench, sys; sys.exit(0 if nutribench.__file__.startswith('/tmp/sens2_clock/') else 1)" || exit 3
  timeout "$left" nice -n 5 python -m nutribench.cli run --engine batched --device cpu --workers 1 \
    --regimes run0,run3,run6 --algos ppo --seeds 0,1,2,3,4 --episodes 5000 --db /tmp/sens2/clock.db \
    >/tmp/sens2/clock_resume2.out 2>&1 || exit $?
  python -m nutribench.cli db export /tmp/sens2/data/clock.npz --db /tmp/sens2/clock.db --algos ppo >>/tmp/sens2/clock_resume2.out 2>&1
)
log "end clock rc=$?"
QUEUE_FROM=4 bash /work/main/reports/sensitivity/run_part2.sh d06a6ac 1 05:05
