"""Greedy evaluation during training on the validation days
(:func:`~nutribench.agents.days.validation_food_streams`), the same in both engines.

Every ``eval_every`` training days, each agent's greedy policy plays its ``val_episodes``
validation days, as it stands when the day is over: its weights after every update that the
day's last step leads to (the policy that would play the next training day's first step),
and its observation statistics of that moment, frozen while it plays. It plays them in envs
of its own and draws no random number, so a run with and without the evaluation trains
identically; it is an evaluation of the same weights, on the same days, as a post-hoc
:func:`~nutribench.agents.api.evaluate` of the agent saved at that day.

Each evaluation gives one row per validation day: ``train_day`` (the training days played
before it, a multiple of ``eval_every``), ``episode`` (the validation day, 0-based), the
metrics of an evaluation row (:data:`~nutribench.env.metrics.METRIC_KEYS`) and ``entropy``;
the rows go to ``on_validation(agent_index, train_day, rows)`` (without ``train_day``) as
they are made, and an exception it raises (a tuner's ``optuna.TrialPruned``) stops the
training and propagates.

* :class:`Validator`: the bookkeeping both engines share (which days, the rows, the callback);
* :class:`ValidationCallback`: the SB3 engine's callback; the batched engine calls its
  validator at every day boundary (:mod:`nutribench.engine.evaluate`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

#: ``on_validation(agent_index, train_day, rows)``: one metrics dict per validation day
ValidationFn = Callable[[int, int, list[dict[str, Any]]], None]
#: validation days per evaluation unless told
DEFAULT_VAL_EPISODES = 5


def check_eval_every(eval_every: int | None, val_episodes: int) -> int:
    """``eval_every`` as a number of days (0: off); ValueError for a negative period or fewer
    than one validation day."""
    every = int(eval_every or 0)
    if every < 0:
        raise ValueError(f"eval_every must be >= 0 training days (0 or None: off), got {eval_every}")
    if every and int(val_episodes) < 1:
        raise ValueError(f"val_episodes must be >= 1, got {val_episodes}")
    return every


class Validator:
    """The evaluations of the agents ``0 .. k-1`` during training: which training days are
    due, their rows (:attr:`rows`, per agent) and the callback."""

    def __init__(self, every: int, k: int = 1, on_validation: ValidationFn | None = None):
        if every < 1:
            raise ValueError(f"a validator needs eval_every >= 1, got {every}")
        self.every, self.on_validation = every, on_validation
        #: per agent, one row per validation day of every evaluation so far
        self.rows: list[list[dict[str, Any]]] = [[] for _ in range(k)]

    @property
    def last_day(self) -> int:
        """The training day of the last evaluation (0: none yet)."""
        return max((r["train_day"] for rows in self.rows for r in rows[-1:]), default=0)

    def due(self, day: int) -> bool:
        """Whether the evaluation after ``day`` training days is due and not yet made."""
        return day > 0 and day % self.every == 0 and day > self.last_day

    def add(self, day: int, per_agent: list[list[dict[str, Any]]]) -> None:
        """Keep each agent's rows of the evaluation after ``day`` training days and hand them
        to the callback, agent by agent (its exception propagates)."""
        for j, rows in enumerate(per_agent):
            self.rows[j] += [{"train_day": day, **r} for r in rows]
        if self.on_validation is not None:
            for j, rows in enumerate(per_agent):
                self.on_validation(j, day, [dict(r) for r in rows])


ObsStats = tuple[np.ndarray | None, np.ndarray | None]


class ValidationCallback(BaseCallback):
    """The SB3 engine's evaluation during training (the module docstring): at the end of
    every ``validator.every``-th training day it freezes the observation statistics; it plays
    the validation days (``play(obs_mean, obs_var)`` -> one metrics dict per day) before the
    next action, i.e. at the next step if no update came between (on-policy: the rollout goes
    on; off-policy: the rollout goes on), else at the start of the next rollout, after the
    update, or at the end of training."""

    def __init__(self, validator: Validator, play: Callable[[np.ndarray | None, np.ndarray | None], list[dict]]):
        super().__init__()
        self.validator, self.play = validator, play
        self.days = 0
        self._pending: tuple[int, ObsStats] | None = None

    def _obs_stats(self) -> ObsStats:
        rms = getattr(self.model.get_env(), "obs_rms", None)
        if rms is None or not getattr(self.model.get_env(), "norm_obs", False):
            return None, None
        return rms.mean.copy(), rms.var.copy()

    def flush(self) -> None:
        """Play the evaluation that is due, if any."""
        if self._pending is not None:
            day, (mean, var) = self._pending
            self._pending = None
            self.validator.add(day, [self.play(mean, var)])

    def _on_step(self) -> bool:
        self.flush()  # a day ended at the previous step and no update came since
        if bool(np.asarray(self.locals["dones"])[0]):
            self.days += 1
            if self.validator.due(self.days):
                self._pending = (self.days, self._obs_stats())
        return True

    _on_rollout_start = _on_training_end = flush
