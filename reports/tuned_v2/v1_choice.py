"""What protocol v2's choice would have changed on protocol v1's studies (plan, "The choice").

Reads the v1 studies in reports/tuned/data/tuning.db (no training) and writes
``v1_choice.md``: per study, its trials by state, the trial v1 chose (the best value at day
500 among the trials the median pruner let finish), the trial the late-mean objective picks
among the same finished trials (the mean of the values after day 250: days 300 .. 500), the
v1 winner's rank under it, and what the pruned trials were worth when they were stopped.

    python reports/tuned_v2/v1_choice.py            # writes reports/tuned_v2/v1_choice.md
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DB = HERE.parent / "tuned" / "data" / "tuning.db"


def late_mean(trial, days: int) -> float | None:
    """The mean of a trial's values after half its days, None if it stopped before its last day."""
    values = trial.intermediate_values
    if days not in values:
        return None
    return float(np.mean([v for d, v in values.items() if 2 * d > days]))


def study_rows(study) -> dict:
    import optuna

    days = study.user_attrs["nutribench"]["days"]
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    pruned = [t for t in study.trials if t.state == optuna.trial.TrialState.PRUNED]
    if not done:
        return {"study": study.study_name, "finished": 0}
    v1 = max(done, key=lambda t: t.value)
    scored = sorted(done, key=lambda t: late_mean(t, days), reverse=True)
    v2 = scored[0]
    half = days // 2
    at_half = [t.intermediate_values.get(half) for t in pruned if half in t.intermediate_values]
    return {
        "study": study.study_name,
        "trials": len(study.trials),
        "complete": len(done),
        "pruned": len(pruned),
        "other": len(study.trials) - len(done) - len(pruned),
        "v1 pick": f"{v1.number} ({v1.value:+.3f}; late {late_mean(v1, days):+.3f})",
        "late-mean pick": f"{v2.number} ({v2.value:+.3f}; late {late_mean(v2, days):+.3f})",
        "v1 pick's late-mean rank": scored.index(v1) + 1,
        "pruned: value when stopped": (
            f"{np.median(at_half):+.3f} median, {max(at_half):+.3f} best" if at_half else "n/a"
        ),
        f"pruned above the v1 pick at day {half}": sum(v >= v1.intermediate_values.get(half, np.inf) for v in at_half),
    }


def main(out: Path = HERE / "v1_choice.md") -> None:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    storage = f"sqlite:///{DB}"
    rows = [
        study_rows(optuna.load_study(study_name=s.study_name, storage=storage))
        for s in sorted(optuna.get_all_study_summaries(storage), key=lambda s: s.study_name)
    ]
    cols = list(max(rows, key=len))
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in cols) + " |" for r in rows]
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "v1_choice.md")
