#!/usr/bin/env bash
# Addendum 5: before a session ends, save SAC's done grid jobs (grid.db, while the grid runs) to
# data/sac_tuned_v2.partial.npz and remake SHA256SUMS, for the commit; a later machine without
# grid.db imports it (sac_rest.sh) and runs only the jobs not in it. Batches not yet ended are
# not in it (their checkpoints are, on this machine only).
# Usage: PYTHON=/work/venv/bin/python bash reports/tuned_v2/sac_save.sh 58584e9
set -eu
here="$(cd "$(dirname "$0")" && pwd)"
main="$(cd "$here/../.." && pwd)"
commit="$(git -C "$main" rev-parse --verify "${1:?usage: sac_save.sh COMMIT}^{commit}")"
frozen="/work/frozen/$commit"
py="${PYTHON:-python}"
[ -e "$here/grid.db" ] || { echo "sac_save.sh: no $here/grid.db: nothing to save" >&2; exit 1; }
done=$(sqlite3 -readonly "$here/grid.db" "select count(*) from jobs j join agent_configs a on a.id = j.agent_config_id
  where a.name = 'sac_tuned_v2' and j.status = 'done'")
[ "$done" -gt 0 ] || { echo "sac_save.sh: grid.db holds no done sac_tuned_v2 job yet: nothing to save" >&2; exit 1; }
# written in a temporary folder outside data/, then moved in: a failed export leaves no file
# there that SHA256SUMS lacks
tmp="$(mktemp -d)/sac_tuned_v2.partial.npz"
( cd "$frozen" && PYTHONPATH="$frozen" "$py" -m nutribench.cli db export "$tmp" --db "$here/grid.db" --algos sac_tuned_v2 )
mv "$tmp" "$here/data/sac_tuned_v2.partial.npz" && rmdir "$(dirname "$tmp")"
(cd "$here/data" && sha256sum -- * | grep -v ' SHA256SUMS$' > SHA256SUMS)
