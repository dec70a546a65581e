"""The tuning objective: how good one trial's agent config is, on validation days only.

A trial trains one agent of its config per (tuning regime, tuning seed) for the study's days,
all at once in the batched engine (K = regimes x seeds agents; a config the batched engine
does not train, a plug-in's, trains job by job with the SB3 engine). Every ``eval_every``
days each agent's greedy policy plays its seed's validation days (never the test days the
tables report); its mean return there becomes its share of the never -> planner gap on those
same days, ``(R - R_never) / (R_planner - R_never)``. The trial's value at that day is the
interquartile mean (IQM) of the K shares; Optuna's pruner reads it at every evaluation. The
trial's objective is, as the study's ``objective`` setting says, its value at the last day
(``last``) or the mean of its values at the evaluations after half its days (``late-mean``:
a setting that learns slowly and ends well is not ranked below one that starts fast and
stops, and one lucky last evaluation weighs less). Each agent's final share is kept as the
trial's user attribute ``shares`` (``"<regime>/<seed>"`` -> share).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from nutribench.baselines import gap_closed
from nutribench.engines import Engine
from nutribench.stats import iqm
from nutribench.tuning.space import SearchSpace
from nutribench.tuning.study import StudySettings


class ValidationObjective:
    """``objective(trial) -> float`` for :func:`~nutribench.tuning.stack.run_study` (module docstring)."""

    def __init__(
        self,
        space: SearchSpace,
        settings: StudySettings,
        device: str = "cpu",
        on_evaluation: Callable[[int, int, float], None] | None = None,
    ):
        self.space, self.settings, self.device, self.on_evaluation = space, settings, device, on_evaluation
        self.jobs = [(r, s) for r in settings.regimes for s in settings.seeds]
        #: ``on_day(day, job)``: a trial's training reached ``day`` (its agents train in step in a
        #: batch: ``job`` None; one after another with SB3 or a plug-in's loop: the 0-based job)
        self.on_day: Callable[[int, int | None], None] | None = None
        self._references: dict[tuple[str, int], tuple[float, float]] = {}

    def references(self, regime: str, seed: int) -> tuple[float, float]:
        """Never eating's and the greedy planner's mean return on the validation days of (regime, seed)."""
        from nutribench.baselines import validation_yardsticks

        key = (regime, seed)
        if key not in self._references:
            yard = validation_yardsticks(regime, seed, self.settings.val_episodes)
            self._references[key] = (yard["never"], yard["planner"])
        return self._references[key]

    def __call__(self, trial: Any) -> float:
        import optuna

        cfg = self.space.config(self.space.suggest(trial))
        scores = TrialScores(self, trial)

        def on_validation(j: int, day: int, rows: list[dict[str, Any]]) -> None:
            value = scores.add(j, day, rows)
            if value is not None and scores.prune(day):
                raise optuna.TrialPruned(f"pruned at day {day}: IQM share {value:.3f}")

        self.record_engine(trial, cfg)
        self.train(cfg, on_validation)
        return scores.final()

    def record_engine(self, trial: Any, cfg: Any) -> None:
        """Which engine and device train ``trial`` (its user attributes)."""
        engine = self.engine(cfg)
        trial.set_user_attr("engine", engine)
        trial.set_user_attr("device", self.device if engine == Engine.BATCHED else "cpu")

    @staticmethod
    def engine(cfg: Any) -> str:
        """Which engine trains ``cfg``'s trials: the batched one where it trains the config as
        the SB3 engine would, else SB3 (a plug-in: its own loop)."""
        from nutribench.engine import supports

        return Engine.BATCHED.value if supports(cfg) is None else Engine.SB3.value

    def batch_days(self, job: int | None = None) -> Callable[[int, dict[str, Any]], None] | None:
        """The batched engine's ``on_episode``: :attr:`on_day` each time the batch's furthest
        agent ends a day (a batch's agents end their days together, a pruned trial's stop),
        telling it ``job`` (None: a batch; a job trained alone, :meth:`job_days`)."""
        if self.on_day is None:
            return None
        on_day, days, reached = self.on_day, {}, [0]

        def on_episode(j: int, _metrics: dict[str, Any]) -> None:
            days[j] = days.get(j, 0) + 1
            if days[j] > reached[0]:
                reached[0] = days[j]
                on_day(reached[0], job)

        return on_episode

    def train(self, cfg: Any, on_validation: Callable[[int, int, list[dict[str, Any]]], None]) -> None:
        """Train the trial's K agents with evaluations during training (batched when supported)."""
        s = self.settings
        if self.engine(cfg) == Engine.BATCHED:
            self.train_batch(self.jobs, cfg, on_validation)
            return
        from nutribench.agents.api import evaluate, train
        from nutribench.agents.days import validation_food_streams
        from nutribench.agents.registry import by_entry_point

        for j, (regime, seed) in enumerate(self.jobs):
            # a plug-in's own loop (algo "external"): its final agent is evaluated, nothing to prune on
            if by_entry_point(cfg.algo):
                agent = train(regime, cfg, seed, s.days, on_episode=self.job_days(j))
                days = validation_food_streams(regime, seed, s.val_episodes)
                on_validation(j, s.days, evaluate(agent, regime, days, record_steps=False).episodes)
                continue
            train(
                regime,
                cfg,
                seed,
                s.days,
                eval_every=s.eval_every,
                val_episodes=s.val_episodes,
                on_validation=lambda _, day, rows, j=j: on_validation(j, day, rows),
                on_episode=self.job_days(j),
            )

    def train_batch(
        self, jobs: list[tuple[str, int]], cfg: Any, on_validation: Callable[..., None], **extra: Any
    ) -> None:
        """``jobs`` trained at once by the batched engine from ``cfg`` (``extra``: more of
        :func:`~nutribench.engine.train.train_batched`'s arguments, a stack's configs per agent),
        evaluated every ``eval_every`` days."""
        from nutribench.engine.train import train_batched

        s = self.settings
        train_batched(
            jobs,
            cfg,
            s.days,
            device=self.device,
            eval_every=s.eval_every,
            val_episodes=s.val_episodes,
            on_validation=on_validation,
            on_episode=self.batch_days(),
            return_agents=False,  # the score is the validation rows: no SB3 model built
            **extra,
        )

    def job_days(self, j: int) -> Callable[[dict[str, Any]], None] | None:
        """The SB3 engine's ``on_episode`` for job ``j`` (trained alone): :attr:`on_day` at each day."""
        count = self.batch_days(j)  # one job: each of its days is the furthest
        return None if count is None else lambda metrics: count(j, metrics)


class TrialScores:
    """One trial's scores: per evaluation day, each agent's share of the gap on its validation
    days, the IQM reported to Optuna once every agent of the day is in (the module docstring)."""

    def __init__(self, objective: ValidationObjective, trial: Any):
        self.objective, self.trial = objective, trial
        self.shares: dict[int, dict[int, float]] = {}  # day -> agent (its index in objective.jobs) -> share

    def add(self, job: int, day: int, rows: list[dict[str, Any]]) -> float | None:
        """Agent ``job``'s evaluation after ``day`` days; the trial's value at that day (reported
        to Optuna and to ``on_evaluation``) once every agent's is in, else None."""
        obj = self.objective
        never, planner = obj.references(*obj.jobs[job])
        per_day = self.shares.setdefault(day, {})
        per_day[job] = gap_closed(float(np.mean([r["return"] for r in rows])), never, planner)
        if len(per_day) < len(obj.jobs):
            return None
        value = iqm(np.array(list(per_day.values())))
        self.trial.report(value, day)
        if obj.on_evaluation is not None:
            obj.on_evaluation(self.trial.number, day, value)
        return value

    def prune(self, day: int) -> bool:
        """Whether the pruner stops the trial after ``day`` (never at its last day)."""
        return day < self.objective.settings.days and self.trial.should_prune()

    def final(self) -> float:
        """The trial's objective (the module docstring): the IQM of its agents' shares at the
        last day, or the mean of those IQMs over the evaluations after half its days; each
        agent's last share kept as the user attribute ``shares``. RuntimeError if an agent was
        not evaluated on a day the objective reads."""
        obj, settings = self.objective, self.objective.settings
        days = [settings.days]
        if settings.objective == "late-mean":
            days = [
                d for d in range(settings.eval_every, settings.days + 1, settings.eval_every) if 2 * d > settings.days
            ]
        values = [self._value(d) for d in days]
        last = self.shares[settings.days]
        self.trial.set_user_attr("shares", {f"{r}/{s}": last[j] for j, (r, s) in enumerate(obj.jobs)})
        return float(np.mean(values))

    def _value(self, day: int) -> float:
        """The IQM of the agents' shares at ``day``, every agent evaluated then."""
        per_day, n = self.shares.get(day, {}), len(self.objective.jobs)
        if len(per_day) != n:
            raise RuntimeError(f"trial {self.trial.number}: {len(per_day)} of {n} agents evaluated at day {day}")
        return iqm(np.array(list(per_day.values())))
