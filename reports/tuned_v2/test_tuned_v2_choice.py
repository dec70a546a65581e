"""reports/tuned_v2/trials.py: addendum 3's rule, the choice among the first 24 complete trials by
completion time (two drivers can complete more, and not in the order of their numbers)."""

from __future__ import annotations

import datetime as dt
import warnings
from pathlib import Path

import optuna
import pytest
from optuna.trial import FrozenTrial, TrialState
from report_scripts import load_script

T0 = dt.datetime(2026, 1, 1)


@pytest.fixture(scope="module")
def trials_py():
    return load_script("tuned_v2", "trials")


def _study(tmp_path: Path, finished: list[tuple[int, TrialState, float | None]]) -> str:
    """A study whose trial ``number`` finished at minute ``minute`` in ``state`` (in this order)."""
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    db = f"sqlite:///{tmp_path / 'tuning.db'}"
    study = optuna.create_study(study_name="v2_x", storage=db, direction="maximize")
    dist = {"lr": optuna.distributions.FloatDistribution(1e-5, 1e-2, log=True)}
    for number, (minute, state, value) in enumerate(finished):
        study.add_trial(
            FrozenTrial(
                number=number,
                state=state,
                value=value,
                datetime_start=T0,
                datetime_complete=T0 + dt.timedelta(minutes=minute),
                params={"lr": 1e-3},
                distributions=dist,
                user_attrs={},
                system_attrs={},
                intermediate_values={},
                trial_id=number,
            )
        )
    return db


def test_late_trials_are_those_completed_after_the_24th_not_the_highest_numbers(tmp_path, trials_py):
    assert trials_py.PLANNED == 24
    # 27 trials: number 1 failed; of the 26 complete, numbers 25 and 26 finish early (a second
    # driver's short trials) and numbers 3 and 7 finish last
    minutes = {n: 10 * (n + 1) for n in range(27)}
    minutes.update({25: 5, 26: 6, 3: 400, 7: 401})
    finished = [
        (minutes[n], TrialState.FAIL if n == 1 else TrialState.COMPLETE, None if n == 1 else float(n))
        for n in range(27)
    ]
    db = _study(tmp_path, finished)
    assert trials_py.late(db, "v2_x") == [3, 7]
    table = trials_py.trials(db).set_index("number")
    assert table.loc[25, "completed_rank"] == 1 and table.loc[7, "completed_rank"] == 26
    assert table.loc[1, "state"] == "FAIL"


def test_no_late_trials_when_24_or_fewer_are_complete(tmp_path, trials_py):
    db = _study(tmp_path, [(n, TrialState.COMPLETE, float(n)) for n in range(24)])
    assert trials_py.late(db, "v2_x") == []
