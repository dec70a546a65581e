"""Every trial of protocol v2's studies as one CSV, and a line per study:
``python reports/tuned_v2/trials.py [DB]`` (reads DB, default reports/tuned_v2/data/tuning.db, writes
reports/tuned_v2/trials.csv and prints per study its trials by state, its best trial and how
many distinct structural settings (minibatch, epochs) its trials had).
``python reports/tuned_v2/trials.py DB --late STUDY`` prints only the numbers of STUDY's complete
trials after the first 24 by completion time (addendum 3: reported, not chosen; sac_rest.sh
fails them in a copy of DB before ``tune best``).

Per trial also: how it was drawn (``drawn``: ``random`` while fewer than the study's start-up
trials had finished when it started, as Optuna's TPE decides; ``tpe`` after; ``retry of N``
for the parameters of failed trial N queued again), and, for complete trials, their place in
the order of completion (``completed_rank``): addendum 3 chooses among the first 24 by it."""

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
#: complete trials per study in the plan (README.md, "Protocol v2"); a later one is an overshoot
PLANNED = 24


def drawn(t: optuna.trial.FrozenTrial, finished_at: list, startup: int) -> str:
    """How ``t``'s parameters were drawn: a retry's come from the trial it retries; otherwise
    TPE draws at random until ``startup`` trials (complete or pruned) have finished."""
    retried = t.system_attrs.get("retry_history")
    if retried:
        return f"retry of {retried[-1]}"
    before = sum(1 for c in finished_at if c <= t.datetime_start)
    return "random" if before < startup else "tpe"


def completion_order(study: optuna.Study) -> list[int]:
    """The numbers of ``study``'s complete trials in the order they completed (ties by number):
    addendum 3's order, by which the first :data:`PLANNED` are the ones the choice is among."""
    return [n for _, n in sorted((t.datetime_complete, t.number) for t in study.trials if t.state.name == "COMPLETE")]


def late(db: str, study_name: str) -> list[int]:
    """Numbers of ``study_name``'s complete trials after the first :data:`PLANNED` by completion."""
    return completion_order(optuna.load_study(study_name=study_name, storage=db))[PLANNED:]


def trials(db: str = DB) -> pd.DataFrame:
    rows = []
    for summary in sorted(optuna.get_all_study_summaries(db, include_best_trial=False), key=lambda s: s.study_name):
        study = optuna.load_study(study_name=summary.study_name, storage=db)
        startup = study.user_attrs.get("nutribench", {}).get("startup_trials", 0)
        finished_at = [t.datetime_complete for t in study.trials if t.state.name in ("COMPLETE", "PRUNED")]
        rank = {n: i + 1 for i, n in enumerate(completion_order(study))}
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
                    "started": t.datetime_start,
                    "completed": t.datetime_complete,
                    "drawn": drawn(t, finished_at, startup),
                    "completed_rank": rank.get(t.number),
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
        eligible = done[done["completed_rank"] <= PLANNED]
        best = eligible.loc[eligible["value"].idxmax()] if len(eligible) else None
        over = list(done[done["completed_rank"] > PLANNED]["number"])
        params = [json.loads(p) for p in part["params"]]
        structure = Counter(tuple(p.get(k) for k in STRUCTURAL) for p in params)
        print(
            f"{study}: {dict(states)}; best "
            + (f"trial {best['number']} {best['value']:+.3f}" if best is not None else "none")
            + f"; (batch_size, n_epochs) drawn: {dict(structure)}"
            + f"; drawn: {dict(Counter(d.split(' of ')[0] for d in part['drawn']))}"
            + (f"; completed after the {PLANNED}th (not chosen): {over}" if over else "")
        )


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("db", nargs="?", help="the study database (default reports/tuned_v2/data/tuning.db)")
    ap.add_argument("--late", metavar="STUDY", help="print only STUDY's trials completed after the first 24")
    a = ap.parse_args()
    url = f"sqlite:///{Path(a.db).resolve()}" if a.db else DB
    if a.late:
        optuna.logging.set_verbosity(optuna.logging.ERROR)
        print(" ".join(str(n) for n in late(url, a.late)))
    else:
        main(url)
