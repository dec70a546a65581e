#!/usr/bin/env bash
# One batch of the plan (an agent at a level) on the CPU: the plan's `batch` function ("Commands")
# with a log beside its archive: logs/obs<level>_<agent>.txt (date, device, commit, packages, wall
# time, exit statuses) and logs/obs<level>_<agent>_run.log (nutribench run's output).
# Usage, from a clean checkout with the project installed as the README says (the plan's order:
# the next batch not run; two free cores: one queue each):
#   bash reports/ladder/cpu_batch.sh ppo 4
# A stopped batch resumes from its checkpoints when started again: the log keeps every start.
set -u
cd "$(dirname "$0")/../.."
[ $# -eq 2 ] || { echo "cpu_batch.sh: give the agent and the level, e.g. ppo 4" >&2; exit 2; }
case "$2" in 1) folder=regimes ;; 2|3|4) folder=reports/ladder/regimes_obs$2 ;;
  *) echo "cpu_batch.sh: level $2 is not 1-4" >&2; exit 2 ;; esac
export NUTRIBENCH_AGENTS=reports/ladder/agents
SEEDS=3800,3801,3802,3803,3804,3805,3806,3807,3808,3809
RUN="nutribench run --engine batched --device cpu --regimes run0,run3,run6 --seeds $SEEDS --episodes 5000 --eval-episodes 10 --eval-every 100 --workers 1"
name=obs$2_$1 log=reports/ladder/logs/obs$2_$1
mkdir -p /tmp/ladder reports/ladder/data reports/ladder/logs
{ date -u +%FT%TZ
  echo "batch $name, device cpu, code $(git rev-parse HEAD) $(git status --porcelain -- nutribench regimes reports/ladder/agents 'reports/ladder/regimes_obs*' | wc -l) changed files"
  nproc
  python -c "import torch,numpy,stable_baselines3 as s;print('torch',torch.__version__,'numpy',numpy.__version__,'sb3',s.__version__)"; } >> "$log.txt"
t0=$SECONDS
NUTRIBENCH_REGIMES=$folder $RUN --algos "$1" --db "/tmp/ladder/$name.db" >> "${log}_run.log" 2>&1
rc=$?
echo "run rc $rc after $((SECONDS - t0)) s" >> "$log.txt"
[ "$rc" -eq 0 ] || exit "$rc"
NUTRIBENCH_REGIMES=$folder nutribench db export "reports/ladder/data/$name.npz" --db "/tmp/ladder/$name.db" --algos "$1" >> "${log}_run.log" 2>&1
rc=$?
echo "export rc $rc" >> "$log.txt"
(cd reports/ladder/data && sha256sum -- * | grep -v ' SHA256SUMS$' > SHA256SUMS)
exit "$rc"
