"""Every trial of the tuned grid's studies as one CSV (the plan's "What is kept"), and a
Markdown summary per study: ``python reports/tuned/trials.py`` (reads
reports/tuned/data/tuning.db, writes reports/tuned/trials.csv and prints the summary)."""

from __future__ import annotations

import json
from pathlib import Path

import optuna
import pandas as pd

HERE = Path(__file__).resolve().parent
DB = f"sqlite:///{HERE / 'data' / 'tuning.db'}"


def trials() -> pd.DataFrame:
    rows = []
    for summary in sorted(optuna.get_all_study_summaries(DB, include_best_trial=False), key=lambda s: s.study_name):
        study = optuna.load_study(study_name=summary.study_name, storage=DB)
        for t in study.trials:
            wall = (t.datetime_complete - t.datetime_start).total_seconds() if t.datetime_complete else None
            rows.append(
                {
                    "study": summary.study_name,
                    "number": t.number,
                    "state": t.state.name,
                    "value": t.value,
                    "last_day": max(t.intermediate_values) if t.intermediate_values else None,
                    "params": json.dumps(t.params, sort_keys=True),
                    "shares": json.dumps(t.user_attrs.get("shares", {}), sort_keys=True),
                    "engine": t.user_attrs.get("engine"),
                    "device": t.user_attrs.get("device"),
                    "wall_seconds": wall,
                }
            )
    return pd.DataFrame(rows)


def summary(df: pd.DataFrame) -> str:
    lines = [
        "| study | complete | pruned | failed | best value (trial) | median value of complete trials | trial time (sum) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, g in df.groupby("study"):
        done = g[g.state == "COMPLETE"]
        best = done.loc[done.value.idxmax()] if len(done) else None
        lines.append(
            f"| {name} | {len(done)} | {(g.state == 'PRUNED').sum()} | {(g.state == 'FAIL').sum()} | "
            + (f"{best.value:+.3f} ({best.number})" if best is not None else "-")
            + f" | {done.value.median():+.3f} | {g.wall_seconds.sum():.0f} s |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    table = trials()
    table.to_csv(HERE / "trials.csv", index=False)
    print(summary(table))
