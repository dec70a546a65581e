#!/usr/bin/env bash
# The third addendum's run (reports/sensitivity/README.md): the `ddqn` level's command, unchanged,
# in a clean clone of <commit> (which records the training diagnostics), into /tmp/sens2/ddqn_diag.db,
# exported to /tmp/sens2/data/ddqn_diag.npz; stopped at the deadline (UTC) if still running.
#   bash reports/sensitivity/ddqn_diag.sh <commit> <deadline, e.g. 08:15>
set -u
SHA=${1:?commit}; DEADLINE=${2:?deadline}
OUT=/tmp/sens2; LOG=$OUT/log.txt; id=ddqn_diag; clone=/tmp/sens2_$id; db=$OUT/$id.db
mkdir -p "$OUT/data"
log() { echo "$(date -u +%FT%TZ) $*" | tee -a "$LOG"; }
left=$(( $(date -u -d "$DEADLINE" +%s) - $(date -u +%s) ))
rm -rf "$clone" "$db"; git clone -q /work/main "$clone" && git -C "$clone" checkout -q "$SHA" || { log "fail $id: clone"; exit 1; }
log "start $id (algos ddqn, 5000 days, regimes shipped, commit $SHA, deadline $DEADLINE)"
(
  cd "$clone" || exit 1
  . /work/venv/bin/activate
  export NUTRIBENCH_AGENTS=reports/sensitivity/agents
  python -c "import nutribench, sys; sys.exit(0 if nutribench.__file__.startswith('$clone/') else 1)" || exit 3
  timeout "$left" python -m nutribench.cli run --engine batched --device cpu --workers 1 \
    --regimes run0,run3,run6 --algos ddqn --seeds 0,1,2,3,4 --episodes 5000 --db "$db" >"$OUT/$id.out" 2>&1 || exit $?
  python -m nutribench.cli db export "$OUT/data/$id.npz" --db "$db" --algos ddqn >>"$OUT/$id.out" 2>&1
)
log "end $id rc=$?"
