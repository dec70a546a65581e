"""Tuning studies: Optuna studies in the results database, resumable, shared by drivers.

A study lives in the same database as the results (SQLite file or any SQLAlchemy URL), in
Optuna's own tables beside nutribench's (:mod:`nutribench.store.schema` says how the two
schema chains keep apart). nutribench's schema is opened (created, upgraded) first, then
Optuna's RDB storage on the same URL.

A study is fixed when it is created: its search space (name, version, content hash), tuning
regimes and seeds, training days per trial, evaluation period, validation days, sampler seed
and pruner are stored as the study's user attribute ``nutribench``; resuming it with other
settings is refused in one line. ``trials`` counts finished trials (complete or pruned): a
driver runs until the study holds that many, so a resumed or second driver only adds what is
missing (:class:`optuna.study.MaxTrialsCallback`).

Stopping: Ctrl-C fails the running trial (Optuna records it as FAIL; it is not counted) and
exits. A driver killed with -9 leaves its trial RUNNING; its heartbeat stops, and once the
grace period has passed the next driver to start a trial marks it FAIL and queues a copy of
its parameters (Optuna's heartbeat and :class:`~optuna.storages.RetryHeartbeatStaleTrialCallback`),
so the trial is neither lost nor counted twice.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nutribench.errors import UserError

#: seeds the project reports results on (the paper's); a tuning study may not tune on them
REPORTED_SEEDS: tuple[int, ...] = (0, 21, 9, 2003, 1997)
#: the tuning seeds a study uses when none are given (fresh: no study reports on them)
DEFAULT_TUNING_SEEDS: tuple[int, ...] = (101, 102, 103)
#: Optuna heartbeat: seconds between a running trial's beats, and how long without one makes it stale
HEARTBEAT_SECONDS = float(os.environ.get("NUTRIBENCH_TUNE_HEARTBEAT", "30"))
GRACE_SECONDS = float(os.environ.get("NUTRIBENCH_TUNE_GRACE", "120"))
#: the attribute holding the study's fixed settings
ATTR = "nutribench"
PRUNERS = ("median", "none")
#: a trial's objective: its value at the last day, or the mean of its values after half its days
OBJECTIVES = ("last", "late-mean")


class TuneError(UserError, ValueError):
    """A tuning study cannot be started or resumed as asked (one line)."""


@dataclass(frozen=True)
class StudySettings:
    """What a study fixes when it is created (stored with it, checked on every resume)."""

    space: str
    space_version: int
    space_sha256: str
    regimes: tuple[str, ...]
    seeds: tuple[int, ...]
    days: int
    eval_every: int
    val_episodes: int
    sampler_seed: int
    pruner: str
    startup_trials: int = 5
    objective: str = "last"  # a study made before the setting existed scored its last day

    def as_attr(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.__dict__.items()}

    def check(self) -> None:
        """Refuse settings a study cannot run on (one line each)."""
        if not self.regimes:
            raise TuneError("--regimes: name at least one regime")
        if not self.seeds:
            raise TuneError("--seeds: name at least one tuning seed")
        reported = sorted(set(self.seeds) & set(REPORTED_SEEDS))
        if reported:
            raise TuneError(
                f"--seeds: {', '.join(map(str, reported))} are seeds results are reported on "
                f"({', '.join(map(str, REPORTED_SEEDS))}); tune on other seeds (default: "
                f"{','.join(map(str, DEFAULT_TUNING_SEEDS))})"
            )
        if any(s < 0 for s in self.seeds):
            raise TuneError("--seeds: seeds are whole numbers >= 0")
        if self.days < 1 or self.eval_every < 1 or self.val_episodes < 1:
            raise TuneError("--days, --eval-every and --val-episodes must be >= 1")
        if self.days % self.eval_every:
            raise TuneError(
                f"--days ({self.days}) must be a multiple of --eval-every ({self.eval_every}): a trial's value is "
                "its evaluation at the last day"
            )
        if self.startup_trials < 1:
            raise TuneError("--startup-trials must be >= 1 (the random trials TPE starts from)")
        if self.pruner not in PRUNERS:
            raise TuneError(f"--pruner: {self.pruner!r} is not one of {', '.join(PRUNERS)}")
        if self.objective not in OBJECTIVES:
            raise TuneError(f"--objective: {self.objective!r} is not one of {', '.join(OBJECTIVES)}")
        if self.objective == "late-mean" and self.days // self.eval_every < 2:
            raise TuneError("--objective late-mean needs two evaluations or more: lower --eval-every")


@contextmanager
def quiet_experimental() -> Iterator[None]:
    """Optuna's ``ExperimentalWarning`` silenced while the block runs, the caller's warnings
    filters restored afterwards: the heartbeat and the stale-trial retry are marked
    experimental since Optuna 2.8; their behaviour here is tested."""
    import optuna

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
        yield


def optuna_storage(db: Any, writer: bool = True) -> Any:
    """Open nutribench's schema on ``db`` (``writer``: created or upgraded, else it must be there:
    :func:`nutribench.store.open_store`), then Optuna's RDB storage on the same URL, with
    heartbeats and stale-trial retry; None for a reader when the database holds no study."""
    import optuna
    from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback
    from sqlalchemy import inspect

    from nutribench.store.schema import open_store

    store = open_store(db, writer=writer)
    url = store.url.render_as_string(hide_password=False)
    with store.engine.connect() as conn:
        has_studies = inspect(conn).has_table("studies")
    store.dispose()
    if not writer and not has_studies:
        return None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError

    for attempt in range(10):
        try:
            with quiet_experimental():
                return RDBStorage(
                    url,
                    heartbeat_interval=max(1, round(HEARTBEAT_SECONDS)),
                    grace_period=max(2, round(GRACE_SECONDS)),
                    heartbeat_stale_trial_callback=RetryHeartbeatStaleTrialCallback(max_retry=3),
                )
        except (OperationalError, ProgrammingError, IntegrityError) as e:
            # two drivers starting on a new database: the other is creating Optuna's tables or
            # stamping their revision; once it has, this one finds them there
            if not isinstance(e, IntegrityError) and "already exists" not in str(e) or attempt == 9:
                raise
            time.sleep(0.2 * (attempt + 1))
        except RuntimeError as e:  # Optuna's schema newer or older than this Optuna
            raise TuneError(f"{store.display}: Optuna's tables: {' '.join(str(e).split())}") from None
    raise AssertionError("unreachable")


def make_sampler(settings: StudySettings, joining: bool = False) -> Any:
    """A seeded TPE sampler (the first ``startup_trials`` random, as Optuna's default).

    The driver that creates a study seeds it with ``sampler_seed``: a study run by one driver
    from start to end is reproducible. A driver that joins or resumes an existing study
    (``joining``) draws a seed of its own from ``sampler_seed``, its process and the clock:
    two drivers with one seed would draw the same random trials (found in the tuned grid's
    first studies: trials 0/1, 2/3 and 4/5 were pairs)."""
    import optuna

    seed = settings.sampler_seed
    if joining:
        seed = int(np.random.SeedSequence([seed, os.getpid(), time.time_ns()]).generate_state(1)[0])
    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=settings.startup_trials)


def make_pruner(settings: StudySettings) -> Any:
    """The median rule on the periodic validation evaluations, not before half the budget.

    Median, not successive halving: a study here has tens of trials, and halving's rungs would
    stop most of them on their first evaluations, when delayed-regime curves still cross
    (reports/sensitivity: PPO at 1e-3 looks as good as 3e-4 early and drifts later). No trial
    is pruned before half its days or before ``startup_trials`` trials have finished."""
    import optuna

    if settings.pruner == "none":
        return optuna.pruners.NopPruner()
    return optuna.pruners.MedianPruner(
        n_startup_trials=settings.startup_trials, n_warmup_steps=settings.days // 2, interval_steps=1
    )


def open_study(db: Any, name: str, settings: StudySettings | None) -> Any:
    """The study ``name`` in ``db``: created with ``settings`` if new; if it exists, its stored
    settings must equal ``settings`` (None: whatever it holds, for status and export)."""
    import optuna

    storage = optuna_storage(db, writer=settings is not None)
    names = set() if storage is None else {s.study_name for s in optuna.get_all_study_summaries(storage, False)}
    if name not in names:
        if settings is None:
            known = ", ".join(sorted(names)) or "(none)"
            raise TuneError(f"no tuning study {name!r} in this database: studies here are {known}")
        settings.check()
        try:
            study = optuna.create_study(
                study_name=name,
                storage=storage,
                sampler=make_sampler(settings),
                pruner=make_pruner(settings),
                direction="maximize",
            )
        except optuna.exceptions.DuplicatedStudyError:
            pass  # another driver created it a moment ago: resume it below
        else:
            study.set_user_attr(ATTR, settings.as_attr())
            return study
    stored = _settings_when_written(optuna.load_study(study_name=name, storage=storage))
    if settings is not None and stored != settings:
        diff = [
            f"{k} {getattr(stored, k)!r} (asked {getattr(settings, k)!r})"
            for k in stored.__dict__
            if getattr(stored, k) != getattr(settings, k)
        ]
        raise TuneError(
            f"study {name!r} was created with other settings: {'; '.join(diff)}; resume it with its own settings "
            "or name a new --study"
        )
    sampler = make_sampler(stored, joining=True)
    return optuna.load_study(study_name=name, storage=storage, sampler=sampler, pruner=make_pruner(stored))


def _settings_when_written(study: Any, wait_s: float = 10.0) -> StudySettings:
    """The study's settings; a study another driver has just created gets them a moment after
    its creation, so wait for them a little before calling it foreign."""
    end = time.monotonic() + wait_s
    while True:
        try:
            return stored_settings(study)
        except TuneError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)


def stored_settings(study: Any) -> StudySettings:
    """The settings a study was created with."""
    attr = study.user_attrs.get(ATTR)
    if not isinstance(attr, dict):
        raise TuneError(f"study {study.study_name!r} was not made by nutribench tune (no {ATTR!r} attribute)")
    return StudySettings(**{k: tuple(v) if isinstance(v, list) else v for k, v in attr.items()})


@dataclass
class StudyCounts:
    """How many trials of a study are in each state, and the best one."""

    name: str
    complete: int = 0
    pruned: int = 0
    running: int = 0
    failed: int = 0
    waiting: int = 0
    best_number: int | None = None
    best_value: float | None = None
    best_params: dict[str, Any] = field(default_factory=dict)
    settings: StudySettings | None = None

    @property
    def finished(self) -> int:
        return self.complete + self.pruned


def count_trials(study: Any) -> StudyCounts:
    """A study's trial counts by state and its best trial."""
    from optuna.trial import TrialState

    counts = StudyCounts(study.study_name)
    for t in study.get_trials(deepcopy=False):
        attr = {
            TrialState.COMPLETE: "complete",
            TrialState.PRUNED: "pruned",
            TrialState.RUNNING: "running",
            TrialState.FAIL: "failed",
            TrialState.WAITING: "waiting",
        }[t.state]
        setattr(counts, attr, getattr(counts, attr) + 1)
    if counts.complete:
        best = study.best_trial
        counts.best_number, counts.best_value, counts.best_params = best.number, best.value, dict(best.params)
    try:
        counts.settings = stored_settings(study)
    except TuneError:
        counts.settings = None
    return counts


def study_counts(db: Any, name: str | None = None) -> list[StudyCounts]:
    """Every study of ``db`` (or the one named) with its counts; [] when none."""
    import optuna

    storage = optuna_storage(db, writer=False)
    if storage is None:
        return []
    names = sorted(s.study_name for s in optuna.get_all_study_summaries(storage, include_best_trial=False))
    if name is not None:
        if name not in names:
            raise TuneError(
                f"no tuning study {name!r} in this database: studies here are {', '.join(names) or '(none)'}"
            )
        names = [name]
    return [count_trials(optuna.load_study(study_name=n, storage=storage)) for n in names]


def run_study(
    study: Any,
    objective: Callable[[Any], float],
    trials: int,
    on_trial: Callable[[StudyCounts], None] | None = None,
) -> StudyCounts:
    """Run trials of ``objective`` until ``study`` holds ``trials`` finished (complete or pruned)
    trials; other drivers on the same study share the work."""
    from optuna.study import MaxTrialsCallback
    from optuna.trial import TrialState

    if trials < 1:
        raise TuneError("--trials must be >= 1")
    counts = count_trials(study)
    missing = trials - counts.finished
    if missing <= 0:
        return counts
    stop = MaxTrialsCallback(trials, states=(TrialState.COMPLETE, TrialState.PRUNED))
    report: list[Callable[..., None]] = [] if on_trial is None else [lambda s, t: on_trial(count_trials(s))]
    # no n_trials: the callback stops this driver as soon as the study (all drivers) holds enough
    # finished trials; retried stale trials and failed ones do not count
    study.optimize(objective, n_trials=None, callbacks=[stop, *report], catch=())
    return count_trials(study)


def default_eval_every(days: int) -> int:
    """The evaluation period when none is given: the largest divisor of ``days`` up to a tenth of it."""
    return next(d for d in range(max(1, days // 10), 0, -1) if days % d == 0)


def parse_seeds(text: str | None) -> tuple[int, ...]:
    """``--seeds 101,102`` checked as ``nutribench run`` checks its seeds
    (:func:`nutribench.scheduler.grid.parse_seeds`: non-negative, in range, no repeats), as a
    tuple; the default tuning seeds for None or an empty text."""
    from nutribench.scheduler.grid import GridError
    from nutribench.scheduler.grid import parse_seeds as grid_seeds

    if text is None or not text.strip():
        return DEFAULT_TUNING_SEEDS
    try:
        return grid_seeds(text)
    except GridError as e:
        raise TuneError(str(e)) from None
