"""The days an agent is scored on, apart from the days it trains on (its own stream):

* **test days** (:func:`eval_food_streams`): the fixed evaluation days of the paper's tables,
  drawn from the job seed alone, so every algorithm trained with a seed plays the same days;
* **validation days** (:func:`validation_food_streams`): the days of the evaluation during
  training and of tuning objectives, drawn from the job seed with a salt of their own, and
  never one of the seed's test days (any such day is drawn again), so that what the tables
  report never fed a choice.
"""

from __future__ import annotations

import numpy as np

from nutribench.config import EnvConfig, load_env_config

#: Mixed into the job seed to draw the evaluation days (independent of training's stream).
EVAL_STREAM_SALT = 20_240_501
#: Mixed into the job seed to draw the validation days.
VALIDATION_STREAM_SALT = 20_261_126
#: How many of a seed's test days the validation days are kept apart from (a job evaluates
#: on the first ``eval_episodes`` of them, 5 by default).
TEST_DAYS_KEPT_APART = 1000


def eval_food_streams(regime: str | EnvConfig, job_seed: int, n: int = 5) -> np.ndarray:
    """``n`` evaluation days ``(n, horizon)`` of food indices, drawn from the job seed alone,
    so every algorithm trained with that seed is evaluated on the same days (paired)."""
    cfg = load_env_config(regime)
    rng = np.random.default_rng([EVAL_STREAM_SALT, int(job_seed)])
    return rng.integers(0, len(cfg.catalog.food), size=(n, cfg.reward.horizon))


def validation_food_streams(
    regime: str | EnvConfig, job_seed: int, n: int = 5, test_days: int = TEST_DAYS_KEPT_APART
) -> np.ndarray:
    """``n`` validation days ``(n, horizon)`` of food indices for ``(regime, job_seed)``: the
    same for every algorithm trained with that seed, none of them one of the seed's first
    ``test_days`` test days (:func:`eval_food_streams`) nor another validation day: such a
    day is drawn again from the same stream, so the first ``m`` days of ``n > m`` are the
    ``m`` days asked for alone."""
    cfg = load_env_config(regime)
    n_foods, horizon = len(cfg.catalog.food), cfg.reward.horizon
    taken = {day.tobytes() for day in eval_food_streams(cfg, job_seed, test_days)}
    rng = np.random.default_rng([VALIDATION_STREAM_SALT, int(job_seed)])
    days = np.empty((n, horizon), dtype=np.int64)
    for i in range(n):
        day = rng.integers(0, n_foods, size=horizon)
        while day.tobytes() in taken:
            day = rng.integers(0, n_foods, size=horizon)
        taken.add(day.tobytes())
        days[i] = day
    return days
