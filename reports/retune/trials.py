"""The re-tuning studies' trials as README.md's tables list them: study, trial, state, value
(the late mean), epochs, minibatch and trial time (Optuna's duration, from a stack's claim to
the trial's end: not a cost), one row a trial.

Usage: python reports/retune/trials.py DB STUDY [FROM]   (DB: a copy of tuning.db, e.g.
data/tuning.db; STUDY: retune_<agent>_<draw>; FROM: the first trial number to list, default 0)
Prints Markdown rows (no header), then the study's count of complete trials and its best.
"""

from __future__ import annotations

import sys

LABELS = {
    "retune_ppo_b": "PPO B",
    "retune_ppo_c": "PPO C",
    "retune_gru_ppo_b": "GRU-PPO B",
    "retune_gru_ppo_c": "GRU-PPO C",
}


def rows(db: str, study: str, first: int = 0) -> list[str]:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    s = optuna.load_study(study_name=study, storage=f"sqlite:///{db}")
    label = LABELS.get(study, study)
    out = []
    for t in s.trials:
        if t.number < first:
            continue
        state = {"COMPLETE": "complete", "RUNNING": "running at the save", "FAIL": "failed"}.get(
            t.state.name, t.state.name
        )
        value = f"{t.value:.3f}" if t.value is not None else ""
        time = f"{t.duration.total_seconds() / 60:.1f} min" if t.duration is not None else ""
        out.append(
            f"| {label} | {t.number} | {state} | {value} | {t.params.get('n_epochs', '')} | "
            f"{t.params.get('batch_size', '')} | {time} |"
        )
    done = [t for t in s.trials if t.state.name == "COMPLETE"]
    if done:
        best = max(done, key=lambda t: t.value)
        out.append(f"{label}: {len(done)} of 24 complete, best {best.value:.3f} (trial {best.number})")
    else:
        out.append(f"{label}: 0 of 24 complete")
    return out


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit("usage: python reports/retune/trials.py DB STUDY [FROM]")
    print("\n".join(rows(sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 0)))
