"""Train K agents of one agent config at once (regimes and seeds may differ), and hand each
back as the :class:`~nutribench.agents.api.TrainedAgent` the SB3 engine would give: the SB3
model of its config (``PPO``, ``MonteCarloAC``, ``DoubleDQN``, ``DiscreteSAC`` or
``GRUPPO``) with the trained weights, its ``VecNormalize`` statistics, its training days'
metrics, and its per-update diagnostics (``agent.diagnostics``). Evaluation, saving and
loading are then the single-agent API's.

Each algorithm is a class (:class:`~nutribench.engine.algorithm.BatchedAlgorithm`) in its own
module: :class:`~nutribench.engine.mc.BatchedMC`, :class:`~nutribench.engine.ppo.BatchedPPO`,
:class:`~nutribench.engine.gru_ppo.BatchedGRUPPO` on the on-policy loop
(:mod:`nutribench.engine.on_policy`), :class:`~nutribench.engine.ddqn.BatchedDDQN` and
:class:`~nutribench.engine.sac.BatchedSAC` on the off-policy loop
(:mod:`nutribench.engine.off_policy`); a config's ``algo`` names its class in the algorithm
registry (:func:`nutribench.agents.registry.batched_class`).

Randomness is per agent and comes from its job seed alone (its food days, its action draws,
its minibatch order, its initial weights), so an agent's run does not depend on which
others share its batch: on the CPU it is the same bit for bit alone or in any batch (the
kernels whose rounding depended on K are avoided: docs/batched-engine.md, "Reproducibility").
It is not SB3's random stream: the two engines' runs with one seed differ as two seeds do;
``python benchmarks/engines.py`` compares them as distributions.

Every engine entry point takes a ``device`` (:mod:`nutribench.engine.device`; default the
CPU). The networks, optimiser states, GRU states and each update's tensors live there; the
envs, replay buffers, running statistics and random streams stay on the CPU (numpy, and CPU
generators for the initial weights, which are drawn on the CPU and then moved), so an
agent's random draws are the same on every device; what it does with them differs by float
rounding from one device to another.

The options of :func:`train_batched`. Each agent comes back with ``diagnostics``: one dict per update (on-policy: per rollout;
off-policy: per training day with gradient steps, the means over them), keyed by
:mod:`nutribench.diagnostics`' names; a batch resumed from a checkpoint returns them all,
those of the run before the stop included.

* ``on_episode``: called with (job index, the finished day's metrics) for every day.
* ``on_rollout``: (on-policy) called before each update with the rollout's arrays (agent axis
  first): ``obs`` (as the policy saw them), ``actions``, ``rewards`` (as the update sees
  them), ``starts``, ``values``, ``advantages``, ``returns``, and ``foods`` (every day drawn
  so far, ``(days, K, horizon)``); for tests that replay it through SB3 (PPO, MC, GRU-PPO).
* ``on_update``: (off-policy) called after each update with ``steps`` (env steps so far) and
  what the update gives: the K ``losses`` (DDQN: with the ``learning_rate`` and ``epsilon``
  in force and ``target_copies`` so far; SAC: ``critic_loss`` and ``actor_loss``).
* ``checkpoint``: resume from its state if it holds one; save the training state to it at
  rollout (off-policy: day) boundaries when it is due (:mod:`nutribench.engine.checkpoint`).
* ``device``: where the networks train (:func:`~nutribench.engine.device.resolve_device`:
  ``"auto"``, ``"cpu"``, ``"cuda"``, ``"cuda:N"``). The default is the CPU, whose runs are
  reproducible bit for bit; the random streams are the CPU's on every device.
* ``eval_every``: every so many training days, all K agents' greedy policies play their
  ``val_episodes`` validation days (:mod:`nutribench.engine.evaluate`), the days the SB3
  engine would play, the training unchanged; each agent's rows in ``agent.validation``.
  None or 0: never. ``on_validation(agent_index, train_day, rows)`` after each one (its
  exception stops the training and propagates).
* ``agent_configs``: one config per job instead of ``agent_config`` for all (tuning trials
  stacked in one batch: :mod:`nutribench.tuning.stack`): they may differ only in continuous
  settings (learning rate, discount, GAE lambda, clip range, entropy and value coefficients,
  gradient-norm clip; SAC: its two learning rates, alpha, tau, discount), which then go on
  the agent axis (the class's ``PER_AGENT``; not DDQN yet); ``agent_config`` is still the
  batch's structure.
* ``active``: a ``(K,)`` bool array the caller may change while training: the agents where
  it is False get no more updates (a pruned trial's; the classes with ``PER_AGENT``).
* ``return_agents``: False: build no SB3 model and return ``[]`` (a tuning trial's score is
  its ``on_validation`` rows alone: :mod:`nutribench.tuning.stack`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch as th

import nutribench.agents.registry as registry
from nutribench.agents.api import TrainedAgent, single_threaded
from nutribench.agents.config import load_agent_config
from nutribench.agents.validation import DEFAULT_VAL_EPISODES, ValidationFn, check_eval_every
from nutribench.config import EnvConfig, load_env_config
from nutribench.engine import check_supported
from nutribench.engine.algorithm import BatchedAlgorithm
from nutribench.engine.checkpoint import Checkpoint, CheckpointRefused
from nutribench.engine.device import resolve_device
from nutribench.engine.envs import AgentEnvs, AgentEpisodeFn
from nutribench.engine.evaluate import BatchValidator


@single_threaded()
def train_batched(
    jobs: Sequence[tuple[str | EnvConfig, int]],
    agent_config: Any,
    episodes: int,
    on_episode: AgentEpisodeFn | None = None,
    on_rollout: Callable[[dict[str, np.ndarray]], None] | None = None,
    on_update: Callable[[dict[str, Any]], None] | None = None,
    checkpoint: Checkpoint | None = None,
    device: str | th.device = "cpu",
    eval_every: int | None = None,
    val_episodes: int = DEFAULT_VAL_EPISODES,
    on_validation: ValidationFn | None = None,
    agent_configs: Sequence[Any] | None = None,
    active: np.ndarray | None = None,
    return_agents: bool = True,
) -> list[TrainedAgent]:
    """Train one agent of ``agent_config`` per ``(regime, seed)`` of ``jobs`` for
    ``episodes`` days, all at once; each comes back with its ``diagnostics`` and
    ``validation`` rows. What each option does: the module docstring.

    :raises nutribench.engine.UnsupportedConfig: (one line, before anything trains) for a
        config this engine would not train as the SB3 engine does (:func:`nutribench.engine.supports`).
    """
    cfg = load_agent_config(agent_config)
    check_supported(cfg)
    agent_configs = None if agent_configs is None else [load_agent_config(c) for c in agent_configs]
    horizon = load_env_config(jobs[0][0]).reward.horizon if jobs else None
    for c in agent_configs or [cfg]:
        check_supported(c, horizon)  # before anything trains
    cls = registry.batched_class(cfg.algo)
    device = resolve_device(device)
    every = check_eval_every(eval_every, val_episodes)

    def made() -> BatchedAlgorithm:
        envs = AgentEnvs(jobs, cfg.normalize_obs, on_episode)
        algorithm = cls(cfg, envs, device, agent_configs)
        algorithm.set_active(active)
        algorithm.on_rollout, algorithm.on_update = on_rollout, on_update
        if every:
            algorithm.validator = BatchValidator(envs, every, val_episodes, on_validation)
        return algorithm

    algorithm = made()
    try:
        wall = algorithm.learn(episodes * algorithm.envs.horizon, checkpoint)
    except CheckpointRefused as exc:  # its state did not fit (raised before any step): start over without it
        checkpoint.refuse(exc)
        algorithm = made()
        wall = algorithm.learn(episodes * algorithm.envs.horizon, checkpoint)
    algorithm.day_boundary(episodes * algorithm.envs.horizon)  # the evaluation after the last day
    return algorithm.trained_agents(episodes, wall) if return_agents else []
