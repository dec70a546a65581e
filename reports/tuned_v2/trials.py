"""Every trial of protocol v2's studies as one CSV, and a line per study:
``python reports/tuned_v2/trials.py [DB]`` (reads DB, default reports/tuned_v2/data/tuning.db, writes
reports/tuned_v2/trials.csv and prints per study its trials by state, its best trial and how
many distinct structural settings (minibatch, epochs) its trials had)."""

from __future__ import annotations

import json
import warnings
from collections import Counter
from pathlib import Path

import optuna
import pandas as pd

HERE = Path(__file__).resolve().parent
DB = f"sqlite:///{HERE / 'data' / 'tuning.db'}"
STRUCTURAL = ("batch_size", "n_epochs")


def trials(db: str = DB) -> pd.DataFrame:
    rows = []
    for summary in sorted(optuna.get_all_study_summaries(db, include_best_trial=False), key=lambda s: s.study_name):
        study = optuna.load_study(study_name=summary.study_name, storage=db)
        for t in study.trials:
            wall = (t.datetime_complete - t.datetime_start).total_seconds() if t.datetime_complete else None
            rows.append(
                {
                    "study": summary.study_name,
                    "number": t.number,
                    "state": t.state.name,
                    "value": t.value,
                    "values_by_day": json.dumps({int(d): v for d, v in sorted(t.intermediate_values.items())}),
                    "params": json.dumps(t.params, sort_keys=True),
                    "shares": json.dumps(t.user_attrs.get("shares", {}), sort_keys=True),
                    "stacked_with": json.dumps(t.user_attrs.get("stacked_with", [])),
                    "engine": t.user_attrs.get("engine"),
                    "device": t.user_attrs.get("device"),
                    "wall_seconds": wall,
                }
            )
    return pd.DataFrame(rows)


def main(db: str = DB) -> None:
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    df = trials(db)
    df.to_csv(HERE / "trials.csv", index=False)
    for study, part in df.groupby("study"):
        states = Counter(part["state"])
        done = part[part["state"] == "COMPLETE"]
        best = done.loc[done["value"].idxmax()] if len(done) else None
        params = [json.loads(p) for p in part["params"]]
        structure = Counter(tuple(p.get(k) for k in STRUCTURAL) for p in params)
        print(
            f"{study}: {dict(states)}; best "
            + (f"trial {best['number']} {best['value']:+.3f}" if best is not None else "none")
            + f"; (batch_size, n_epochs) drawn: {dict(structure)}"
        )


if __name__ == "__main__":
    import sys

    main(f"sqlite:///{Path(sys.argv[1]).resolve()}" if len(sys.argv) > 1 else DB)
