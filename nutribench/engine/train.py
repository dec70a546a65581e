"""Train K agents of one agent config at once (regimes and seeds may differ), and hand each
back as the :class:`~nutribench.agents.api.TrainedAgent` the SB3 engine would give: the SB3
model of its config (``PPO``, ``MonteCarloAC``, ``DoubleDQN``, ``DiscreteSAC`` or
``GRUPPO``) with the trained weights, its ``VecNormalize`` statistics, and its training days'
metrics. Evaluation, saving and loading are then the single-agent API's. DDQN and SAC run
in :mod:`nutribench.engine.ddqn` and :mod:`nutribench.engine.sac`; the on-policy ones here.

Per agent, the on-policy loop is SB3's ``PPO.learn`` (MC: ``A2C.learn``; GRU-PPO:
``GRUPPO.learn``, the GRU state carried from step to step and reset at each day's start) on
nutribench's one-env ``VecNormalize`` setting:
observations normalised by a running mean and variance updated with every observation
(including each day's first), rewards scaled by the running deviation of the discounted
return, ``n_steps`` steps per rollout (MC: one day), a day's end a terminal, then the update. A budget
that ends inside a rollout stops there without a partial update, as SB3 does.

Randomness is per agent and comes from its job seed alone (its food days, its action draws,
its minibatch order, its initial weights), so an agent's run does not depend on which
others share its batch, up to float rounding: the batched matrix kernels round differently
for different K, and over a long run a rounding difference can flip a sampled action, after
which the two runs differ as two runs of one seed on two machines may. It is not SB3's
random stream: the two engines' runs with one seed
differ as two seeds do; ``nutribench bench engines`` compares them as distributions.

Every engine entry point takes a ``device`` (:mod:`nutribench.engine.device`; default the
CPU). The networks, optimiser states, GRU states and each update's tensors live there; the
envs, replay buffers, running statistics and random streams stay on the CPU (numpy, and CPU
generators for the initial weights, which are drawn on the CPU and then moved), so an
agent's random draws are the same on every device; what it does with them differs by float
rounding from one device to another.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch as th

from nutribench.agents.api import CLIP_OBS, NORM_EPS, TrainedAgent
from nutribench.agents.config import load_agent_config
from nutribench.config import EnvConfig, load_env_config
from nutribench.engine import check_supported
from nutribench.engine.actor_critic import (
    OnPolicySettings,
    Rollout,
    RunningStats,
    StackedActorCritic,
    gae,
    make_optimizer,
)
from nutribench.engine.checkpoint import Checkpoint, register
from nutribench.engine.device import resolve_device
from nutribench.engine.envs import AgentEnvs, AgentEpisodeFn, as_trained_agent
from nutribench.engine.gru_ppo import StackedGRUActorCritic, gru_ppo_update


class _Feedforward:
    """Acting with the shared MLP actor-critic: ``(obs (K, d), starts (K,))`` -> logits ``(K, 2)``, values ``(K,)``."""

    def __init__(self, net: StackedActorCritic):
        self.net = net

    def __call__(self, obs: th.Tensor, starts: th.Tensor, advance: bool = True) -> tuple[th.Tensor, th.Tensor]:
        logits, values = self.net.forward(obs.unsqueeze(1))
        return logits[:, 0], values[:, 0]


class _Recurrent:
    """Acting with the GRU actor-critic, its state carried from step to step (reset where a
    day starts); ``advance=False`` peeks (the value after the rollout, as SB3's
    ``predict_values``, which does not keep the new state)."""

    def __init__(self, net: StackedGRUActorCritic):
        self.net = net
        self.state = th.zeros(2 * net.k, 1, net.hidden, device=net.params[0].device)

    def __call__(self, obs: th.Tensor, starts: th.Tensor, advance: bool = True) -> tuple[th.Tensor, th.Tensor]:
        logits, values, state = self.net.step(obs, self.state, starts)
        if advance:
            self.state = state
        return logits, values


register(_Feedforward, _Recurrent, StackedActorCritic, StackedGRUActorCritic, RunningStats)  # what its checkpoints hold


def train_batched(
    jobs: Sequence[tuple[str | EnvConfig, int]],
    agent_config: Any,
    episodes: int,
    on_episode: AgentEpisodeFn | None = None,
    on_rollout: Callable[[dict[str, np.ndarray]], None] | None = None,
    checkpoint: Checkpoint | None = None,
    device: str | th.device = "cpu",
) -> list[TrainedAgent]:
    """Train one agent of ``agent_config`` per ``(regime, seed)`` of ``jobs`` for
    ``episodes`` days, all at once.

    :param on_rollout: called before each update with the rollout's arrays (agent axis first):
        ``obs`` (as the policy saw them), ``actions``, ``rewards`` (as the update sees them),
        ``starts``, ``values``, ``advantages``, ``returns``, and ``foods`` (every day drawn so
        far, ``(days, K, horizon)``); for tests that replay it through SB3 (PPO, MC, GRU-PPO).

    :param on_episode: called with (job index, the finished day's metrics) for every day.
    :param checkpoint: resume from its state if it holds one; save the training state to it
        at rollout (off-policy: day) boundaries when it is due (:mod:`nutribench.engine.checkpoint`).
    :param device: where the networks train (:func:`~nutribench.engine.device.resolve_device`:
        ``"auto"``, ``"cpu"``, ``"cuda"``, ``"cuda:N"``). The default is the CPU, whose runs are
        reproducible bit for bit; the random streams are the CPU's on every device.
    :raises nutribench.engine.UnsupportedConfig: (one line, before anything trains) for a
        config this engine would not train as the SB3 engine does (:func:`nutribench.engine.supports`).
    """
    th.set_num_threads(1)
    cfg = load_agent_config(agent_config)
    check_supported(cfg, load_env_config(jobs[0][0]).reward.horizon if jobs else None)  # before anything trains
    device = resolve_device(device)
    if cfg.algo == "ddqn":
        from nutribench.engine.ddqn import train_ddqn_batched

        return train_ddqn_batched(jobs, cfg, episodes, on_episode, checkpoint=checkpoint, device=device)
    if cfg.algo == "sac":
        from nutribench.engine.sac import train_sac_batched

        return train_sac_batched(jobs, cfg, episodes, on_episode, checkpoint=checkpoint, device=device)
    envs = AgentEnvs(jobs, cfg.normalize_obs, on_episode)
    k, horizon, obs_dim, rng = envs.k, envs.horizon, envs.obs_dim, envs.rng
    s = OnPolicySettings.from_config(cfg, horizon)
    generators = [th.Generator().manual_seed(int(r.integers(2**62))) for r in rng["init"]]
    if s.sequence_length is None:
        net = StackedActorCritic(k, obs_dim, list(cfg.net_arch), generators=generators, device=device)
        policy = _Feedforward(net)
    else:  # whole days (check_supported)
        net = StackedGRUActorCritic(k, obs_dim, cfg.hidden_size, generators=generators, device=device)
        policy = _Recurrent(net)
    optimizer = make_optimizer(net, s.learning_rate)
    ret_stats = RunningStats(k) if cfg.normalize_reward else None
    discounted = np.zeros(k)

    total_steps = episodes * horizon
    n_rollouts = total_steps // s.n_steps
    saved = checkpoint.read_onto(device) if checkpoint is not None else None
    if saved is not None:
        envs.restore(saved["envs"])
        rng = envs.rng
        net, policy, optimizer, ret_stats, discounted = saved["model"]
        obs, start_of_day, step, first = saved["obs"], saved["start_of_day"], saved["steps"], saved["rollout"]
    else:
        obs = envs.seen(envs.new_days())
        start_of_day = np.ones(k, dtype=np.float32)
        step = first = 0
    t0 = time.perf_counter()
    for rollout_index in range(first, n_rollouts + 1):
        if checkpoint is not None and rollout_index > first and checkpoint.due():
            checkpoint.save(
                rollout=rollout_index,
                steps=step,
                envs=envs,
                obs=obs,
                start_of_day=start_of_day,
                model=(net, policy, optimizer, ret_stats, discounted),
            )
        T = s.n_steps if rollout_index < n_rollouts else total_steps - step
        if T == 0:
            break
        buf_obs = np.empty((k, T, obs_dim), dtype=np.float32)
        buf_act = np.empty((k, T), dtype=np.int64)
        buf_logp = np.empty((k, T), dtype=np.float32)
        buf_val = np.empty((k, T), dtype=np.float32)
        buf_rew = np.empty((k, T), dtype=np.float32)
        buf_start = np.empty((k, T), dtype=np.float32)
        uniforms = np.stack([r.random(T) for r in rng["actions"]])
        for t in range(T):
            with th.no_grad():
                logits, values = policy(th.as_tensor(obs, device=device), th.as_tensor(start_of_day, device=device))
            logp = th.log_softmax(logits, dim=-1).cpu().numpy()
            p_eat = np.exp(logp[:, 1])
            actions = (uniforms[:, t] < p_eat).astype(np.int64)
            buf_obs[:, t], buf_act[:, t], buf_start[:, t] = obs, actions, start_of_day
            buf_logp[:, t] = logp[np.arange(k), actions]
            buf_val[:, t] = values.cpu().numpy()
            raw_next, rewards, day_over = envs.step(actions, entropy=-(np.exp(logp) * logp).sum(axis=1))
            if ret_stats is not None:
                discounted = discounted * s.gamma + rewards
                ret_stats.update(discounted)
                scaled = np.clip(rewards / np.sqrt(ret_stats.var + NORM_EPS), -CLIP_OBS, CLIP_OBS)
            else:
                scaled = rewards
            buf_rew[:, t] = scaled
            step += 1
            if day_over:
                discounted[:] = 0.0
                raw_next = envs.new_days()
                start_of_day = np.ones(k, dtype=np.float32)
            else:
                start_of_day = np.zeros(k, dtype=np.float32)
            obs = envs.seen(raw_next)
        if T < s.n_steps:
            break  # a partial rollout: SB3 stops without updating on it
        with th.no_grad():
            _, last_values = policy(
                th.as_tensor(obs, device=device), th.as_tensor(start_of_day, device=device), advance=False
            )
        adv, ret = gae(
            buf_rew, buf_val, buf_start, last_values.cpu().numpy(), start_of_day.astype(bool), s.gamma, s.gae_lambda
        )
        if on_rollout is not None:
            on_rollout(
                {
                    "obs": buf_obs,
                    "actions": buf_act,
                    "rewards": buf_rew,
                    "starts": buf_start,
                    "values": buf_val,
                    "advantages": adv,
                    "returns": ret,
                    "foods": np.stack(envs.days_drawn),
                }
            )
        on = lambda x: th.as_tensor(x, device=device)  # noqa: E731
        rollout = Rollout(
            obs=on(buf_obs),
            actions=on(buf_act),
            log_probs=on(buf_logp),
            values=on(buf_val),
            advantages=on(adv),
            returns=on(ret),
        )
        units = T if s.sequence_length is None else T // s.sequence_length  # transitions, or days (GRU-PPO)
        perms = np.stack([[r.permutation(units) for r in rng["minibatches"]] for _ in range(s.n_epochs)])
        if s.sequence_length is None:
            s.update(net, optimizer, rollout, perms)
        else:
            gru_ppo_update(net, optimizer, rollout, s, perms)
    wall = time.perf_counter() - t0 + (checkpoint.seconds_before if saved is not None else 0.0)
    return [
        as_trained_agent(
            envs, j, cfg, episodes, lambda model, j=j: net.store_sb3(j, model.policy), ret_stats, wall / k, str(device)
        )
        for j in range(k)
    ]
