"""The sampler and pruner of a tuning study, made from its stored settings
(:class:`~nutribench.tuning.study.StudySettings`): what a study fixes when it is created is
what every driver that resumes it uses."""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np
import optuna


def make_sampler(settings: Any, joining: bool = False) -> Any:
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
        constant_liar=bool(getattr(settings, "constant_liar", False)),
    )


def make_pruner(settings: Any) -> Any:
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
