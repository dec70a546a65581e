#!/usr/bin/env bash
# The re-tuning study's tuning draws (README.md, "Factors and levels"), from a frozen checkout
# of COMMIT (a git worktree under /work/frozen), one driver a study, at nice 10. Resumable: the
# same command with the same COMMIT goes on where a study stopped.
# Usage: PYTHON=/work/venv/bin/python bash reports/retune/tune.sh COMMIT STUDY [STUDY ...]
#   STUDY is <agent>:<draw>, e.g. ppo:b gru_ppo:c; the studies given run one after another
# Stop with SIGINT (kill -INT) before a session ends, then `save.sh` and commit data/tuning.db.
set -u
main="$(cd "$(dirname "$0")/../.." && pwd)"
commit="$(git -C "$main" rev-parse --verify "${1:?usage: tune.sh COMMIT AGENT:DRAW...}^{commit}")" || exit 2
shift
frozen="/work/frozen/$commit"
[ -d "$frozen" ] || git -C "$main" worktree add --detach "$frozen" "$commit" >/dev/null || exit 2
out="$main/reports/retune"
mkdir -p "$out/logs"
for study in "$@"; do
  agent="${study%%:*}" draw="${study##*:}"
  case "$draw" in
    b) sampler=1 seeds=5101,5102 ;;
    c) sampler=2 seeds=5201,5202 ;;
    *) echo "tune.sh: draw '$draw' of '$study' is not b or c (README.md)" >&2; exit 2 ;;
  esac
  echo "$(date -u +%FT%TZ) start ${agent}_$draw: commit $commit, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores" >> "$out/logs/code_version.txt"
  ( cd "$frozen" && PYTHONPATH="$frozen" nice -n 10 /usr/bin/time -f "%e s wall" "${PYTHON:-python}" -m nutribench.cli tune \
      --space "${agent}_v2" --study "retune_${agent}_$draw" --regimes run0,run2,run4,run5 --seeds "$seeds" \
      --days 1000 --eval-every 100 --val-episodes 5 --trials 24 --startup-trials 8 \
      --sampler-seed "$sampler" --pruner none --objective late-mean --stack 4 \
      --db "$out/tuning.db" >> "$out/logs/tune_${agent}_$draw.log" 2>&1 ) || exit $?
done
