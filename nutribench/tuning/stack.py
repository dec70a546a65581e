"""Running a study's trials (docs/tuning.md, "Stopping and resuming"): one at a time
(:func:`run_study`) or many in one process (``--stack N``: :class:`StackedTrials`).

Drivers stop at ``trials`` finished (complete or pruned) exactly, however many share the
study: a driver claims a trial only while the study holds fewer finished and running trials
(:func:`claim`), and waits while the missing trials all run elsewhere (:func:`wait_for_room`).
Ctrl-C fails the running trial (not counted). A driver killed with -9 leaves its trial RUNNING
with a stopped heartbeat; after the grace period (:func:`~nutribench.tuning.study.heartbeat_settings`)
any driver fails it and queues its parameters (:func:`fail_stale`), run by the next claim, so
that a rerun started at once waits for it and leaves no trial running.

With ``--stack N`` the driver claims up to N trials at once (never more than the study still
misses), each drawn as a lone trial is (structure included), and groups them by structure: trials whose configs agree on everything but the
continuous settings (learning rate, discount, GAE lambda, clip range, entropy and value
coefficients, gradient-norm clip; SAC's learning rates, alpha and tau) train in one batch,
each trial's agents (one per tuning regime and seed) with its own settings on the agent axis
(:attr:`nutribench.engine.algorithm.BatchedAlgorithm.PER_AGENT`: PPO, MC, GRU-PPO and SAC).
Trials of another structure, and algorithms without per-agent settings (DDQN, plug-ins),
train in batches of their own, one trial each, as without ``--stack``.

Every evaluation is scored per trial exactly as a single trial is
(:class:`~nutribench.tuning.objective.ValidationObjective`): the IQM of its agents' shares of
the never -> planner gap on validation days, reported to Optuna at that day. A trial the
pruner stops is told PRUNED and its agents are frozen (no more updates); when every trial of
a batch is pruned, the batch stops. Every claimed trial beats from its claim until told (a
later group's too, while an earlier one trains); an error or Ctrl-C fails those not yet told.
"""

from __future__ import annotations

import datetime
import time
from collections.abc import Callable
from contextlib import suppress
from typing import Any

import numpy as np
import optuna
from optuna.storages._rdb import models
from optuna.trial import TrialState
from sqlalchemy.exc import OperationalError

from nutribench.tuning.asking import StackView, claim, heartbeats, rdb_backend
from nutribench.tuning.objective import TrialScores, ValidationObjective
from nutribench.tuning.study import (
    GRACE_SECONDS,
    StudyCounts,
    TuneError,
    count_trials,
    quiet_experimental,
    quiet_optuna,
)

#: the fields of an agent config that name it, not what it trains
_NAMING = ("name", "version", "description")


def fail_stale(study: Any) -> None:
    """Fail the study's stale trials (a killed driver's) and queue their parameters again:
    those whose heartbeat is older than the grace period (Optuna's
    :func:`~optuna.storages.fail_stale_trials`), and a RUNNING trial that never beat (its
    driver killed between asking it and its first beat) once it started that long ago."""
    with quiet_experimental():
        optuna.storages.fail_stale_trials(study)
    storage = rdb_backend(study)
    if not hasattr(storage, "scoped_session") or not storage.get_heartbeat_interval():
        return
    grace = datetime.timedelta(seconds=storage.grace_period or 2 * storage.heartbeat_interval)
    with storage.scoped_session() as session:  # closed afterwards
        never_beat = [
            t.trial_id
            for t in session.query(models.TrialModel)
            .filter(models.TrialModel.study_id == study._study_id, models.TrialModel.state == TrialState.RUNNING)
            .all()
            if not t.heartbeats and t.datetime_start is not None and datetime.datetime.now() - t.datetime_start > grace
        ]
    callback = storage.get_heartbeat_stale_trial_callback()
    for trial_id in never_beat:
        try:
            if not storage.set_trial_state_values(trial_id, state=TrialState.FAIL):
                continue
        except optuna.exceptions.UpdateFinishedTrialError:
            continue  # another driver failed it first
        if callback is not None:
            with quiet_experimental():
                callback(study, storage.get_trial(trial_id))


def wait_for_room(
    study: Any, trials: int, on_wait: Callable[[StudyCounts], None] | None = None
) -> tuple[StudyCounts, int]:
    """(the study's counts, how many trials a driver may claim now): 0 once the study holds
    ``trials`` finished trials. While every missing trial is running (another driver's, or a
    killed driver's not yet stale), it waits, failing stale trials as their grace period ends
    (their parameters queued again, and claimed next); ``on_wait`` is told once. Since no
    driver claims past the count, a study that reaches it has no trial left running (a driver
    with a higher ``--trials`` aside)."""
    told = False
    interval = study._storage.get_heartbeat_interval() if hasattr(study._storage, "get_heartbeat_interval") else None
    while True:
        fail_stale(study)
        counts = count_trials(study)
        if counts.finished >= trials:
            return counts, 0
        room = trials - counts.finished - counts.running
        if room > 0:
            return counts, room
        if on_wait is not None and not told:
            on_wait(counts)
            told = True
        time.sleep(min(5.0, float(interval or 1)) * (0.5 + np.random.random()))


def run_study(
    study: Any,
    objective: Callable[[Any], float],
    trials: int,
    on_trial: Callable[[StudyCounts], None] | None = None,
    on_wait: Callable[[StudyCounts], None] | None = None,
) -> StudyCounts:
    """Run trials of ``objective`` until ``study`` holds exactly ``trials`` finished (complete
    or pruned) trials, none left running; other drivers on the same study share the work
    (:func:`claim`, :func:`wait_for_room`). An exception in the objective (Ctrl-C included)
    fails its trial and is raised; :class:`optuna.TrialPruned` prunes it. A write the database
    refuses (a full disk) fails the trial at once and is one line (:func:`fail_trials`)."""
    if trials < 1:
        raise TuneError("--trials must be >= 1")

    def run_one(room: int) -> bool:
        trial = claim(study, trials)
        if trial is None:
            return False
        with heartbeats(study, [trial]):
            try:
                try:
                    value = objective(trial)
                except optuna.TrialPruned:
                    study.tell(trial, state=TrialState.PRUNED)
                else:
                    study.tell(trial, value)
            except BaseException as e:  # Ctrl-C, an error, a write the database refused: failed at once
                fail_trials(study, [trial], e)
        if on_trial is not None:
            on_trial(count_trials(study))
        return True

    return drive(study, trials, run_one, on_wait)


def drive(
    study: Any, trials: int, run: Callable[[int], bool], on_wait: Callable[[StudyCounts], None] | None
) -> StudyCounts:
    """Call ``run(room)`` (it claims and runs up to ``room`` trials; False when another driver
    claimed them first) until ``study`` holds ``trials`` finished trials (:func:`wait_for_room`);
    the study's counts then. Optuna's log quiet; a write the database refuses outside a trial
    (claiming one, failing a stale one) one line (:class:`TuneError`), not Optuna's traceback."""
    with quiet_optuna():
        try:
            while True:
                counts, room = wait_for_room(study, trials, on_wait)
                if not room:
                    return counts
                if not run(room):
                    time.sleep(0.05 + 0.2 * np.random.random())  # another driver asked at the same moment
        except TuneError:
            raise
        except Exception as e:
            reason = refused_write(e)
            if reason is None:
                raise
            raise _RefusedWrite(
                f"the study's database refused a write: {reason}: no trial of this driver was running; free space "
                "(or make the database writable) and run the same command again"
            ) from None


def refused_write(error: BaseException) -> str | None:
    """The database's own words when ``error`` is a write (or read) it refused, on one line
    ("database or disk is full", "disk I/O error", "attempt to write a readonly database"): an
    :class:`sqlalchemy.exc.OperationalError` met directly or behind Optuna's
    ``StorageInternalError`` (its cause); None for any other error."""
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OperationalError):
            return " ".join(str(e.orig if e.orig is not None else e).split()) or type(e).__name__
        e = e.__cause__ or e.__context__
    return None


class _RefusedWrite(TuneError):
    """The study's database refused a write (one line, :func:`fail_trials`)."""


def fail_trials(study: Any, trials: list[Any], error: BaseException) -> None:
    """Tell FAIL to those of ``trials`` still running, stopped by ``error``, and raise: ``error``
    itself, or, where the database refused a write (:func:`refused_write`: a full disk), one
    line saying so, which trials were failed at once and what to do. A trial the database
    would not even mark failed is left to the stale rule: any driver fails it (and runs its
    parameters again) once the grace period has passed since its last heartbeat."""
    reason = refused_write(error)
    failed, left = [], []
    for trial in trials:
        for attempt in (0, 1):
            try:
                state = study._storage.get_trial(trial._trial_id).state
                if state == TrialState.RUNNING:
                    study.tell(trial, state=TrialState.FAIL)
                if state in (TrialState.RUNNING, TrialState.FAIL):  # FAIL: told already, on the way up
                    failed.append(trial.number)
                break
            except Exception as e:  # the database refuses that write too
                again = refused_write(e)
                if again is None:
                    raise
                reason = reason or again
                if attempt or not _empty_the_log(study):
                    left.append(trial.number)
                    break
    if reason is None:
        raise error
    grace = getattr(rdb_backend(study), "grace_period", None) or GRACE_SECONDS

    def numbers(ns: list[int]) -> str:
        return f"trial{'s' if len(ns) > 1 else ''} {', '.join(map(str, ns))}"

    done = [f"{numbers(failed)} failed"] if failed else []
    if left:
        done.append(
            f"{numbers(left)} could not be marked failed (a driver fails {'them' if len(left) > 1 else 'it'} "
            f"and runs {'their' if len(left) > 1 else 'its'} parameters again {grace} s after the last heartbeat)"
        )
    raise _RefusedWrite(
        f"the study's database refused a write: {reason}: {'; '.join(done) or 'no trial was running'}; free "
        "space (or make the database writable) and run the same command again: the study goes on from its "
        "finished trials"
    ) from None


def _empty_the_log(study: Any) -> bool:
    """On a SQLite study, move the write-ahead log into the database file and empty it
    (``PRAGMA wal_checkpoint(TRUNCATE)``): on a full disk that frees the log's space, so that the
    small write of a trial's failure fits (on a 2 MB tmpfs the log held 40 kB). Whether it did."""
    backend = rdb_backend(study)
    engine = getattr(backend, "engine", None)
    if engine is None or engine.dialect.name != "sqlite":
        return False
    try:
        with engine.connect() as conn:
            busy, _, _ = conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)").one()
    except Exception as e:
        if refused_write(e) is None:
            raise
        return False
    return not busy


class _AllPruned(Exception):
    """Every trial of a batch was pruned: stop training it."""


def per_agent_fields(cfg: Any) -> tuple[str, ...]:
    """The settings that may differ between stacked trials of ``cfg``'s algorithm (its batched
    class's :attr:`~nutribench.engine.algorithm.BatchedAlgorithm.PER_AGENT`); () where the batched
    engine does not train ``cfg`` or takes no per-agent settings."""
    from nutribench.agents.registry import batched_class
    from nutribench.engine import supports

    if supports(cfg) is not None:
        return ()
    return batched_class(cfg.algo).PER_AGENT


def structure_key(cfg: Any) -> str | None:
    """What trials must share to train in one batch (their config without the settings that
    may differ per agent), or None for an algorithm whose batched class takes none."""
    fields = per_agent_fields(cfg)
    if not fields:
        return None
    data = cfg.model_dump(mode="json")
    return repr(sorted((k, v) for k, v in data.items() if k not in fields and k not in _NAMING))


class StackedTrials:
    """Runs a study ``stack`` trials at a time (the module docstring)."""

    def __init__(self, objective: ValidationObjective, stack: int):
        if stack < 1:
            raise TuneError("--stack must be >= 1")
        self.objective, self.stack = objective, stack

    def run(
        self,
        study: Any,
        trials: int,
        on_trial: Callable[[StudyCounts], None] | None = None,
        on_wait: Callable[[StudyCounts], None] | None = None,
    ) -> StudyCounts:
        """Ask, train and tell batches of trials until ``study`` holds exactly ``trials`` finished
        ones: each batch asks only as many trials as the study still misses
        (none of them running), and claims each as a single trial does
        (:func:`~nutribench.tuning.study.claim`, :func:`~nutribench.tuning.study.wait_for_room`:
        a killed driver's stale trials are failed and their parameters run again)."""

        def run_stack(room: int) -> bool:
            asked = self.ask(study, min(self.stack, room), trials)
            if not asked:
                return False
            groups: dict[str, list[tuple[Any, Any]]] = {}
            for n, (trial, cfg) in enumerate(asked):
                key = structure_key(cfg)
                groups.setdefault(f"alone {n}" if key is None else key, []).append((trial, cfg))
            with heartbeats(study, [t for t, _ in asked]):  # the groups waiting their turn beat too
                try:
                    for group in groups.values():
                        self.train_group(study, group)
                        if on_trial is not None:
                            on_trial(count_trials(study))
                except BaseException as e:
                    fail_trials(study, [t for t, _ in asked], e)  # those not told yet
            return True

        return drive(study, trials, run_stack, on_wait)

    def ask(self, study: Any, n: int, trials: int) -> list[tuple[Any, Any]]:
        """Up to ``n`` claimed trials and their configs (fewer where other drivers claimed the
        study's last places first: never past ``trials`` finished and running), each drawn by
        the sampler as a lone trial is, its structural knobs included (issue 73: a stack that
        shared its first trial's structure searched minibatch and epochs once per stack).
        :meth:`run` then trains trials of one structure together. A trial Optuna queued (a
        killed driver's, to retry) keeps its own parameters."""
        space = self.objective.space
        view = StackView.of(study)  # the study read once; the stack's trials kept as written (asking.py)
        out: list[tuple[Any, Any]] = []
        try:
            for _ in range(n):
                trial = claim(view, trials)
                if trial is None:
                    break
                try:
                    out.append((trial, space.config(space.suggest(trial))))
                except BaseException as e:
                    asked = [trial, *(t for t, _ in out)]
                    for t in asked:
                        t.study, t.storage = study, study._storage
                    fail_trials(study, asked, e)
        finally:
            for trial, _ in out:  # asked: from now on the study's own (reports, prunes, tells)
                trial.study, trial.storage = study, study._storage
        return out

    def train_group(self, study: Any, group: list[tuple[Any, Any]]) -> None:
        """Train the trials of one group in one batch and tell Optuna each one's outcome."""
        obj = self.objective
        n_jobs = len(obj.jobs)
        trials = [t for t, _ in group]
        active = np.ones(n_jobs * len(group), dtype=bool)
        scores = [TrialScores(obj, t) for t in trials]
        pruned: set[int] = set()

        def on_validation(j: int, day: int, rows: list[dict[str, Any]]) -> None:
            n, job = divmod(j, n_jobs)
            if n in pruned:
                return
            if scores[n].add(job, day, rows) is not None and scores[n].prune(day):
                pruned.add(n)
                active[n * n_jobs : (n + 1) * n_jobs] = False
                if len(pruned) == len(group):
                    raise _AllPruned

        for trial, cfg in group:
            obj.record_engine(trial, cfg)
            trial.set_user_attr("stacked_with", [t.number for t in trials if t is not trial])
        try:  # beating since their claim (run's heartbeats)
            with suppress(_AllPruned):
                self.train(group, on_validation, active)
        except BaseException:
            for trial in trials:
                study.tell(trial, state=TrialState.FAIL)
            raise
        for n, trial in enumerate(trials):
            if n in pruned:
                study.tell(trial, state=TrialState.PRUNED)
                continue
            try:
                value = scores[n].final()
            except RuntimeError:
                study.tell(trial, state=TrialState.FAIL)
                raise
            study.tell(trial, value)

    def train(self, group: list[tuple[Any, Any]], on_validation: Callable[..., None], active: np.ndarray) -> None:
        """One batch: every trial's agents, one per (regime, seed), each trial's config for its own."""
        obj = self.objective
        if len(group) == 1 and structure_key(group[0][1]) is None:
            obj.train(group[0][1], on_validation)  # as a single trial (SB3 engine, plug-in, off-policy)
            return
        cfgs = [cfg for _, cfg in group for _ in obj.jobs]
        obj.train_batch(obj.jobs * len(group), group[0][1], on_validation, agent_configs=cfgs, active=active)
