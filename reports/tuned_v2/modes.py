"""Which way each run of a v2 file eats during training: its validation days (every 250 days of
the grid) read as "nothing" (no food on any validation day at that point), "much" (at least
MUCH foods a validation day, on average) or neither, and how often a run changes between the two.

Written for SAC's v2 file, whose test days split its delayed runs between eating nothing and
overeating (README.md, "SAC, v2"): do its runs settle into one of the two, or switch?

Usage: python reports/tuned_v2/modes.py [AGENT]   (default sac_tuned_v2; reads
data/AGENT.npz, imported into a temporary database: about 12 s on the 2-core machine)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
#: foods a validation day, on average, from which a point counts as "much" (run0's learners eat about 5)
MUCH = 20


def modes(curve: pd.DataFrame, much: float = MUCH) -> pd.DataFrame:
    """Per regime: runs, how many were at "nothing" at one validation point and at "much" at
    another, and the median number of changes between the two (points in between skipped).
    ``curve`` holds ``regime``, ``seed``, ``train_day`` and ``foods`` (one row per validation day)."""
    per_point = curve.groupby(["regime", "seed", "train_day"], sort=True)["foods"].mean()
    rows = []
    for (regime, seed), foods in per_point.groupby(level=["regime", "seed"]):
        seq = [f >= much for f in foods if f == 0 or f >= much]
        changes = sum(a != b for a, b in zip(seq, seq[1:]))
        rows.append({"regime": regime, "seed": seed, "both": len(set(seq)) == 2, "changes": changes})
    runs = pd.DataFrame(rows)
    return runs.groupby("regime").agg(
        runs=("seed", "size"), nothing_and_much=("both", "sum"), median_changes=("changes", "median")
    )


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("agent", nargs="?", default="sac_tuned_v2", help="an archive of data/ (without .npz)")
    a = ap.parse_args(argv)
    archive = HERE / "data" / f"{a.agent}.npz"
    if not archive.is_file():
        print(f"modes.py: no archive {archive}: name one of data/*.npz (without .npz)", file=sys.stderr)
        return 2
    from nutribench.store import read_learning_curve
    from nutribench.store.archive import import_results

    with tempfile.TemporaryDirectory(prefix="nutribench-modes-") as tmp:
        db = str(Path(tmp) / "modes.db")
        import_results(archive, db)
        curve = read_learning_curve(db)
    print(f"{a.agent}: validation points every 250 days; 'nothing' = no food, 'much' = >= {MUCH} foods a day")
    print(modes(curve[curve["algo"] == a.agent]).to_string())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
