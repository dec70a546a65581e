"""Train K agents of one agent config (PPO or MC) at once (regimes and seeds may differ), and hand
each back as the :class:`~nutribench.agents.api.TrainedAgent` the SB3 engine would give:
an SB3 ``PPO`` with the trained weights, its ``VecNormalize`` statistics, and its training
days' metrics. Evaluation, saving and loading are then the single-agent API's.

Per agent, the loop is SB3's ``PPO.learn`` (MC: ``A2C.learn``) on nutribench's one-env
``VecNormalize`` setting:
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
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch as th

from nutribench.agents.algos import build_model
from nutribench.agents.api import CLIP_OBS, NORM_EPS, TrainedAgent, make_train_env
from nutribench.agents.config import load_agent_config
from nutribench.config import EnvConfig, load_env_config
from nutribench.engine.actor_critic import OnPolicySettings, Rollout, RunningStats, StackedActorCritic, gae, make_optimizer
from nutribench.env.metrics import EpisodeRecorder
from nutribench.env.vector_env import NutriRLVectorEnv

#: Mixed into each job seed for the batched engine's streams (foods, actions, minibatches, init).
STREAMS = {"foods": 1, "actions": 2, "minibatches": 3, "init": 4}

AgentEpisodeFn = Callable[[int, dict[str, Any]], None]


class _Group:
    """The agents of one regime: one natively batched vector env, rows ``agents``."""

    def __init__(self, env_cfg: EnvConfig, agents: list[int]):
        self.agents = np.asarray(agents)
        self.env = NutriRLVectorEnv(len(agents), regime=env_cfg)
        self.recorder = EpisodeRecorder(len(agents))
        self.n_foods = len(env_cfg.catalog.food)


def train_batched(
    jobs: Sequence[tuple[str | EnvConfig, int]],
    agent_config: Any,
    episodes: int,
    on_episode: AgentEpisodeFn | None = None,
    on_rollout: Callable[[dict[str, np.ndarray]], None] | None = None,
) -> list[TrainedAgent]:
    """Train one agent of ``agent_config`` (PPO or MC) per ``(regime, seed)`` of ``jobs`` for
    ``episodes`` days, all at once.

    :param on_rollout: called before each update with the rollout's arrays (agent axis first):
        ``obs`` (as the policy saw them), ``actions``, ``rewards`` (as the update sees them),
        ``starts``, ``values``, ``advantages``, ``returns``, and ``foods`` (every day drawn so
        far, ``(days, K, horizon)``); for tests that replay it through SB3.

    :param on_episode: called with (job index, the finished day's metrics) for every day.
    """
    th.set_num_threads(1)
    cfg = load_agent_config(agent_config)
    env_cfgs = [load_env_config(r) for r, _ in jobs]
    seeds = [int(s) for _, s in jobs]
    k = len(jobs)
    horizons = {c.reward.horizon for c in env_cfgs}
    if len(horizons) != 1:
        raise ValueError(f"the agents of one batch need one horizon, got {sorted(horizons)}")
    horizon = horizons.pop()
    s = OnPolicySettings.from_config(cfg, horizon)
    rng = {name: [np.random.default_rng([salt, seed]) for seed in seeds] for name, salt in STREAMS.items()}
    by_regime: dict[str, list[int]] = {}
    for j, c in enumerate(env_cfgs):
        by_regime.setdefault(c.sha256, []).append(j)
    groups = [_Group(env_cfgs[js[0]], js) for js in by_regime.values()]
    dims = {g.env.single_observation_space.shape[0] for g in groups}
    if len(dims) != 1:
        raise ValueError(f"the agents of one batch need one observation size (one food catalog), got {sorted(dims)}")
    obs_dim = dims.pop()
    net = StackedActorCritic(k, obs_dim, list(cfg.net_arch),
                             generators=[th.Generator().manual_seed(int(r.integers(2**62))) for r in rng["init"]])  # fmt: skip
    optimizer = make_optimizer(net, s.learning_rate)
    obs_stats = RunningStats(k, (obs_dim,)) if cfg.normalize_obs else None
    ret_stats = RunningStats(k) if cfg.normalize_reward else None
    discounted = np.zeros(k)

    days_drawn: list[np.ndarray] = []

    def new_days() -> np.ndarray:
        raw = np.empty((k, obs_dim))
        day = np.empty((k, horizon), dtype=np.int64)
        for g in groups:
            foods = np.stack([rng["foods"][j].integers(0, g.n_foods, size=horizon) for j in g.agents])
            o, _ = g.env.reset(options={"foods": foods})
            raw[g.agents], day[g.agents] = o, foods
        days_drawn.append(day)
        return raw

    def seen(raw: np.ndarray) -> np.ndarray:
        if obs_stats is None:
            return raw.astype(np.float32)
        obs_stats.update(raw)
        return np.clip((raw - obs_stats.mean) / np.sqrt(obs_stats.var + NORM_EPS), -CLIP_OBS, CLIP_OBS).astype(np.float32)

    episodes_done = [[] for _ in range(k)]
    day_entropy = np.zeros(k)
    total_steps = episodes * horizon
    n_rollouts = total_steps // s.n_steps
    obs = seen(new_days())
    start_of_day = np.ones(k, dtype=np.float32)
    step = 0
    t0 = time.perf_counter()
    for rollout_index in range(n_rollouts + 1):
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
                logits, values = net.forward(th.as_tensor(obs).unsqueeze(1))
            logp = th.log_softmax(logits[:, 0], dim=-1).numpy()
            p_eat = np.exp(logp[:, 1])
            actions = (uniforms[:, t] < p_eat).astype(np.int64)
            day_entropy += -(np.exp(logp) * logp).sum(axis=1)
            buf_obs[:, t], buf_act[:, t], buf_start[:, t] = obs, actions, start_of_day
            buf_logp[:, t] = logp[np.arange(k), actions]
            buf_val[:, t] = values[:, 0].numpy()
            raw_next = np.empty((k, obs_dim))
            rewards = np.empty(k)
            day_over = False
            for g in groups:
                o, r, term, trunc, info = g.env.step(actions[g.agents])
                raw_next[g.agents], rewards[g.agents] = o, r
                ended = term | trunc
                for row, metrics in zip(np.flatnonzero(ended), g.recorder.record(r, ended, info)):
                    j = int(g.agents[row])
                    metrics = {"episode": len(episodes_done[j]), **metrics, "entropy": float(day_entropy[j] / horizon)}
                    episodes_done[j].append(metrics)
                    if on_episode is not None:
                        on_episode(j, metrics)
                day_over = bool(ended.all())
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
                day_entropy[:] = 0.0
                raw_next = new_days()
                start_of_day = np.ones(k, dtype=np.float32)
            else:
                start_of_day = np.zeros(k, dtype=np.float32)
            obs = seen(raw_next)
        if T < s.n_steps:
            break  # a partial rollout: SB3 stops without updating on it
        with th.no_grad():
            _, last_values = net.forward(th.as_tensor(obs).unsqueeze(1))
        adv, ret = gae(buf_rew, buf_val, buf_start, last_values[:, 0].numpy(), start_of_day.astype(bool), s.gamma, s.gae_lambda)
        if on_rollout is not None:
            on_rollout({"obs": buf_obs, "actions": buf_act, "rewards": buf_rew, "starts": buf_start, "values": buf_val,
                        "advantages": adv, "returns": ret, "foods": np.stack(days_drawn)})  # fmt: skip
        rollout = Rollout(
            obs=th.as_tensor(buf_obs), actions=th.as_tensor(buf_act), log_probs=th.as_tensor(buf_logp),
            values=th.as_tensor(buf_val), advantages=th.as_tensor(adv), returns=th.as_tensor(ret),
        )  # fmt: skip
        perms = np.stack([[r.permutation(T) for r in rng["minibatches"]] for _ in range(s.n_epochs)])
        s.update(net, optimizer, rollout, perms)
    wall = time.perf_counter() - t0
    return [_as_trained_agent(net, j, cfg, env_cfgs[j], seeds[j], episodes, obs_stats, ret_stats, episodes_done[j], wall / k)
            for j in range(k)]  # fmt: skip


def _as_trained_agent(net: StackedActorCritic, j: int, cfg: Any, env_cfg: EnvConfig, seed: int, episodes: int,
                      obs_stats: RunningStats | None, ret_stats: RunningStats | None, days: list[dict],
                      wall: float) -> TrainedAgent:  # fmt: skip
    """Agent ``j`` as an SB3 PPO in its ``VecNormalize``, as ``agents.train`` returns it."""
    _, env = make_train_env(env_cfg, cfg)
    model = build_model(cfg, env, seed=seed, horizon=env_cfg.reward.horizon)
    net.store_sb3(j, model.policy)
    mean = var = None
    if obs_stats is not None:
        mean, var = obs_stats.mean[j].copy(), obs_stats.var[j].copy()
        env.obs_rms.mean, env.obs_rms.var, env.obs_rms.count = mean.copy(), var.copy(), float(obs_stats.count[j])
    if ret_stats is not None:
        env.ret_rms.mean, env.ret_rms.var, env.ret_rms.count = float(ret_stats.mean[j]), float(ret_stats.var[j]), float(ret_stats.count[j])
    provenance = {"regime": env_cfg.name, "regime_version": env_cfg.version, "regime_sha256": env_cfg.sha256,
                  "agent_config": cfg.name, "agent_config_version": cfg.version, "seed": seed, "episodes": episodes,
                  "engine": "batched", "batch_wall_seconds_per_agent": wall}  # fmt: skip
    agent = TrainedAgent(model, cfg.algo, cfg, mean, var, vec_normalize=env if hasattr(env, "obs_rms") else None, provenance=provenance)
    agent.train_episodes = days
    return agent
