"""Many trials in one process: ``nutribench tune --stack N``.

The driver asks Optuna for up to N trials at once and groups them by structure: trials whose
configs agree on everything but the continuous settings (learning rate, discount, GAE
lambda, clip range, entropy and value coefficients, gradient-norm clip; SAC's learning rates,
alpha and tau) train in one batch,
each trial's agents (one per tuning regime and seed) with its own settings on the agent axis
(:attr:`nutribench.engine.algorithm.Algorithm.PER_AGENT`: PPO, MC, GRU-PPO and SAC).
Trials of another structure, and algorithms without per-agent settings (DDQN, plug-ins),
train in batches of their own, one trial each, as without ``--stack``.

Every evaluation is scored per trial exactly as a single trial is
(:class:`~nutribench.tuning.objective.ValidationObjective`): the IQM of its agents' shares of
the never -> planner gap on validation days, reported to Optuna at that day. A trial the
pruner stops is told PRUNED and its agents are frozen (no more updates); when every trial of
a batch is pruned, the batch stops. The trials of a batch keep a heartbeat while it trains, so
a driver killed with -9 leaves them to be failed and retried by the next driver, as single
trials are.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from nutribench.tuning.objective import TrialScores, ValidationObjective
from nutribench.tuning.study import StudyCounts, TuneError, count_trials, quiet_experimental

#: the fields of an agent config that name it, not what it trains
_NAMING = ("name", "version", "description")


class _AllPruned(Exception):
    """Every trial of a batch was pruned: stop training it."""


def per_agent_fields(cfg: Any) -> tuple[str, ...]:
    """The settings that may differ between stacked trials of ``cfg``'s algorithm (its batched
    class's :attr:`~nutribench.engine.algorithm.Algorithm.PER_AGENT`); () where the batched
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


@contextmanager
def heartbeats(study: Any, trials: list[Any]) -> Iterator[None]:
    """Keep the running ``trials``' heartbeats while the block runs (Optuna beats one trial of
    ``Study.optimize``; a batch of asked trials needs its own)."""
    storage = study._storage
    interval = storage.get_heartbeat_interval() if hasattr(storage, "get_heartbeat_interval") else None
    if not interval:
        yield
        return
    stop = threading.Event()

    def beat() -> None:
        while True:
            for t in trials:
                storage.record_heartbeat(t._trial_id)
            if stop.wait(interval):
                return

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


class StackedTrials:
    """Runs a study ``stack`` trials at a time (the module docstring)."""

    def __init__(self, objective: ValidationObjective, stack: int):
        if stack < 1:
            raise TuneError("--stack must be >= 1")
        self.objective, self.stack = objective, stack

    def run(self, study: Any, trials: int, on_trial: Callable[[StudyCounts], None] | None = None) -> StudyCounts:
        """Ask, train and tell batches of trials until ``study`` holds ``trials`` finished ones."""
        import optuna

        while True:
            with quiet_experimental():
                optuna.storages.fail_stale_trials(study)  # a killed driver's trials: failed, queued again
            counts = count_trials(study)
            missing = trials - counts.finished - counts.running
            if counts.finished >= trials or missing <= 0:
                return counts
            asked = self.ask(study, min(self.stack, missing))
            groups: dict[str, list[tuple[Any, Any]]] = {}
            for n, (trial, cfg) in enumerate(asked):
                key = structure_key(cfg)
                groups.setdefault(f"alone {n}" if key is None else key, []).append((trial, cfg))
            for group in groups.values():
                self.train_group(study, group)
                if on_trial is not None:
                    on_trial(count_trials(study))

    def ask(self, study: Any, n: int) -> list[tuple[Any, Any]]:
        """``n`` trials and their configs: the first as the sampler draws it; the others share its
        structural parameters (enqueued with them fixed, the sampler drawing the rest), so that
        the stack trains as one batch. A trial Optuna queued (a killed driver's, to retry) keeps
        its own parameters."""
        space = self.objective.space
        out: list[tuple[Any, Any]] = []
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Heartbeat of storage is supposed to be used")
            for i in range(n):
                trial = study.ask()
                out.append((trial, space.config(space.suggest(trial))))
                if i == 0 and n > 1 and structure_key(out[0][1]) is not None:
                    shared = per_agent_fields(out[0][1])
                    fixed = {k: v for k, v in trial.params.items() if k not in shared}
                    for _ in range(n - 1):
                        study.enqueue_trial(fixed, skip_if_exists=False)
        return out

    def train_group(self, study: Any, group: list[tuple[Any, Any]]) -> None:
        """Train the trials of one group in one batch and tell Optuna each one's outcome."""
        from optuna.trial import TrialState

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
        try:
            with heartbeats(study, trials):
                self.train(group, on_validation, active)
        except _AllPruned:
            pass
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
        obj, s = self.objective, self.objective.settings
        if len(group) == 1 and structure_key(group[0][1]) is None:
            obj.train(group[0][1], on_validation)  # as a single trial (SB3 engine, plug-in, off-policy)
            return
        from nutribench.engine.train import train_batched

        cfgs = [cfg for _, cfg in group for _ in obj.jobs]
        train_batched(
            obj.jobs * len(group),
            group[0][1],
            s.days,
            device=obj.device,
            eval_every=s.eval_every,
            val_episodes=s.val_episodes,
            on_validation=on_validation,
            agent_configs=cfgs,
            active=active,
        )
