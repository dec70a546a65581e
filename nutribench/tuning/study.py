"""Tuning studies: Optuna studies in the results database, resumable, shared by drivers.

A study lives in the same database as the results (SQLite file or any SQLAlchemy URL), in
Optuna's own tables beside nutribench's (:mod:`nutribench.store.schema` says how the two
schema chains keep apart). nutribench's schema is opened (created, upgraded) first, then
Optuna's RDB storage on the same URL.

A study is fixed when it is created: its search space (name, version, content hash), tuning
regimes and seeds, training days per trial, evaluation period, validation days, sampler seed
and pruner are stored as the study's user attribute ``nutribench``; resuming it with other
settings is refused in one line. The space's file (its path and its text) is kept too, as the
user attribute ``nutribench_space``, so that ``tune best`` finds a plug-in's space given by
path, even moved (:func:`nutribench.tuning.export.study_space`).

``trials`` counts finished trials (complete or pruned); how drivers claim, run and retry trials
(stopping at that count exactly, a killed driver's trial failed and run again) is
:mod:`nutribench.tuning.stack`'s. The heartbeat's interval and grace period are
:func:`heartbeat_settings`. The sampler and pruner are made from the stored settings
(:func:`make_sampler`, :func:`make_pruner`): what a study fixes when it is created is what
every driver that resumes it uses.
"""

from __future__ import annotations

import os
import time
import warnings
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import optuna
from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback
from optuna.trial import TrialState
from sqlalchemy import inspect
from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError

from nutribench.errors import UserError

#: seeds the project reports results on (the paper's); a tuning study may not tune on them
REPORTED_SEEDS: tuple[int, ...] = (0, 21, 9, 2003, 1997)
#: the tuning seeds a study uses when none are given (fresh: no study reports on them)
DEFAULT_TUNING_SEEDS: tuple[int, ...] = (101, 102, 103)
#: Optuna heartbeat: seconds between a running trial's beats, and how long without one makes it
#: stale (a killed driver's trial is failed and retried then): :func:`heartbeat_settings`
HEARTBEAT_SECONDS = 30
GRACE_SECONDS = 120
#: the attribute holding the study's fixed settings
ATTR = "nutribench"
#: the attribute holding the search space's file: {"path": absolute path, "toml": its text}
SPACE_ATTR = "nutribench_space"
#: the longest --days: 100 times the paper's 1000-day budget per agent
MAX_DAYS = 100_000
#: the most --val-episodes: validation days are played side by side, one environment each
#: (as ``nutribench agents evaluate --episodes``: :data:`nutribench.scheduler.grid.MAX_EVAL_DAYS`)
MAX_VAL_EPISODES = 10_000
#: the largest --sampler-seed: numpy's seeds (TPE's) are 0 .. 2**32 - 1
MAX_SAMPLER_SEED = 2**32 - 1
#: the longest study name: Optuna's ``studies.study_name`` column is VARCHAR(512)
MAX_STUDY_NAME = 512
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
    constant_liar: bool = False  # one made before it drew its stacked trials without (make_sampler)

    def as_attr(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.__dict__.items()}

    def check(self) -> None:
        """Refuse settings a study cannot run on (one line each)."""
        if not self.regimes:
            raise TuneError("--regimes: name at least one regime")
        twice = sorted({r for r in self.regimes if self.regimes.count(r) > 1})
        if twice:
            raise TuneError(f"--regimes: {', '.join(twice)} given twice: name each tuning regime once")
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
        if self.days > MAX_DAYS:
            raise TuneError(
                f"--days {str(self.days)[:24]}: give at most {MAX_DAYS} (100 times the paper's 1000 days per agent)"
            )
        if self.val_episodes > MAX_VAL_EPISODES:
            raise TuneError(
                f"--val-episodes {str(self.val_episodes)[:24]}: give at most {MAX_VAL_EPISODES} (the validation days "
                "are played side by side, one environment each)"
            )
        if not 0 <= self.sampler_seed <= MAX_SAMPLER_SEED:
            raise TuneError(
                f"--sampler-seed {str(self.sampler_seed)[:24]}: give a seed from 0 to {MAX_SAMPLER_SEED} "
                "(numpy's seeds, which TPE draws from)"
            )
        if self.days % self.eval_every:
            raise TuneError(
                f"--days ({self.days}) must be a multiple of --eval-every ({self.eval_every}): a trial's value is "
                "its evaluation at the last day"
            )
        if self.startup_trials < 1:
            raise TuneError("--startup-trials must be >= 1 (the random trials TPE starts from)")
        for option, value, known in (("--pruner", self.pruner, PRUNERS), ("--objective", self.objective, OBJECTIVES)):
            if value not in known:
                raise TuneError(f"{option}: {value!r} is not one of {', '.join(known)}")
        if self.objective == "late-mean" and self.days // self.eval_every < 2:
            raise TuneError("--objective late-mean needs two evaluations or more: lower --eval-every")


def make_sampler(settings: StudySettings, joining: bool = False) -> Any:
    """A seeded TPE sampler (the first ``startup_trials`` random, as Optuna's default), with
    Optuna's constant liar where the study's settings ask for it (every study made since the
    setting exists): a trial still running counts as a bad one while the next is drawn, so the
    N trials of a stack (asked at once, all running) spread out instead of crowding the same
    good region (Optuna's advice for batch and parallel optimisation). Not multivariate: the
    protocols' studies were all drawn by independent TPE, and a sampler switched between them
    would confound their comparison; ``multivariate`` is Optuna's to try in a study of one's own.

    The driver that creates a study seeds it with ``sampler_seed``: a study run by one driver
    from start to end is reproducible. A driver that joins or resumes an existing study
    (``joining``) draws a seed of its own from ``sampler_seed``, its process and the clock:
    two drivers with one seed would draw the same random trials (found in the tuned grid's
    first studies: trials 0/1, 2/3 and 4/5 were pairs)."""
    seed = settings.sampler_seed
    if joining:
        seed = int(np.random.SeedSequence([seed, os.getpid(), time.time_ns()]).generate_state(1)[0])
    return optuna.samplers.TPESampler(
        seed=seed,
        n_startup_trials=settings.startup_trials,
        constant_liar=settings.constant_liar,
    )


def make_pruner(settings: StudySettings) -> Any:
    """The median rule on the periodic validation evaluations, not before half the budget.

    Median, not successive halving: a study here has tens of trials, and halving's rungs would
    stop most of them on their first evaluations, when delayed-regime curves still cross
    (reports/sensitivity: PPO at 1e-3 looks as good as 3e-4 early and drifts later). No trial
    is pruned before half its days or before ``startup_trials`` trials have finished."""
    if settings.pruner == "none":
        return optuna.pruners.NopPruner()
    return optuna.pruners.MedianPruner(
        n_startup_trials=settings.startup_trials, n_warmup_steps=settings.days // 2, interval_steps=1
    )


def quiet_experimental() -> warnings.catch_warnings[None]:
    """Optuna's ``ExperimentalWarning`` silenced while the block runs, the caller's warnings
    filters restored afterwards: the heartbeat and the stale-trial retry are marked
    experimental since Optuna 2.8; their behaviour here is tested."""
    return warnings.catch_warnings(action="ignore", category=optuna.exceptions.ExperimentalWarning)


@contextmanager
def quiet_optuna() -> Iterator[None]:
    """Optuna's log at ``WARNING`` while the block runs (no "A new study created" line among
    the command's own), its verbosity as the caller had it afterwards, an exception or not: a
    library does not change its caller's process. Used as a decorator too (``@quiet_optuna()``)."""
    verbosity = optuna.logging.get_verbosity()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        yield
    finally:
        optuna.logging.set_verbosity(verbosity)


def heartbeat_settings() -> tuple[int, int]:
    """(seconds between heartbeats, grace period in seconds): ``NUTRIBENCH_TUNE_HEARTBEAT`` and
    ``NUTRIBENCH_TUNE_GRACE`` where set, else :data:`HEARTBEAT_SECONDS` and :data:`GRACE_SECONDS`;
    the grace period is longer than the interval (a live trial is never stale)."""
    out = []
    for var, default in (("NUTRIBENCH_TUNE_HEARTBEAT", HEARTBEAT_SECONDS), ("NUTRIBENCH_TUNE_GRACE", GRACE_SECONDS)):
        text = os.environ.get(var, "").strip() or str(default)
        value = float(text) if text.replace(".", "", 1).isdigit() else float("nan")
        if not 1 <= value <= 86_400:
            raise TuneError(f"{var}={text[:24]!r}: give whole seconds from 1 to 86400")
        out.append(round(value))
    interval, grace = out
    return interval, max(grace, interval + 1)


def optuna_storage(db: Any, writer: bool = True) -> Any:
    """Open nutribench's schema on ``db`` (``writer``: created or upgraded, else it must be there:
    :func:`nutribench.store.open_store`), then Optuna's RDB storage on the same URL, with
    heartbeats and stale-trial retry; None for a reader when the database holds no study."""
    from nutribench.store.schema import open_store

    interval, grace = heartbeat_settings()  # a bad setting refused before anything is opened
    store = open_store(db, writer=writer)
    url = store.url.render_as_string(hide_password=False)
    with store.engine.connect() as conn:
        has_studies = inspect(conn).has_table("studies")
    store.dispose()
    if not writer and not has_studies:
        return None

    for attempt in range(10):
        try:
            with quiet_experimental(), quiet_optuna():
                return RDBStorage(
                    url,
                    heartbeat_interval=interval,
                    grace_period=grace,
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


def check_study_name(name: str) -> None:
    """A study name Optuna can store: not empty, at most :data:`MAX_STUDY_NAME` characters
    (its column's width), no control characters (one line)."""
    if not name.strip():
        raise TuneError("--study: give the study a name (it is empty)")
    if len(name) > MAX_STUDY_NAME:
        raise TuneError(
            f"--study {name[:40]!r}... ({len(name)} characters): give at most {MAX_STUDY_NAME} "
            "(Optuna's study_name column)"
        )
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise TuneError(f"--study {name[:40]!r}: a name without control characters (tabs, new lines)")


@quiet_optuna()
def open_study(
    db: Any, name: str, settings: StudySettings | None, space_file: dict[str, str] | None = None, once: bool = False
) -> Any:
    """The study ``name`` in ``db``: created with ``settings`` if new; if it exists, its stored
    settings must equal ``settings`` (None: whatever it holds, for status and export).
    ``once``: a plug-in's study (:func:`scored_once`): one made before its settings said so
    (an ``eval_every`` and ``pruner`` that never applied) resumes with what it holds.
    ``space_file`` (``{"path": ..., "toml": ...}``: :func:`nutribench.tuning.export.space_file_attr`)
    is kept with the study (a study made before it was kept gets it on its next resume)."""
    if settings is not None:
        check_study_name(name)
    storage = optuna_storage(db, writer=settings is not None)
    names = study_names(storage)
    if name not in names:
        if settings is None:
            raise no_such_study(name, names)
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
            if space_file is not None:
                study.set_user_attr(SPACE_ATTR, space_file)
            study.set_user_attr(ATTR, settings.as_attr())
            return study
    stored = _settings_when_written(optuna.load_study(study_name=name, storage=storage))
    if settings is not None:  # a study resumes with the sampler it was made with (and a plug-in's as it was)
        kept = ("constant_liar", "eval_every", "pruner") if once else ("constant_liar",)
        settings = replace(settings, **{k: getattr(stored, k) for k in kept})
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
    study = optuna.load_study(study_name=name, storage=storage, sampler=sampler, pruner=make_pruner(stored))
    if space_file is not None and SPACE_ATTR not in study.user_attrs:
        study.set_user_attr(SPACE_ATTR, space_file)
    return study


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
    n = Counter(t.state for t in study.get_trials(deepcopy=False))
    states = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.RUNNING, TrialState.FAIL, TrialState.WAITING)
    counts = StudyCounts(study.study_name, *(n[state] for state in states))
    if counts.complete:
        best = study.best_trial
        counts.best_number, counts.best_value, counts.best_params = best.number, best.value, dict(best.params)
    with suppress(TuneError):  # a study not made by nutribench tune: no settings
        counts.settings = stored_settings(study)
    return counts


@quiet_optuna()
def study_counts(db: Any, name: str | None = None) -> list[StudyCounts]:
    """Every study of ``db`` (or the one named) with its counts; [] when none."""
    storage = optuna_storage(db, writer=False)
    if storage is None:
        return []
    names = study_names(storage)
    if name is not None:
        if name not in names:
            raise no_such_study(name, names)
        names = [name]
    return [count_trials(optuna.load_study(study_name=n, storage=storage)) for n in names]


def study_names(storage: Any) -> list[str]:
    """The names of the studies in ``storage`` (None: no study table), sorted."""
    return [] if storage is None else sorted(s.study_name for s in optuna.get_all_study_summaries(storage, False))


def no_such_study(name: str, names: list[str]) -> TuneError:
    """The one line for a study ``name`` not among ``names``."""
    return TuneError(f"no tuning study {name!r} in this database: studies here are {', '.join(names) or '(none)'}")


def scored_once(settings: StudySettings) -> StudySettings:
    """The settings of a plug-in's study (``algo = "external"``: its own loop trains each agent
    and only the final agent is scored, :mod:`nutribench.tuning.objective`), as they apply:
    one evaluation, after the last day (``eval_every = days``), and no pruner (a trial with
    one value has nothing to be pruned on). :class:`TuneError` for ``late-mean``, which needs
    two evaluations."""
    if settings.objective == "late-mean":
        raise TuneError(
            "--objective late-mean: a plug-in's trials are scored once, after their last day; use --objective last"
        )
    return replace(settings, eval_every=settings.days, pruner="none")


def default_eval_every(days: int) -> int:
    """The evaluation period when none is given: the largest divisor of ``days`` up to a tenth of
    it (1 for days beyond :data:`MAX_DAYS`, which :meth:`StudySettings.check` refuses)."""
    if not 1 <= days <= MAX_DAYS:
        return 1
    return next(d for d in range(max(1, days // 10), 0, -1) if days % d == 0)


def tuning_seeds(text: str | None) -> tuple[int, ...]:
    """``--seeds 101,102`` checked as ``nutribench run`` checks its seeds
    (:func:`nutribench.scheduler.grid.parse_seeds`: non-negative, in range, no repeats), as a
    tuple; the default tuning seeds for None or an empty text."""
    from nutribench.scheduler.grid import GridError, parse_seeds

    if text is None or not text.strip():
        return DEFAULT_TUNING_SEEDS
    try:
        return parse_seeds(text)
    except GridError as e:
        raise TuneError(str(e)) from None
