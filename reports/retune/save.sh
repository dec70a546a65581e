#!/usr/bin/env bash
# A consistent copy of the studies' database (tuning.db, ignored by git, written by the drivers)
# into data/tuning.db for the commit (sqlite3's online backup: the drivers may keep running).
# Usage: PYTHON=/work/venv/bin/python bash reports/retune/save.sh
set -eu
here="$(cd "$(dirname "$0")" && pwd)"
[ -e "$here/tuning.db" ] || { echo "save.sh: no $here/tuning.db yet: nothing to save" >&2; exit 1; }
mkdir -p "$here/data"
"${PYTHON:-python}" - "$here/tuning.db" "$here/data/tuning.db" <<'PY'
import sqlite3, sys
src, dst = sqlite3.connect(sys.argv[1]), sqlite3.connect(sys.argv[2])
with dst:
    src.backup(dst)
PY
# the folder's sums, as every reports/*/data folder has them (tests/test_archive_replay.py)
( cd "$here/data" && sha256sum $(ls | grep -vx SHA256SUMS) > SHA256SUMS )
