"""The batched engine's DDQN against SB3's (``nutribench.agents.builtin.ddqn.DoubleDQN``): the
n-step replay sampling, one update of stacked agents, the schedules, and the loop's timing
(when it updates, with which learning rate and epsilon, how often it copies the target)."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.utils import LinearSchedule

from nutribench.agents.api import TrainedAgent, eval_food_streams, evaluate, make_train_env
from nutribench.agents.builtin.ddqn import DoubleDQN
from nutribench.agents.config import load_agent_config
from nutribench.config import load_env_config
from nutribench.engine.ddqn import ddqn_update
from nutribench.engine.envs import AgentEnvs
from nutribench.engine.off_policy import OFF_POLICY_ADAM_EPS, StackedReplay
from nutribench.engine.stacked import StackedAdam, StackedMLP, linears
from nutribench.engine.train import train_batched
from tests.conftest import random_batch, sb3_model, sb3_updates, shake

OBS_DIM, GAMMA, N_STEP = 13, 0.99, 5


def _transitions(seed: int, n: int, day: int = 50):
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, OBS_DIM)).astype(np.float32)
    nxt = rng.normal(size=(n, OBS_DIM)).astype(np.float32)
    actions = rng.integers(0, 2, size=n)
    rewards = rng.normal(size=n).astype(np.float32)
    dones = (np.arange(n) + 1) % day == 0
    return obs, nxt, actions, rewards, dones


@pytest.mark.parametrize("size,n", [(200, 131), (120, 131), (100, 100)])
def test_n_step_sampling_equals_sb3_s_n_step_replay_buffer(size: int, n: int) -> None:
    """Three agents' replays (one wrapped, one cut at the newest transition, one full at a
    day's end) sampled at the same indices as SB3's ``NStepReplayBuffer`` of each."""
    k = 3
    ours = StackedReplay(k, size, OBS_DIM, N_STEP, GAMMA)
    data = [_transitions(seed, n) for seed in range(k)]
    theirs = []
    for obs, nxt, act, rew, done in data:
        buf = NStepReplayBuffer(
            size,
            spaces.Box(-np.inf, np.inf, (OBS_DIM,)),
            spaces.Discrete(2),
            device="cpu",
            n_envs=1,
            n_steps=N_STEP,
            gamma=GAMMA,
        )
        for t in range(n):
            buf.add(obs[t : t + 1], nxt[t : t + 1], np.array([[act[t]]]), rew[t : t + 1], done[t : t + 1], [{}])
        theirs.append(buf)
    for t in range(n):
        ours.add(*(np.stack([d[i][t] for d in data]) for i in (0, 2, 3, 1, 4)))
    idx = np.random.default_rng(7).integers(0, ours.filled, size=(k, 64))
    idx[:, :4] = [(ours.pos - 1) % size, (ours.pos - 3) % size, 48, 49]  # the newest, near it, a day's end
    got = ours.sample(idx, lambda x: x)
    for j, buf in enumerate(theirs):
        ref = buf._get_samples(idx[j])
        np.testing.assert_allclose(got.obs[j], ref.observations, rtol=1e-6)
        np.testing.assert_allclose(got.next_obs[j], ref.next_observations, rtol=1e-6)
        np.testing.assert_array_equal(got.actions[j], ref.actions[:, 0])
        np.testing.assert_allclose(got.rewards[j], ref.rewards[:, 0], rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(got.dones[j], ref.dones[:, 0])
        np.testing.assert_allclose(got.discounts[j], ref.discounts[:, 0], rtol=1e-6)


def _sb3_ddqn(seed: int):
    cfg, model = sb3_model("ddqn", seed)
    shake(model.q_net_target.parameters(), seed)  # so that the target network matters
    return cfg, model


def test_one_ddqn_update_of_stacked_agents_equals_sb3_s_update_of_each_alone() -> None:
    """Two updates (the second with Adam's state) of three stacked agents, each against
    ``DoubleDQN.train`` of that agent alone on the same samples: losses and new weights."""
    k, b = 3, 32
    models = [_sb3_ddqn(seed) for seed in range(k)]
    cfg = models[0][0]
    sizes = [OBS_DIM, *cfg.net_arch, 2]
    q, q_target = StackedMLP(k, sizes), StackedMLP(k, sizes)
    for j, (_, m) in enumerate(models):
        q.load_sb3(j, linears(m.q_net.q_net))
        q_target.load_sb3(j, linears(m.q_net_target.q_net))
    optimizer = StackedAdam(q.params, cfg.learning_rate_start, OFF_POLICY_ADAM_EPS)
    rng = np.random.default_rng(3)
    for progress in (0.9, 0.6):
        batch = random_batch(rng, k, b, OBS_DIM, 20.0, GAMMA, n_step=5)
        lr = LinearSchedule(cfg.learning_rate_start, cfg.learning_rate_end, 1.0)(progress)
        losses = ddqn_update(q, q_target, optimizer, batch, lr, cfg.max_grad_norm)
        for j, (_, m) in enumerate(models):
            sample = ReplayBufferSamples(
                batch.obs[j],
                batch.actions[j].unsqueeze(1),
                batch.next_obs[j],
                batch.dones[j].unsqueeze(1),
                batch.rewards[j].unsqueeze(1),
                batch.discounts[j].unsqueeze(1),
            )
            m.replay_buffer.sample = lambda *a, s=sample, **kw: s
            m._current_progress_remaining = progress
            m.train(gradient_steps=1, batch_size=b)
            assert losses[j] == pytest.approx(m.logger.name_to_value["train/loss"], rel=1e-5)
            for i, lin in enumerate(linears(m.q_net.q_net)):
                np.testing.assert_allclose(q.params[2 * i][j].detach().T, lin.weight.detach(), rtol=1e-4, atol=1e-6)
                np.testing.assert_allclose(q.params[2 * i + 1][j, 0].detach(), lin.bias.detach(), rtol=1e-4, atol=1e-6)


def test_observations_are_normalised_as_vecnormalize_does() -> None:
    cfg = load_agent_config("ddqn")
    envs = AgentEnvs([("run0", 0), ("run3", 1)], normalize_obs=True)
    raws = [envs.new_days() for _ in range(3)]
    for raw in raws:
        envs.seen(raw)
    for j, regime in enumerate(("run0", "run3")):
        _, venv = make_train_env(load_env_config(regime), cfg)
        venv.obs_rms.mean, venv.obs_rms.var = envs.obs_stats.mean[j], envs.obs_stats.var[j]
        batch = np.stack([r[j] for r in raws])
        np.testing.assert_allclose(envs.normalize(np.stack([batch, batch]))[j], venv.normalize_obs(batch), rtol=1e-6)


def _small(cfg):
    return cfg.model_copy(update=dict(learning_starts=60, target_update_interval=40, buffer_size=120))


def test_the_loop_updates_when_sb3_does_with_its_learning_rate_epsilon_and_target_copies() -> None:
    """A short budget (3 days, learning from step 60, the replay wrapping) through SB3's
    ``DoubleDQN.learn`` and the batched loop: the same update steps, learning rates, epsilons
    and target copies (SB3's last step ends the job before its update, as ours does)."""
    cfg = _small(load_agent_config("ddqn"))
    events: list[tuple] = []
    train_batched(
        [("run0", 0), ("run6", 1)],
        cfg,
        episodes=3,
        on_update=lambda u: events.append((u["steps"], u["learning_rate"], u["epsilon"], u["target_copies"])),
    )
    sb3 = sb3_updates(
        DoubleDQN,
        "run0",
        cfg,
        3,
        lambda m: (
            m.num_timesteps,
            m.lr_schedule(m._current_progress_remaining),
            m.exploration_rate,
            m._n_calls // m.target_update_interval,
        ),
    )
    assert len(events) == len(sb3) == (150 - 1 - 60) // 4
    for ours, theirs in zip(events, sb3):
        assert ours[0] == theirs[0] and ours[3] == theirs[3]
        assert ours[1] == pytest.approx(theirs[1]) and ours[2] == pytest.approx(theirs[2])


def test_batched_ddqn_agents_are_sb3_double_dqns_the_single_agent_api_uses(tmp_path) -> None:
    cfg = _small(load_agent_config("ddqn"))
    days: list[tuple[int, dict]] = []
    agents = train_batched([("run0", 0), ("run3", 0)], cfg, episodes=3, on_episode=lambda j, m: days.append((j, m)))
    assert [len(a.train_episodes) for a in agents] == [3, 3] and len(days) == 6
    assert all(m["entropy"] is None for _, m in days)
    streams = eval_food_streams("run0", 0, 2)
    for a in agents:
        assert isinstance(a.model, DoubleDQN) and a.provenance["engine"] == "batched"
        path = a.save(tmp_path / f"{a.provenance['regime']}.zip")
        back = TrainedAgent.load(path)
        before = evaluate(a, "run0", streams, record_steps=False).episodes
        after = evaluate(back, "run0", streams, record_steps=False).episodes
        assert [e["return"] for e in before] == [e["return"] for e in after]
    # the two agents' Q-networks differ (their own seeds, their own regimes)
    w = [next(a.model.q_net.parameters()).detach() for a in agents]
    assert not th.equal(w[0], w[1])
