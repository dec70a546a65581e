#!/usr/bin/env bash
# ddqn_tgt4000 beside ddqn_eps002 (the queue's run_level commands, by hand)
set -u
OUT=/tmp/sens2; LOG=$OUT/log.txt; id=ddqn_tgt4000; clone=/tmp/sens2_$id; db=$OUT/$id.db
log() { echo "$(date -u +%FT%TZ) $*" | tee -a "$LOG"; }
left=$(( $(date -u -d 05:05 +%s) - $(date -u +%s) ))
rm -rf "$clone"; git clone -q /work/main "$clone" && git -C "$clone" checkout -q d06a6ac || { log "fail $id: clone"; exit 1; }
log "start $id (by hand, beside ddqn_eps002; algos $id, 5000 days, regimes shipped)"
(
  cd "$clone" || exit 1
  . /work/venv/bin/activate
  export NUTRIBENCH_AGENTS=reports/sensitivity/agents
  python -c "import nutribench, sys; sys.exit(0 if nutribench.__file__.startswith('$clone/') else 1)" || exit 3
  timeout "$left" nice -n 5 python -m nutribench.cli run --engine batched --device cpu --workers 1 \
    --regimes run0,run3,run6 --algos $id --seeds 0,1,2,3,4 --episodes 5000 --db "$db" >"$OUT/$id.out" 2>&1 || exit $?
  python -m nutribench.cli db export "$OUT/data/$id.npz" --db "$db" --algos $id >>"$OUT/$id.out" 2>&1
)
log "end $id rc=$?"
