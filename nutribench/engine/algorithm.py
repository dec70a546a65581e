"""What every batched algorithm is: :class:`Algorithm`, the interface the training loops
(:mod:`nutribench.engine.on_policy`, :mod:`nutribench.engine.off_policy`) call and each
algorithm module implements (:mod:`~nutribench.engine.mc`, :mod:`~nutribench.engine.ppo`,
:mod:`~nutribench.engine.gru_ppo`, :mod:`~nutribench.engine.ddqn`, :mod:`~nutribench.engine.sac`),
as SB3's ``BaseAlgorithm`` is for its algorithms; :func:`~nutribench.engine.train.train_batched`
picks the class by the config's ``algo`` in one lookup.

An algorithm is made for one agent config and one batch of envs (:class:`~nutribench.engine.envs.AgentEnvs`,
K agents); :meth:`Algorithm.learn` trains it for a number of env steps (resuming from a
checkpoint when it holds a state), and each agent is then handed back with
:meth:`Algorithm.store_weights`. While it learns, an algorithm records each agent's
per-update diagnostics (:attr:`Algorithm.diagnostics`, the vocabulary of
:mod:`nutribench.diagnostics`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np
import torch as th

from nutribench import diagnostics as names
from nutribench.agents.api import TrainedAgent
from nutribench.agents.validation import DEFAULT_VAL_EPISODES, ValidationFn, check_eval_every
from nutribench.config import EnvConfig, load_env_config
from nutribench.engine import check_supported
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.device import resolve_device
from nutribench.engine.envs import AgentEnvs, AgentEpisodeFn, as_trained_agent
from nutribench.engine.evaluate import BatchValidator, Greedy
from nutribench.engine.stacked import RunningStats


class Algorithm:
    """K agents of one algorithm and agent config, trained together on ``envs``.

    Subclasses set :attr:`algo` (the ``algo`` of the agent configs they train) and implement
    :meth:`learn` (through a loop's base class) and :meth:`store_weights`."""

    #: the agent configs' ``algo`` this class trains
    algo: ClassVar[str]

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device):
        self.cfg, self.envs, self.device, self.k = cfg, envs, device, envs.k
        #: per agent, one dict per update (on-policy: rollout; off-policy: training day), keys
        #: from :mod:`nutribench.diagnostics`
        self.diagnostics: list[list[dict[str, float]]] = [[] for _ in range(envs.k)]
        #: on-policy: called before each update with the rollout's arrays (``train_batched``'s ``on_rollout``)
        self.on_rollout: Callable[[dict[str, np.ndarray]], None] | None = None
        #: off-policy: called after each gradient step with its step count and losses (``on_update``)
        self.on_update: Callable[[dict[str, Any]], None] | None = None
        #: the evaluations during training (``train_batched``'s ``eval_every``), None: none
        self.validator: BatchValidator | None = None

    @classmethod
    def train(
        cls,
        jobs: Sequence[tuple[str | EnvConfig, int]],
        cfg: Any,
        episodes: int,
        on_episode: AgentEpisodeFn | None = None,
        checkpoint: Checkpoint | None = None,
        device: str | th.device = "cpu",
        on_rollout: Callable[[dict[str, np.ndarray]], None] | None = None,
        on_update: Callable[[dict[str, Any]], None] | None = None,
        eval_every: int | None = None,
        val_episodes: int = DEFAULT_VAL_EPISODES,
        on_validation: ValidationFn | None = None,
    ) -> list[TrainedAgent]:
        """Train one agent of ``cfg`` (a config of this algorithm) per ``(regime, seed)`` of
        ``jobs`` for ``episodes`` days, all at once, and hand each back with its diagnostics
        (:func:`~nutribench.engine.train.train_batched` says what the arguments do)."""
        check_supported(cfg, load_env_config(jobs[0][0]).reward.horizon if jobs else None)  # before anything trains
        device = resolve_device(device)
        every = check_eval_every(eval_every, val_episodes)
        envs = AgentEnvs(jobs, cfg.normalize_obs, on_episode)
        algorithm = cls(cfg, envs, device)
        algorithm.on_rollout, algorithm.on_update = on_rollout, on_update
        if every:
            algorithm.validator = BatchValidator(envs, every, val_episodes, on_validation)
        wall = algorithm.learn(episodes * envs.horizon, checkpoint)
        algorithm.day_boundary(episodes * envs.horizon)  # the evaluation after the last day
        return algorithm.trained_agents(episodes, wall)

    def trained_agents(self, episodes: int, wall: float) -> list[TrainedAgent]:
        """Each agent as the SB3 engine's :class:`~nutribench.agents.api.TrainedAgent` of its
        config (:func:`~nutribench.engine.envs.as_trained_agent`), with its ``diagnostics``."""
        agents = []
        for j in range(self.k):
            agent = as_trained_agent(
                self.envs,
                j,
                self.cfg,
                episodes,
                lambda model, j=j: self.store_weights(j, model),
                self.return_stats,
                wall / self.k,
                str(self.device),
            )
            agent.diagnostics = self.diagnostics[j]
            agent.validation = self.envs.validation[j]
            agents.append(agent)
        return agents

    def learn(self, total_steps: int, checkpoint: Checkpoint | None = None) -> float:
        """Train for ``total_steps`` env steps of each agent (from ``checkpoint``'s state if it
        holds one, saving to it when due); the wall seconds, those before a resume included."""
        raise NotImplementedError

    def store_weights(self, j: int, model: Any) -> None:
        """Put agent ``j``'s trained weights into ``model``, the SB3 model of its config."""
        raise NotImplementedError

    def greedy(self) -> Greedy:
        """A fresh greedy player of the K agents' current policies for days played side by
        side (:data:`nutribench.engine.evaluate.Greedy`; a recurrent one starts each day from
        the zero state), as the SB3 model of each agent acts with ``deterministic=True``."""
        raise NotImplementedError

    def day_boundary(self, steps: int) -> None:
        """The loops call this before every env step (``steps`` taken so far by each agent):
        after a day's end, the evaluation during training that is due (:attr:`validator`)."""
        if self.validator is not None:
            self.validator.at(steps, self.greedy, self.device)

    @property
    def return_stats(self) -> RunningStats | None:
        """The agents' running statistics of the discounted return (reward scaling), if any."""
        return None

    def record(self, timestep: int, values: dict[str, Any]) -> None:
        """Append one diagnostics dict to each agent's list: ``update`` (its index), ``timestep``
        (env steps of each agent so far) and ``values``: per name, K floats (a list or array:
        agent ``j`` gets the ``j``-th) or one float (every agent gets it)."""
        update = len(self.diagnostics[0])
        shared = {n: float(v) for n, v in values.items() if np.ndim(v) == 0}
        columns = {n: np.asarray(v, dtype=np.float64).tolist() for n, v in values.items() if n not in shared}
        for j in range(self.k):
            row: dict[str, float] = {names.UPDATE: update, names.TIMESTEP: timestep}
            row.update({n: v[j] for n, v in columns.items()})
            row.update(shared)
            self.diagnostics[j].append(row)
