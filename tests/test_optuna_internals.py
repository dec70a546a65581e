"""The Optuna internals nutribench's tuning driver relies on (``nutribench/tuning/asking.py``,
``stack.py``, ``study.py``: private attributes and the RDB storage's table models, used where
Optuna's public API would read every trial of a study for each ask or beat) exist, with the
meaning the driver gives them, in the installed Optuna; pyproject pins ``optuna>=5.0,<6``. An
upgrade that moves one fails here, by name, not as a wrong count in a running study."""

from __future__ import annotations

from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState


@pytest.fixture
def study(tmp_path: Path):
    storage = optuna.storages.RDBStorage(f"sqlite:///{tmp_path / 's.db'}", heartbeat_interval=60, grace_period=120)
    return optuna.create_study(study_name="s", storage=storage)


def test_the_pinned_optuna_is_the_one_installed() -> None:
    major = int(optuna.__version__.split(".")[0])
    assert major == 5, f"optuna {optuna.__version__}: pyproject pins >=5.0,<6; recheck these internals first"


def test_the_study_and_trial_internals_the_driver_reads(study) -> None:
    from optuna.storages._cached_storage import _CachedStorage

    storage = study._storage
    assert isinstance(storage, _CachedStorage) and hasattr(storage, "_backend")  # asking.rdb_backend
    backend = storage._backend
    assert hasattr(backend, "engine") and callable(backend.scoped_session)  # the SQL queries and the beat
    assert backend.get_heartbeat_interval() == 60 and backend.grace_period == 120
    assert callable(backend.get_heartbeat_stale_trial_callback)
    assert isinstance(study._study_id, int)
    assert hasattr(study, "_thread_local")
    study._thread_local.cached_all_trials = None  # claim() resets it as Study.ask does
    trial = study.ask()
    assert isinstance(trial._trial_id, int)
    assert study.trials[0]._trial_id == trial._trial_id  # FrozenTrial's too (StackView keys)


def test_the_table_models_the_driver_queries(study) -> None:
    from optuna.storages._rdb import models

    trial = models.TrialModel
    for column in ("trial_id", "study_id", "state", "datetime_start"):
        assert column in trial.__table__.columns, column
    assert hasattr(trial, "heartbeats")  # a trial that never beat (stack.py)
    beats = models.TrialHeartbeatModel
    assert {"trial_id", "heartbeat"} <= set(beats.__table__.columns.keys())
    t = study.ask()
    session = study._storage._backend.scoped_session()
    try:
        row = session.query(trial).filter(trial.trial_id == t._trial_id).one()
        assert row.state == TrialState.RUNNING and row.study_id == study._study_id
    finally:
        session.close()


def test_the_samplers_constant_liar_is_where_the_test_of_it_reads_it() -> None:
    assert optuna.samplers.TPESampler(constant_liar=True)._constant_liar is True
