#!/usr/bin/env bash
# The leaderboard of docs/leaderboard.md's section 1, written to reports/tuned_v2/leaderboard/:
# the paper's archives (reports/paper/data/) and the tuned files', protocol v2's
# (data/<agent>_tuned_v2.npz, all five); ranked by `nutribench leaderboard --archives`, which checks each
# archive by replaying its evaluation days on import (the folders' SHA256SUMS it does not read:
# `sha256sum -c SHA256SUMS` in each data/ folder checks those).
# Usage: bash reports/tuned_v2/leaderboard.sh   (PYTHON=... to name the interpreter)
set -eu
here="$(cd "$(dirname "$0")" && pwd)"
main="$(cd "$here/../.." && pwd)"
py="${PYTHON:-python}"
dir="$(mktemp -d)"
trap 'rm -rf "$dir"' EXIT
ln -s "$main"/reports/paper/data/*.npz "$dir"/
for agent in mc ddqn ppo gru_ppo sac; do
  if [ ! -e "$here/data/${agent}_tuned_v2.npz" ]; then
    echo "leaderboard.sh: data/${agent}_tuned_v2.npz is missing: run grid.sh for it first" >&2
    exit 1
  fi
  ln -s "$here/data/${agent}_tuned_v2.npz" "$dir"/
done
echo "leaderboard.sh: ranking $(ls "$dir" | wc -l) archives: $(ls "$dir" | tr '\n' ' ')" >&2
cd "$main"
"$py" -m nutribench.cli leaderboard --archives "$dir" --out "$here/leaderboard"
