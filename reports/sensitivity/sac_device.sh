#!/usr/bin/env bash
# The sensitivity study's SAC levels (plan part 2, rank 4, as its second addendum says): `sac` and
# `sac_a005` at 1000 days, both at once on one GPU machine, each its own batch of 15 jobs
# (run0, run3, run6 x seeds 0-4) in its own database, exported to $OUT/<id>_1000.npz.
# The code is the plan's commit d06a6ac: a sparse partial clone of it in .dev/d06 (not
# committed; made as the README's "Commands, part 2 (SAC)" says) travels with the call, so
# every job row records that commit. Dry run here: DEVICE=cpu DAYS=2 OUT=/tmp/x bash <this>.
set -uo pipefail
export PYTHONUNBUFFERED=1
DEVICE=${DEVICE:-cuda}
DAYS=${DAYS:-1000}
LIMIT=${LIMIT:-510}   # seconds each level may run; a level stopped by it is reported as not run
ROOT=$PWD
if [ -d .whl ] && [ "$DEVICE" = cuda ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site PATH=/tmp/site/bin:$PATH
fi
git config --global --add safe.directory '*' 2>/dev/null
cd .dev/d06 || { echo "no .dev/d06: make the clone first (README)"; exit 2; }
export NUTRIBENCH_AGENTS=reports/sensitivity/agents
start=$SECONDS
{ date -u +%FT%TZ; nproc; nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>/dev/null
  python3 -c "import torch, numpy, nutribench; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'numpy', numpy.__version__); print('nutribench from', nutribench.__file__)"
  echo "commit $(git rev-parse HEAD 2>&1) dirty=[$(git status --porcelain --untracked-files=no 2>&1)]"; } 2>&1 | tee "$OUT/machine.txt"
mkdir -p /tmp/sens3
for id in sac sac_a005; do
  ( t0=$SECONDS
    timeout "$LIMIT" python3 -m nutribench.cli run --engine batched --device "$DEVICE" --workers 1 \
      --regimes run0,run3,run6 --algos "$id" --seeds 0,1,2,3,4 --episodes "$DAYS" --db "/tmp/sens3/$id.db" \
      > "$OUT/$id.out" 2>&1
    rc=$?
    echo "run: exit $rc after $((SECONDS - t0)) s" >> "$OUT/$id.out"
    [ "$rc" = 0 ] && python3 -m nutribench.cli db export "$OUT/${id}_$DAYS.npz" --db "/tmp/sens3/$id.db" --algos "$id" >> "$OUT/$id.out" 2>&1
  ) &
done
sleep 60; nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv >> "$OUT/machine.txt" 2>&1
wait
echo "both levels ended after $((SECONDS - start)) s" | tee -a "$OUT/machine.txt"
cd "$ROOT" || exit 1
