#!/usr/bin/env bash
# What is left of the plan for SAC, in order, each step resumable (run the same command again
# after a session's end): its study with two drivers (addendum 3) until 24 trials are complete;
# `tune best` by addendum 3's rule (the best of the first 24 complete trials by completion
# time) -> agents/sac_tuned_v2.toml, once; its grid (grid.sh, batches of 2 jobs, two at once on
# the two cores: addendum 5); analyse.py. Everything runs from the frozen checkout of COMMIT,
# as the other agents'.
# Usage: PYTHON=/work/venv/bin/python bash reports/tuned_v2/sac_rest.sh 58584e9
set -eu
here="$(cd "$(dirname "$0")" && pwd)"
main="$(cd "$here/../.." && pwd)"
commit="$(git -C "$main" rev-parse --verify "${1:?usage: sac_rest.sh COMMIT}^{commit}")"
py="${PYTHON:-python}"
db="$here/data/tuning.db"
frozen="/work/frozen/$commit"

complete() { sqlite3 "$db" "select count(*) from trials t join studies s using(study_id) where s.study_name='v2_sac' and t.state='COMPLETE'"; }

# 1. the study (tune_v2.sh resumes it; a RUNNING trial left by a killed driver is retried)
if [ "$(complete)" -lt 24 ]; then
  DRIVERS="1 2" PYTHON="$py" bash "$here/tune_v2.sh" "$commit" sac
fi
[ "$(complete)" -ge 24 ] || { echo "sac_rest.sh: the study holds $(complete) complete trials, not 24: run again" >&2; exit 1; }

# 2. the choice, once: among the first 24 complete trials by completion time (addendum 3); a
# later one is marked failed in a copy of the database only, for `tune best` to pass over it
agent="$here/agents/sac_tuned_v2.toml"
if [ ! -e "$agent" ]; then
  pick="$db"
  late=$("$py" "$here/trials.py" "$db" --late v2_sac)
  if [ -n "$late" ]; then
    pick="$(mktemp -d)/tuning_first24.db"
    sqlite3 "$db" ".backup '$pick'"
    sqlite3 "$pick" "update trials set state='FAIL' where number in ($(echo $late | tr ' ' ,))
      and study_id = (select study_id from studies where study_name = 'v2_sac')"
    echo "sac_rest.sh: trials $late completed after the 24th: not chosen (addendum 3)"
  fi
  ( cd "$frozen" && PYTHONPATH="$frozen" "$py" -m nutribench.cli tune best --study v2_sac --name sac_tuned_v2 \
      --write --out "$here/agents" --db "$pick" )
  echo "$(date -u +%FT%TZ) tune best v2_sac -> agents/sac_tuned_v2.toml: commit $commit" >> "$here/logs/code_version.txt"
fi

# 3. the grid (resumable: grid.db keeps finished batches, a batch its checkpoint), in batches of
# at most 2 jobs that each end within a session (addendum 5); a machine without grid.db first
# takes the jobs saved at earlier sessions' ends (`sac_save.sh` -> data/sac_tuned_v2.partial.npz)
partial="$here/data/sac_tuned_v2.partial.npz"
if [ ! -e "$here/grid.db" ] && [ -e "$partial" ]; then
  [ -d "$frozen" ] || git -C "$main" worktree add --detach "$frozen" "$commit" >/dev/null
  ( cd "$frozen" && PYTHONPATH="$frozen" "$py" -m nutribench.cli db import "$partial" --db "$here/grid.db" )
  echo "$(date -u +%FT%TZ) imported data/sac_tuned_v2.partial.npz into a new grid.db: commit $commit" >> "$here/logs/grid/code_version.txt"
fi
BATCH="${BATCH:-2}" WORKERS="${WORKERS:-2}" PYTHON="$py" bash "$here/grid.sh" "$commit" sac_tuned_v2
# 4. the whole archive replaces the partial one, then the comparisons
rm -f "$partial"
(cd "$here/data" && sha256sum -- * | grep -v ' SHA256SUMS$' > SHA256SUMS)
"$py" "$here/analyse.py"
