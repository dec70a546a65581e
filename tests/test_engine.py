"""The batched engine makes the SB3 agents' updates: with identical initial
weights and identical data, one update of K stacked agents gives each agent exactly the
parameters SB3 gives it alone (float32 tolerance), so there is no cross-talk."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from nutribench.agents.algos import build_model
from nutribench.agents.api import make_train_env
from nutribench.agents.config import load_agent_config
from nutribench.config import load_env_config
from nutribench.engine.actor_critic import StackedActorCritic
from nutribench.engine.mc import a2c_update
from nutribench.engine.on_policy import ADAM_EPS, OnPolicySettings, Rollout, gae
from nutribench.engine.ppo import ppo_update
from nutribench.engine.stacked import RunningStats, StackedAdam, clip_grad_norm_per_agent


def _sb3_ppo_after_one_rollout(seed: int, regime: str = "run0", algo: str = "ppo"):
    cfg = load_agent_config(algo)
    env_cfg = load_env_config(regime)
    _, env = make_train_env(env_cfg, cfg)
    model = build_model(cfg, env, seed=seed, horizon=env_cfg.reward.horizon)
    _, callback = model._setup_learn(model.n_steps, callback=None)
    callback.on_training_start(locals(), globals())
    assert model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=model.n_steps)
    return cfg, model


def _rollout_of(models) -> Rollout:
    bufs = [m.rollout_buffer for m in models]
    stack = lambda name: th.as_tensor(np.stack([getattr(b, name)[:, 0] for b in bufs]))  # noqa: E731
    return Rollout(
        obs=stack("observations").float(),
        actions=stack("actions").squeeze(-1).long(),
        log_probs=stack("log_probs").float(),
        values=stack("values").float(),
        advantages=stack("advantages").float(),
        returns=stack("returns").float(),
    )


def test_one_ppo_update_of_stacked_agents_equals_sb3_s_update_of_each_alone() -> None:
    th.set_num_threads(1)
    seeds = [0, 1, 2]  # different weights, different data (run0 and run3), one stack
    made = [_sb3_ppo_after_one_rollout(s, r) for s, r in zip(seeds, ["run0", "run3", "run0"])]
    cfg, models = made[0][0], [m for _, m in made]
    net = StackedActorCritic(len(models), models[0].observation_space.shape[0], list(cfg.net_arch))
    for j, m in enumerate(models):
        net.load_sb3(j, m.policy)
    optimizer = StackedAdam(net.params, cfg.learning_rate, ADAM_EPS)
    rollout = _rollout_of(models)
    settings = OnPolicySettings.from_config(cfg, 50)
    perms = []
    for j, m in enumerate(models):  # SB3 draws one permutation per epoch from numpy's global RNG
        np.random.seed(100 + j)
        perms.append([np.random.permutation(cfg.n_steps) for _ in range(cfg.n_epochs)])
        np.random.seed(100 + j)
        m.train()
    ppo_update(net, optimizer, rollout, settings, np.stack(perms, axis=1))
    for j, m in enumerate(models):
        mine = StackedActorCritic(1, net.params[0].shape[1], list(cfg.net_arch))
        mine.params = [p[j : j + 1].detach() for p in net.params]
        reference = StackedActorCritic(1, net.params[0].shape[1], list(cfg.net_arch))
        reference.load_sb3(0, m.policy)
        for a, b in zip(mine.params, reference.params):
            np.testing.assert_allclose(a.numpy(), b.detach().numpy(), rtol=1e-4, atol=2e-6)


def test_stacked_agents_do_not_talk_to_each_other() -> None:
    """Agent 0's update is the same whether it is trained alone or beside two others whose
    data is wild (large rewards): nothing of theirs reaches it (gradient norm, Adam, losses)."""
    th.set_num_threads(1)
    cfg, model = _sb3_ppo_after_one_rollout(0)
    settings = OnPolicySettings.from_config(cfg, 50)
    base = _rollout_of([model])
    rng = np.random.default_rng(0)

    def stacked(k: int):
        net = StackedActorCritic(k, 13, list(cfg.net_arch))
        for j in range(k):  # every agent starts from the same weights
            net.load_sb3(j, model.policy)
        return net

    alone, crowd = stacked(1), stacked(3)
    wild = Rollout(
        *(
            th.cat([getattr(base, f), getattr(base, f).repeat(2, *([1] * (getattr(base, f).ndim - 1)))])
            for f in ("obs", "actions", "log_probs", "values", "advantages", "returns")
        )
    )
    wild.advantages[1:] *= 1e4
    wild.returns[1:] += 1e3
    perm = np.stack([[rng.permutation(cfg.n_steps) for _ in range(3)] for _ in range(cfg.n_epochs)])
    ppo_update(alone, StackedAdam(alone.params, cfg.learning_rate, ADAM_EPS), base, settings, perm[:, :1])
    ppo_update(crowd, StackedAdam(crowd.params, cfg.learning_rate, ADAM_EPS), wild, settings, perm)
    for a, b in zip(alone.params, crowd.params):  # float32 rounding only (batched kernels differ by K)
        th.testing.assert_close(a[0], b[0], rtol=1e-5, atol=1e-6)
    drift = max(float((b[1] - b[0]).abs().max().detach()) for b in crowd.params)
    assert drift > 1e-3  # same start, other data, far apart: cross-talk would show


def test_running_stats_equal_sb3_s_for_each_agent() -> None:
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    rng = np.random.default_rng(0)
    xs = rng.normal(size=(200, 3, 5)) * np.array([1.0, 10.0, 0.1])[:, None]
    mine, refs = RunningStats(3, (5,)), [RunningMeanStd(shape=(5,)) for _ in range(3)]
    for x in xs:
        mine.update(x)
        for j, r in enumerate(refs):
            r.update(x[j : j + 1])
    for j, r in enumerate(refs):
        np.testing.assert_allclose(mine.mean[j], r.mean, rtol=1e-12)
        np.testing.assert_allclose(mine.var[j], r.var, rtol=1e-10)


def test_gae_equals_sb3_s_rollout_buffer() -> None:
    from gymnasium import spaces
    from stable_baselines3.common.buffers import RolloutBuffer

    rng = np.random.default_rng(1)
    t_max = 100
    buf = RolloutBuffer(t_max, spaces.Box(-1, 1, (2,)), spaces.Discrete(2), n_envs=1, gamma=0.99, gae_lambda=0.95)
    rewards, values = rng.normal(size=t_max).astype(np.float32), rng.normal(size=t_max).astype(np.float32)
    starts = (np.arange(t_max) % 50 == 0).astype(np.float32)
    for t in range(t_max):
        buf.add(
            np.zeros((1, 2)),
            np.zeros((1, 1)),
            rewards[t : t + 1],
            starts[t : t + 1],
            th.tensor([values[t]]),
            th.zeros(1),
        )
    buf.compute_returns_and_advantage(th.tensor([0.3]), np.array([True]))
    adv, ret = gae(rewards[None], values[None], starts[None], np.array([0.3]), np.array([True]), 0.99, 0.95)
    np.testing.assert_allclose(adv[0], buf.advantages[:, 0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ret[0], buf.returns[:, 0], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("max_norm", [0.5, float("inf")])
def test_gradient_clipping_is_per_agent(max_norm: float) -> None:
    g = th.Generator().manual_seed(0)
    params = [th.randn(3, 4, 5, generator=g, requires_grad=True), th.randn(3, 1, 5, generator=g, requires_grad=True)]
    for p in params:
        p.grad = th.randn(p.shape, generator=g) * th.tensor([0.01, 1.0, 100.0]).reshape(-1, *([1] * (p.ndim - 1)))
    expected = []
    for j in range(3):
        own = [th.nn.Parameter(p[j].detach().clone()) for p in params]
        for o, p in zip(own, params):
            o.grad = p.grad[j].clone()
        th.nn.utils.clip_grad_norm_(own, max_norm)
        expected.append([o.grad for o in own])
    clip_grad_norm_per_agent(params, max_norm)
    for j in range(3):
        for p, e in zip(params, expected[j]):
            th.testing.assert_close(p.grad[j], e)


def test_batched_training_yields_agents_the_single_agent_api_uses(tmp_path) -> None:
    """Every job's days, in the SB3 engine's row format; the same seed gives the same run
    whichever agents share its batch; the agents evaluate, save and load as SB3 agents do."""
    from nutribench.agents import eval_food_streams, evaluate
    from nutribench.agents.api import TrainedAgent
    from nutribench.engine.train import train_batched

    seen: list[tuple[int, int]] = []
    agents = train_batched(
        [("run0", 0), ("run3", 1), ("run0", 2)],
        "ppo",
        episodes=21,
        on_episode=lambda j, row: seen.append((j, row["episode"])),
    )
    assert sorted(seen) == sorted((j, e) for j in range(3) for e in range(21))
    first = agents[0].train_episodes
    assert len(first) == 21 and set(first[0]) == {
        "episode",
        "return",
        "foods",
        "final_distance",
        "overshoot_ratio",
        "final_C",
        "final_F",
        "final_P",
        "first_overshoot_step",
        "entropy",
    }
    alone = train_batched([("run0", 0)], "ppo", episodes=21)[0].train_episodes
    assert [d["foods"] for d in alone] == [d["foods"] for d in first]
    np.testing.assert_allclose([d["return"] for d in alone], [d["return"] for d in first], rtol=1e-5)
    assert [d["foods"] for d in agents[2].train_episodes] != [d["foods"] for d in first]  # another seed, another run
    streams = eval_food_streams("run3", 1, 3)
    before = evaluate(agents[1], "run3", streams)
    path = agents[1].save(tmp_path / "batched.zip")
    after = evaluate(TrainedAgent.load(path), "run3", streams)
    assert [e["return"] for e in before.episodes] == [e["return"] for e in after.episodes]
    assert agents[1].provenance["engine"] == "batched"


@pytest.mark.slow
def test_bench_engines_and_bench_train_batched_report_their_shape() -> None:
    """The benchmarks' shape, not their figures (timings belong in benchmarks)."""
    from nutribench.agents.registry import batched_class
    from nutribench.bench.throughput import bench_train_batched
    from tests.conftest import benchmark_script

    engines = benchmark_script("engines")
    ENGINE_COLUMNS, bench_engines, engine_cells = engines.ENGINE_COLUMNS, engines.bench_engines, engines.engine_cells
    markdown_table = benchmark_script("learn").markdown_table

    rows = bench_engines(["ppo"], ["run0"], [0, 1], episodes=10, eval_episodes=2, workers=1)
    assert [(r["engine"], r["seeds"]) for r in rows] == [("sb3", 2), ("batched", 2)]
    assert rows[0]["overlap"] is None and isinstance(rows[1]["overlap"], bool)
    assert all(r["ci_low"] <= r["iqm"] <= r["ci_high"] for r in rows)
    assert markdown_table(rows, ENGINE_COLUMNS, engine_cells).count("\n") == 3
    cfg = load_agent_config("ppo")
    assert batched_class("ppo").flops_per_env_step(cfg) == (2 * (13 * 256 + 256 * 128) + 2 * 128 * 3) * (
        1 + 3 * cfg.n_epochs
    )
    assert (
        batched_class("mc").flops_per_env_step(load_agent_config("mc"))
        == (2 * (13 * 256 + 256 * 128) + 2 * 128 * 3) * 4
    )
    b = bench_train_batched("ppo", k_regimes=2, k_seeds=1, episodes=2, repeats=1)
    assert b["k"] == 2 and b["steps_per_s"] > 0 and 0 < b["floor_share"]


def test_one_mc_update_of_stacked_agents_equals_sb3_s_update_of_each_alone() -> None:
    """MC is SB3's A2C with a one-day rollout: one gradient step on the whole day."""
    th.set_num_threads(1)
    made = [_sb3_ppo_after_one_rollout(s, r, "mc") for s, r in zip([0, 1, 2], ["run0", "run3", "run6"])]
    cfg, models = made[0][0], [m for _, m in made]
    net = StackedActorCritic(len(models), 13, list(cfg.net_arch))
    for j, m in enumerate(models):
        net.load_sb3(j, m.policy)
    optimizer = StackedAdam(net.params, cfg.learning_rate, ADAM_EPS)
    settings = OnPolicySettings.from_config(cfg, 50)
    assert (settings.n_steps, settings.n_epochs, settings.clip_range) == (50, 1, None)
    rollout = _rollout_of(models)  # before train(), which flattens SB3's buffer in place
    for m in models:
        m.train()
    a2c_update(net, optimizer, rollout, settings)
    for j, m in enumerate(models):
        reference = StackedActorCritic(1, 13, list(cfg.net_arch))
        reference.load_sb3(0, m.policy)
        for a, b in zip(net.params, reference.params):
            np.testing.assert_allclose(a[j].detach().numpy(), b[0].detach().numpy(), rtol=1e-4, atol=2e-6)


@pytest.mark.parametrize("algo", ["ppo", "mc", "gru_ppo"])
def test_the_batched_rollout_equals_sb3_s_vecnormalize_and_rollout_buffer_on_the_same_days(algo: str) -> None:
    """The rollout loop itself, replayed through SB3: the same food days and the same actions
    played in SB3's VecNormalize over the SB3 adapter give the observations and scaled rewards
    the batched loop recorded (normalisation order, each day's first observation, the return
    reset at day ends), and SB3's RolloutBuffer gives its advantages and returns."""
    from gymnasium import spaces
    from stable_baselines3.common.buffers import RolloutBuffer
    from stable_baselines3.common.vec_env import VecNormalize

    from nutribench.agents.api import CLIP_OBS, NORM_EPS
    from nutribench.engine.train import train_batched
    from nutribench.env.sb3 import NutriRLSB3VecEnv

    cfg = load_agent_config(algo)
    jobs = [("run0", 0), ("run3", 1)]
    seen: list[dict] = []
    days = 2 if algo == "mc" else 10  # one PPO / GRU-PPO rollout (500 steps), two MC rollouts (one day each)
    train_batched(jobs, cfg, days, on_rollout=seen.append)
    assert len(seen) == (2 if algo == "mc" else 1)
    for j, (regime, _) in enumerate(jobs):
        base = NutriRLSB3VecEnv(regime=regime)
        queue = [d[j] for d in seen[-1]["foods"]]
        start_day = base.venv._start_day
        base.venv._start_day = lambda foods=None, start_day=start_day, queue=queue: start_day(
            queue.pop(0)
        )  # the batched loop's days, in order
        env = VecNormalize(
            base,
            norm_obs=cfg.normalize_obs,
            norm_reward=cfg.normalize_reward,
            gamma=cfg.gamma,
            clip_obs=CLIP_OBS,
            epsilon=NORM_EPS,
        )
        obs = env.reset()
        for rollout in seen:
            t_max = rollout["actions"].shape[1]
            buf = RolloutBuffer(
                t_max,
                spaces.Box(-1, 1, (obs.shape[1],)),
                spaces.Discrete(2),
                n_envs=1,
                gamma=cfg.gamma,
                gae_lambda=1.0 if algo == "mc" else cfg.gae_lambda,
            )
            start = True
            for t in range(t_max):
                np.testing.assert_allclose(rollout["obs"][j, t], obs[0], rtol=1e-5, atol=1e-6)
                assert rollout["starts"][j, t] == float(start)
                obs, reward, done, _ = env.step(np.array([rollout["actions"][j, t]]))
                np.testing.assert_allclose(rollout["rewards"][j, t], reward[0], rtol=1e-5, atol=1e-6)
                buf.add(
                    np.zeros((1, obs.shape[1])),
                    np.zeros((1, 1)),
                    reward,
                    np.array([start]),
                    th.tensor([float(rollout["values"][j, t])]),
                    th.zeros(1),
                )
                start = bool(done[0])
            buf.compute_returns_and_advantage(th.tensor([0.0]), np.array([start]))
            np.testing.assert_allclose(rollout["advantages"][j], buf.advantages[:, 0], rtol=1e-4, atol=1e-5)
            np.testing.assert_allclose(rollout["returns"][j], buf.returns[:, 0], rtol=1e-4, atol=1e-5)


# --------------------------------------------------------------------------- GRU-PPO
@pytest.mark.slow
def test_one_gru_ppo_update_of_stacked_agents_equals_gru_ppo_s_update_of_each_alone() -> None:
    """One rollout each (run0, run3, run0), then one ``GRUPPO.train()`` of each alone against
    one stacked update: every weight of both GRUs and both heads, relative tolerance 1e-4.

    Three epochs (six minibatch steps over whole days), not the config's ten: the two agree
    to 2e-7 for four epochs, and then, on these seeds, one critic-head ReLU unit of one agent
    whose input sits at zero to float rounding is on in one implementation and off in the
    other for one sample, so that unit's 256 weights part by ~1e-4 (traced: every other
    weight of that head stays equal). The update code is the same in every epoch."""
    import dataclasses

    from nutribench.engine.gru_ppo import StackedGRUActorCritic

    th.set_num_threads(1)
    epochs = 3
    made = [_sb3_ppo_after_one_rollout(s, r, "gru_ppo") for s, r in zip([0, 1, 2], ["run0", "run3", "run0"])]
    cfg, models = made[0][0], [m for _, m in made]
    net = StackedGRUActorCritic(len(models), models[0].observation_space.shape[0], cfg.hidden_size)
    for j, m in enumerate(models):
        net.load_sb3(j, m.policy)
        m.n_epochs = epochs
    optimizer = StackedAdam(net.params, cfg.learning_rate, ADAM_EPS)
    settings = dataclasses.replace(OnPolicySettings.from_config(cfg, 50), n_epochs=epochs)
    n_days = cfg.n_steps // cfg.sequence_length
    perms = []
    for j, m in enumerate(models):  # the buffer draws one permutation of the days per epoch
        np.random.seed(200 + j)
        perms.append([np.random.permutation(n_days) for _ in range(epochs)])
        np.random.seed(200 + j)
        m.train()
    ppo_update(net, optimizer, _rollout_of(models), settings, np.stack(perms, axis=1))
    for j, m in enumerate(models):
        for ours, theirs in net.sb3_pairs(j, m.policy):
            np.testing.assert_allclose(ours.detach().numpy(), theirs.detach().numpy(), rtol=1e-4, atol=1e-6)


def test_the_stacked_gru_acts_and_replays_days_as_the_sb3_policy_does() -> None:
    """Acting step by step (state carried, reset at a day's start) and replaying whole days
    give the SB3 policy's logits and values for each of two stacked agents."""
    from nutribench.engine.gru_ppo import StackedGRUActorCritic

    models = [_sb3_ppo_after_one_rollout(s, "run0", "gru_ppo")[1] for s in (3, 4)]
    net = StackedGRUActorCritic(2, 13, 128)
    for j, m in enumerate(models):
        net.load_sb3(j, m.policy)
    obs = th.as_tensor(np.stack([m.rollout_buffer.observations[:100, 0] for m in models]), dtype=th.float32)  # two days
    state = th.full((4, 1, 128), 0.3)  # junk before the first day: the reset must clear it
    with th.no_grad():
        day_logits, day_values = net.sequences(obs.reshape(2, 2, 50, 13))
        for j, m in enumerate(models):
            feats, _ = m.policy.unroll(obs[j].reshape(2, 50, 13), m.policy.initial_state(2), th.zeros(2, 50))
            np.testing.assert_allclose(
                day_logits[j].reshape(100, -1), m.policy.actor_head(feats).reshape(100, -1), rtol=1e-4, atol=1e-5
            )
            np.testing.assert_allclose(
                day_values[j].reshape(100), m.policy.critic_head(feats).reshape(100), rtol=1e-4, atol=1e-5
            )
        for t in range(100):
            starts = th.full((2,), float(t % 50 == 0))
            logits, values, state = net.step(obs[:, t], state, starts)
            np.testing.assert_allclose(logits, day_logits.reshape(2, 100, -1)[:, t], rtol=1e-4, atol=1e-5)
            np.testing.assert_allclose(values, day_values.reshape(2, 100)[:, t], rtol=1e-4, atol=1e-5)


def test_the_gru_s_hand_written_backward_is_the_gradient() -> None:
    """``GRUSequence``'s backward against numerical differentiation (float64), and against
    autograd through the step-by-step cell (float32)."""
    from nutribench.engine.gru_ppo import GRUSequence, StackedGRUActorCritic

    g = th.Generator().manual_seed(0)
    m, s, t_max, h = 2, 3, 5, 4
    args = [
        th.randn(m, s, t_max, 3 * h, generator=g, dtype=th.float64),
        0.5 * th.randn(m, h, 3 * h, generator=g, dtype=th.float64),
        th.randn(m, 1, 3 * h, generator=g, dtype=th.float64),
    ]
    assert th.autograd.gradcheck(GRUSequence.apply, [a.requires_grad_() for a in args])

    net = StackedGRUActorCritic(3, 13, 16, generators=[th.Generator().manual_seed(j) for j in range(3)])
    gi = th.randn(6, 2, 7, 48, generator=g, requires_grad=True)
    weights = th.randn(6, 2, 7, 16, generator=g)
    (GRUSequence.apply(gi, net.params[2], net.params[3]) * weights).sum().backward()
    ours = [gi.grad.clone(), net.params[2].grad.clone(), net.params[3].grad.clone()]
    for x in (gi, net.params[2], net.params[3]):
        x.grad = None
    hidden, outs = th.zeros(6, 2, 16), []
    for t in range(7):
        hidden = net._cell(gi[:, :, t], hidden)
        outs.append(hidden)
    (th.stack(outs, dim=2) * weights).sum().backward()
    for a, b in zip(ours, [gi.grad, net.params[2].grad, net.params[3].grad]):
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=1e-4, atol=1e-5)
