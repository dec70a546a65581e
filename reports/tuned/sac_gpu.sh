#!/usr/bin/env bash
# Addendum 3: the second SAC study (tuned2_sac) on a lent GPU, two drivers stacking 6 trials
# each (12 trials in flight, two rounds), with the code of the second set's commit.
# Usage, on the GPU machine, from the repository root, with OUT set to a folder for the results:
#   CODE=<checkout of the set-2 commit> DB=<copy of reports/tuned/data/tuning.db> bash reports/tuned/sac_gpu.sh
# The optional WHL folder holds the wheels of the dependencies the machine lacks (it has no network).
# As run on 2026-11-26 (addendum 3): CODE=.devrun/code (`git archive bce897c nutribench regimes
# migrations pyproject.toml alembic.ini`, plus engine/stacked.py's fix of 0f5ea0b), DB=.devrun/tuning.db
# (an sqlite backup of the study database), WHL=.whl (pip download of gymnasium, stable-baselines3,
# pydantic, sqlalchemy, alembic, optuna, typer and their missing needs, for cp312 manylinux), both
# folders git-ignored and carried to the machine, DEADLINE=450, after a smoke study on a scratch copy
# (STUDY=smoke DAYS=4 EVERY=2 TRIALS=4 STACK=2). The trial records come back in $OUT/tuning.db.
# A deadline (DEADLINE s, default 500) stops the drivers with SIGINT: a trial running then is
# recorded as failed (not counted) and the study is finished later with tune_all.sh (SET=2).
set -uo pipefail
export PYTHONUNBUFFERED=1
: "${CODE:?CODE: a checkout of the set-2 commit}" "${DB:?DB: the study database}" "${OUT:?OUT: a results folder}"
STUDY="${STUDY:-tuned2_sac}" DAYS="${DAYS:-500}" EVERY="${EVERY:-50}" TRIALS="${TRIALS:-24}"
DEVICE="${DEVICE:-cuda}" STACK="${STACK:-6}" DRIVERS="${DRIVERS:-2}" DEADLINE="${DEADLINE:-500}"
if [ -n "${WHL:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$WHL"/*.whl || exit 1
  export PYTHONPATH=/tmp/site
fi
DB=$(realpath "$DB"); OUT=$(realpath "$OUT")
cd "$CODE" && export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
start=$SECONDS
{ date -u +%FT%TZ; nproc; nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>&1
  python3 -c "import torch, numpy, optuna, stable_baselines3 as sb3; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__, 'optuna', optuna.__version__, 'sb3', sb3.__version__)"
  echo "code: $(cat COMMIT 2>/dev/null || echo unknown)"
  echo "drivers $DRIVERS x stack $STACK, device $DEVICE, deadline $DEADLINE s"; } > "$OUT/machine.txt" 2>&1
for d in $(seq 1 "$DRIVERS"); do
  timeout -s INT -k 30 "$DEADLINE" python3 -m nutribench.cli tune --algo sac --study "$STUDY" \
    --regimes run0,run1,run2,run4 --seeds 101,102 --days "$DAYS" --eval-every "$EVERY" --val-episodes 5 \
    --trials "$TRIALS" --sampler-seed 1 --pruner median --stack "$STACK" --device "$DEVICE" --db "$DB" \
    > "$OUT/driver$d.log" 2>&1 &
  sleep 5  # the first driver opens the study
done
wait
echo "drivers ended after $((SECONDS - start)) s" >> "$OUT/machine.txt"
python3 - "$DB" "$OUT/tuning.db" <<'PY'
import sqlite3, sys
src, dst = sqlite3.connect(sys.argv[1]), sqlite3.connect(sys.argv[2])
src.backup(dst)
PY
python3 -m nutribench.cli tune status --db "$OUT/tuning.db" > "$OUT/status.txt" 2>&1
