"""Claiming trials and keeping them alive, at a cost in proportion to the trials asked.

:func:`claim` takes a queued trial or asks a new one and counts the study's held trials in
one SQL query each (a study's storage is RDB: :func:`nutribench.tuning.study.optuna_storage`), and
:func:`heartbeats` beats all of a batch's trials in one transaction per interval, reading no
trial. :class:`StackView` serves the sampler's reads while a stack of trials is asked from
one read of the study plus the stack's own trials, kept as they are written (issue 51: with
``--stack 256`` each ask read every running trial several times, Optuna's cached storage
reading its unfinished trials afresh on each call, and the stack's asks cost N squared).

Optuna's public API has no such reads, so this module (and a few lines of ``stack.py``) use its
internals: ``Study._storage``, ``_study_id``, ``_thread_local``, ``Trial._trial_id``,
the cached storage's ``_backend`` and the RDB table models.
``tests/test_optuna_internals.py`` checks each of them against the installed Optuna (pinned
``>=5.0,<6``), so that an upgrade which moves one fails there, by name.
"""

from __future__ import annotations

import copy
import datetime
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from typing import Any

import optuna
import sqlalchemy
from optuna.storages._rdb import models
from optuna.trial import TrialState


def rdb_backend(study: Any) -> Any:
    """The study's RDB storage (under Optuna's cache, or under a :class:`StackView`)."""
    storage = study._storage
    storage = getattr(storage, "inner", storage)
    return getattr(storage, "_backend", storage)


def beat(storage: Any, trial_ids: list[int]) -> None:
    """Record the heartbeat of every trial of ``trial_ids`` (Optuna's ``record_heartbeat``),
    on an RDB storage in one transaction that reads only their heartbeat rows."""
    backend = getattr(storage, "_backend", storage)
    if not trial_ids:
        return

    beats = models.TrialHeartbeatModel
    with backend.scoped_session() as session:  # closed (an open transaction rolled back) whatever happens
        try:
            now = session.execute(sqlalchemy.func.now()).scalar()
            rows = session.query(beats).filter(beats.trial_id.in_(trial_ids)).all()
            known = {row.trial_id for row in rows}
            for row in rows:
                row.heartbeat = now
            session.add_all([beats(trial_id=t, heartbeat=now) for t in trial_ids if t not in known])
            session.commit()
        except sqlalchemy.exc.IntegrityError:  # a heartbeat row written meanwhile: one by one, as Optuna does
            session.rollback()
            for trial_id in trial_ids:
                backend.record_heartbeat(trial_id)


@contextmanager
def heartbeats(study: Any, trials: list[Any]) -> Iterator[None]:
    """Keep the running ``trials``' heartbeats while the block runs (the first beat before the
    block starts); a driver killed with -9 stops them, and its trials go stale. A beat writes
    the trials' heartbeats and reads no trial of the study."""
    storage = study._storage
    interval = storage.get_heartbeat_interval() if hasattr(storage, "get_heartbeat_interval") else None
    if not interval:
        yield
        return
    ids = [t._trial_id for t in trials]
    beat(storage, ids)
    stop = threading.Event()

    def beating() -> None:
        while not stop.wait(interval):
            # a beat the database refused (a full disk): the next one tries again; missed for the
            # whole grace period, the trials go stale as a killed driver's
            with suppress(sqlalchemy.exc.OperationalError):
                beat(storage, ids)

    thread = threading.Thread(target=beating, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def _count_held(study: Any) -> int:
    """How many of the study's trials are finished (complete or pruned) or running: one
    ``COUNT`` on an RDB storage, read afresh (other drivers' trials included)."""
    trials, held = models.TrialModel, (TrialState.COMPLETE, TrialState.PRUNED, TrialState.RUNNING)
    query = sqlalchemy.select(sqlalchemy.func.count(trials.trial_id)).where(
        trials.study_id == study._study_id, trials.state.in_(held)
    )
    with rdb_backend(study).engine.connect() as conn:
        return int(conn.execute(query).scalar_one())


def _pop_waiting(study: Any) -> int | None:
    """The id of a queued (WAITING) trial this driver set RUNNING, or None when none is queued:
    the queued ids read in one query, each taken in one conditional UPDATE, which one driver
    wins (Study.ask reads, then writes: on SQLite two drivers could both take one trial, and
    one trial was told twice)."""
    storage = rdb_backend(study)
    trials = models.TrialModel
    waiting = (
        sqlalchemy.select(trials.trial_id)
        .where(trials.study_id == study._study_id, trials.state == TrialState.WAITING)
        .order_by(trials.trial_id)
        .limit(8)
    )
    while True:
        with storage.engine.connect() as conn:
            queued = conn.execute(waiting).scalars().all()
        if not queued:
            return None
        for trial_id in queued:
            with storage.engine.begin() as conn:
                won = conn.execute(
                    sqlalchemy.update(trials)
                    .where(trials.trial_id == trial_id, trials.state == TrialState.WAITING)
                    .values(state=TrialState.RUNNING, datetime_start=datetime.datetime.now())
                ).rowcount
            refresh = getattr(study._storage, "refresh", None)
            if refresh is not None:
                refresh(trial_id)  # a stack's view: the trial as it is now (taken, by this driver or another)
            if won == 1:
                return trial_id


def claim(study: Any, trials: int) -> Any | None:
    """A trial of ``study`` to run (a queued one first: a killed driver's parameters to retry),
    or None when the study holds ``trials`` finished and running trials once it is asked.

    The count is taken after the ask, the new trial among the running: of drivers asking at
    once none runs a trial past the count (each one's count holds every trial asked before it;
    one over the count goes back to the queue, WAITING, never run nor counted, never beaten)."""
    study._thread_local.cached_all_trials = None  # as Study.ask: the trials read afresh
    trial_id = _pop_waiting(study)
    if trial_id is None:
        trial_id = study._storage.create_new_trial(study._study_id)
    else:  # a queued trial, perhaps another driver's: Optuna's cached storage must know it first
        _know(study, trial_id)
    trial = optuna.Trial(study, trial_id)
    if _count_held(study) <= trials:
        return trial
    study._storage.set_trial_state_values(trial._trial_id, state=TrialState.WAITING)
    return None


def _know(study: Any, trial_id: int) -> None:
    """Make ``study``'s storage hold ``trial_id``, a queued trial this driver took (another
    driver may have queued it): Optuna's cached storage writes a trial's parameters only for
    trials it has read, so it reads the study's trials once more; a :class:`StackView` also adds
    it to the trials the sampler sees. Nothing is read for a trial the view already holds (one
    this driver queued for its stack)."""
    storage = study._storage
    if isinstance(storage, StackView):
        if trial_id not in storage.trials:
            storage.inner.get_all_trials(study._study_id, deepcopy=False)
            storage.refresh(trial_id)
    else:
        storage.get_all_trials(study._study_id, deepcopy=False)


class StackView:
    """A study's storage as the sampler sees it while one stack of trials is asked: the
    study's trials read once (:meth:`of`), then the stack's own trials kept as this driver
    writes them (created, their parameters, system attributes and states); every write goes
    to the storage, and every other call too. Other drivers' trials asked meanwhile are seen
    by the next stack (TPE's constant liar sees every trial of this stack as running)."""

    def __init__(self, inner: Any, study_id: int):
        self.inner, self.study_id = inner, study_id
        self.trials = {t._trial_id: t for t in inner.get_all_trials(study_id, deepcopy=True)}

    @classmethod
    def of(cls, study: Any) -> Any:
        """A copy of ``study`` reading through a new view (its sampler and pruner shared)."""
        view = copy.copy(study)
        view._storage = cls(study._storage, study._study_id)
        view._thread_local = type(study._thread_local)()
        return view

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def refresh(self, trial_id: int) -> None:
        """Read one trial afresh (after a write this view does not mirror)."""
        self.trials[trial_id] = copy.deepcopy(self.inner.get_trial(trial_id))

    def get_all_trials(self, study_id: int, deepcopy: bool = True, states: Any = None) -> list[Any]:
        if study_id != self.study_id:
            return self.inner.get_all_trials(study_id, deepcopy=deepcopy, states=states)
        out = sorted((t for t in self.trials.values() if states is None or t.state in states), key=lambda t: t.number)
        return copy.deepcopy(out) if deepcopy else out

    def create_new_trial(self, study_id: int, template_trial: Any = None) -> int:
        trial_id = self.inner.create_new_trial(study_id, template_trial)
        if study_id == self.study_id:
            self.refresh(trial_id)
        return trial_id

    def set_trial_param(self, trial_id: int, name: str, internal: float, distribution: Any) -> None:
        try:
            self.inner.set_trial_param(trial_id, name, internal, distribution)
        except KeyError:  # Optuna's cache has not read this trial (another driver's, queued): read, retry
            self.inner.get_all_trials(self.study_id, deepcopy=False)
            self.inner.set_trial_param(trial_id, name, internal, distribution)
        if trial_id in self.trials:
            self.trials[trial_id].params[name] = distribution.to_external_repr(internal)
            self.trials[trial_id].distributions[name] = distribution

    def set_trial_system_attr(self, trial_id: int, key: str, value: Any) -> None:
        self.inner.set_trial_system_attr(trial_id, key, value)
        if trial_id in self.trials:
            self.trials[trial_id].system_attrs[key] = value

    def set_trial_state_values(self, trial_id: int, state: Any, values: Any = None) -> bool:
        try:
            return self.inner.set_trial_state_values(trial_id, state=state, values=values)
        finally:
            if trial_id in self.trials:
                self.refresh(trial_id)
