"""Every held-out job of the re-tuning study, one by one (README.md: "Every job of the grid is
reported"): per agent file, a row per held-out regime and a column per evaluation seed, the
job's share of the never -> planner gap on its fixed test days (%, the mean over its test days)
and the foods it ate a test day; then the jobs that did not finish.

Usage: python reports/retune/jobs.py DB [FILE ...]   (DB: the grid's database, or one that the
archives in data/ were imported into; FILE: the agent files to list, default every one held)
Prints Markdown. No statistic is computed here: the readings R1-R4 come after the whole grid.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import pandas as pd

REGIMES = ("run1", "run3", "run6")


def job_rows(db: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(scores, foods): each (algo, regime, seed) run's share of the gap, and its foods a test day."""
    from nutribench.report.data import prepare
    from nutribench.report.references import eval_day_references
    from nutribench.report.scores import run_scores
    from nutribench.store import read_episode_metrics

    ev = prepare(read_episode_metrics(db, phase="eval")).eval
    scores = run_scores(ev, eval_day_references(ev, log=lambda *_: None))
    foods = ev.groupby(["algo", "regime", "seed"])["foods"].mean().rename("foods").reset_index()
    return scores, foods


def unfinished(db: str) -> pd.DataFrame:
    """The grid's jobs not done (regime, algo, seed, status), from the jobs table."""
    from nutribench.store import read_jobs

    jobs = read_jobs(db)[["regime", "algo", "seed", "status"]]
    return jobs[jobs["status"] != "done"].sort_values(["algo", "regime", "seed"])


def markdown(db: str, files: Sequence[str] = ()) -> str:
    scores, foods = job_rows(db)
    both = scores.merge(foods, on=["algo", "regime", "seed"])
    lines = []
    for name in files or sorted(both["algo"].unique()):
        cell = both[both["algo"] == name].set_index(["regime", "seed"])
        seeds = sorted(cell.index.get_level_values("seed").unique())
        lines += [f"**{name}**: {len(cell)} jobs done; share of the gap in % (foods a test day)", ""]
        lines += ["| regime | " + " | ".join(f"seed {s}" for s in seeds) + " |", "|---|" + "---|" * len(seeds)]
        for r in REGIMES:
            row = [
                f"{100 * cell.loc[(r, s), 'score']:.0f} ({cell.loc[(r, s), 'foods']:.1f})"
                if (r, s) in cell.index
                else ""
                for s in seeds
            ]
            lines.append(f"| {r} | " + " | ".join(row) + " |")
        lines.append("")
    left = unfinished(db)
    lines.append(
        "Jobs not done: none."
        if left.empty
        else "Jobs not done: "
        + ", ".join(f"{a} {r} seed {s} ({st})" for r, a, s, st in left.itertuples(index=False, name=None))
        + "."
    )
    return "\n".join(lines)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: python reports/retune/jobs.py DB [FILE ...]")
    print(markdown(sys.argv[1], sys.argv[2:]))
