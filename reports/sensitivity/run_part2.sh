#!/usr/bin/env bash
# The sensitivity study's part 2 queue (reports/sensitivity/README.md, "Plan, part 2").
#
#   bash reports/sensitivity/run_part2.sh <plan commit> [slots] [deadline, e.g. 01:40]
#
# Runs the ranked levels below, at most `slots` at once (default 2), each in its own clean
# clone /tmp/sens2_<id> of <plan commit> (so every job row records that commit, git_dirty = 0),
# into its own database /tmp/sens2/<id>.db, then exports it to /tmp/sens2/data/<id>.npz.
# A level starts only if its estimated wall time fits before the deadline (UTC, today or
# tomorrow); a level still running at the deadline is stopped (timeout) and is not run.
# Times go to /tmp/sens2/log.txt. QUEUE_FROM=<n> starts at the queue's entry n (0-based; default 0).
set -u
SHA=${1:?plan commit}
SLOTS=${2:-2}
DEADLINE=${3:-01:40}
VENV=${VENV:-/work/venv}
SRC=${SRC:-/work/main}
OUT=/tmp/sens2
mkdir -p "$OUT/data"
LOG=$OUT/log.txt
deadline_s=$(date -u -d "$DEADLINE" +%s)
[ "$deadline_s" -lt "$(date -u +%s)" ] && deadline_s=$((deadline_s + 86400))

# id | estimated minutes | algos | episodes | regimes folder ('' = shipped)
QUEUE=(
  "clock|35|ppo|5000|reports/sensitivity/regimes_clock"
  "len500|5|ppo|500|"
  "len1000|8|ppo|1000|"
  "len2000|15|ppo|2000|"
  "ddqn|30|ddqn|5000|"
  "ddqn_eps002|30|ddqn_eps002|5000|"
  "ddqn_tgt4000|30|ddqn_tgt4000|5000|"
  "sac|160|sac|5000|"
  "sac_a005|160|sac_a005|5000|"
)

log() { echo "$(date -u +%FT%TZ) $*" | tee -a "$LOG"; }

run_level() {
  local id=$1 est=$2 algos=$3 episodes=$4 regimes=$5
  local now left clone=/tmp/sens2_$id db=$OUT/$id.db
  now=$(date -u +%s)
  left=$((deadline_s - now))
  if [ $((est * 60)) -gt "$left" ]; then
    log "skip $id: estimated $est min, $((left / 60)) min left before $DEADLINE"
    return
  fi
  rm -rf "$clone"
  git clone -q "$SRC" "$clone" && git -C "$clone" checkout -q "$SHA" || { log "fail $id: clone"; return; }
  log "start $id (est $est min, algos $algos, $episodes days, regimes ${regimes:-shipped})"
  (
    cd "$clone" || exit 1
    # shellcheck disable=SC1091
    . "$VENV/bin/activate"
    export NUTRIBENCH_AGENTS=reports/sensitivity/agents
    [ -n "$regimes" ] && export NUTRIBENCH_REGIMES=$regimes
    python -c "import nutribench, sys; sys.exit(0 if nutribench.__file__.startswith('$clone/') else 1)" || exit 3
    timeout "$left" nice -n 5 python -m nutribench.cli run --engine batched --device cpu --workers 1 \
      --regimes run0,run3,run6 --algos "$algos" --seeds 0,1,2,3,4 --episodes "$episodes" --db "$db" \
      >"$OUT/$id.out" 2>&1 || exit $?
    python -m nutribench.cli db export "$OUT/data/$id.npz" --db "$db" --algos "$algos" >>"$OUT/$id.out" 2>&1
  )
  local rc=$?
  log "end $id rc=$rc"
}

next_level() {  # pops the next queue entry (a lock dir makes it atomic between slots)
  until mkdir "$OUT/.lock" 2>/dev/null; do sleep 1; done
  local i
  i=$(cat "$OUT/.next" 2>/dev/null || echo 0)
  echo $((i + 1)) >"$OUT/.next"
  rmdir "$OUT/.lock"
  [ "$i" -lt "${#QUEUE[@]}" ] && echo "${QUEUE[$i]}"
}

slot() {
  local entry
  while entry=$(next_level) && [ -n "$entry" ]; do
    IFS='|' read -r id est algos episodes regimes <<<"$entry"
    run_level "$id" "$est" "$algos" "$episodes" "$regimes"
  done
}

echo "${QUEUE_FROM:-0}" >"$OUT/.next"
rmdir "$OUT/.lock" 2>/dev/null
log "queue of $SHA from entry ${QUEUE_FROM:-0}, $SLOTS slots, deadline $DEADLINE UTC"
for _ in $(seq "$SLOTS"); do
  slot &
  sleep 2
done
wait
log "queue done"
