"""Discrete SAC (the paper's Table 5): the soft value and target maths, the update, learning, save/load, seeding."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import VecNormalize

from nutribench.agents.sac import DiscreteSAC, DiscreteSACPolicy, soft_bellman_target, soft_value
from nutribench.env import NutriRLEnv
from nutribench.env.sb3 import NutriRLSB3VecEnv
from tests.policy_probes import sac_action_probabilities

th.set_num_threads(1)


def make_venv(regime: str = "run0", num_envs: int = 4, normalize: bool = True):
    venv = NutriRLSB3VecEnv(num_envs=num_envs, regime=regime)
    return VecNormalize(venv, norm_obs=True, norm_reward=False) if normalize else venv


def np_softmax(logits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = logits - logits.max(axis=-1, keepdims=True)
    log_p = z - np.log(np.exp(z).sum(axis=-1, keepdims=True))
    return np.exp(log_p), log_p


def mlp_np(seq: th.nn.Sequential, x: np.ndarray) -> np.ndarray:
    """Forward pass of a Linear/ReLU stack in float64 numpy (independent of torch's forward)."""
    for layer in seq:
        if isinstance(layer, th.nn.Linear):
            x = x @ layer.weight.detach().double().numpy().T + layer.bias.detach().double().numpy()
        else:
            x = np.maximum(x, 0.0)
    return x


# ---- pure maths ----


def test_soft_value_by_hand():
    q1 = th.tensor([[1.0, 2.0], [0.0, -1.0]])
    q2 = th.tensor([[0.5, 3.0], [0.2, -3.0]])
    probs = th.tensor([[0.25, 0.75], [0.9, 0.1]])
    alpha = 0.2
    v = soft_value(q1, q2, probs, probs.log(), alpha)
    # row 0: min Q = (0.5, 2.0); row 1: min Q = (0.0, -3.0)
    expected0 = 0.25 * (0.5 - alpha * math.log(0.25)) + 0.75 * (2.0 - alpha * math.log(0.75))
    expected1 = 0.9 * (0.0 - alpha * math.log(0.9)) + 0.1 * (-3.0 - alpha * math.log(0.1))
    assert v.shape == (2,)
    assert v[0].item() == pytest.approx(expected0, abs=1e-6)
    assert v[1].item() == pytest.approx(expected1, abs=1e-6)
    assert expected0 == pytest.approx(1.7374670, abs=1e-6)


def test_soft_value_random_batch_matches_numpy():
    rng = np.random.default_rng(0)
    q1, q2, logits = (rng.normal(size=(64, 2)) for _ in range(3))
    p, log_p = np_softmax(logits)
    alpha = 0.2
    expected = np.zeros(64)
    for i in range(64):
        for a in range(2):
            expected[i] += p[i, a] * (min(q1[i, a], q2[i, a]) - alpha * log_p[i, a])
    got = soft_value(th.tensor(q1), th.tensor(q2), th.tensor(p), th.tensor(log_p), alpha)
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-12, atol=1e-12)
    # alpha = 0: the plain expectation of min Q
    got0 = soft_value(th.tensor(q1), th.tensor(q2), th.tensor(p), th.tensor(log_p), 0.0)
    np.testing.assert_allclose(got0.numpy(), (p * np.minimum(q1, q2)).sum(axis=1), atol=1e-12)


def test_soft_bellman_target():
    r = th.tensor([[1.0], [-2.0], [0.5]])
    d = th.tensor([[0.0], [1.0], [0.0]])
    v = th.tensor([10.0, 10.0, -4.0])
    y = soft_bellman_target(r, d, v, 0.99)
    np.testing.assert_allclose(y.numpy(), [1.0 + 0.99 * 10.0, -2.0, 0.5 - 0.99 * 4.0], atol=1e-6)


# ---- the algorithm ----


def test_defaults_follow_the_spec():
    model = DiscreteSAC("MlpPolicy", make_venv(), seed=0)
    assert (model.alpha, model.tau, model.gamma) == (0.2, 0.005, 0.99)
    assert (model.buffer_size, model.learning_starts, model.batch_size) == (100_000, 128, 128)
    assert model.replay_buffer.buffer_size * model.n_envs >= 100_000 - model.n_envs
    policy = model.policy
    assert isinstance(policy, DiscreteSACPolicy)
    assert policy.actor_optimizer.param_groups[0]["lr"] == pytest.approx(1e-4)
    assert policy.critic_optimizer.param_groups[0]["lr"] == pytest.approx(1e-3)
    assert isinstance(policy.actor_optimizer, th.optim.Adam) and isinstance(policy.critic_optimizer, th.optim.Adam)
    for net in (policy.actor, policy.critic.q1, policy.critic.q2, policy.critic_target.q1, policy.critic_target.q2):
        shapes = [tuple(m.weight.shape) for m in net if isinstance(m, th.nn.Linear)]
        assert shapes == [(256, 13), (128, 256), (2, 128)]
        assert [type(m) for m in net if not isinstance(m, th.nn.Linear)] == [th.nn.ReLU, th.nn.ReLU]
    # twin critics are independent networks; targets start as copies and take no gradient
    assert not th.equal(policy.critic.q1[0].weight, policy.critic.q2[0].weight)
    for p, pt in zip(policy.critic.parameters(), policy.critic_target.parameters()):
        assert th.equal(p, pt) and p.data_ptr() != pt.data_ptr() and not pt.requires_grad
    # the optimisers own disjoint parameter sets: actor vs both critics, no target parameters
    actor_ids = {id(p) for g in policy.actor_optimizer.param_groups for p in g["params"]}
    critic_ids = {id(p) for g in policy.critic_optimizer.param_groups for p in g["params"]}
    assert actor_ids == {id(p) for p in policy.actor.parameters()}
    assert critic_ids == {id(p) for p in policy.critic.parameters()}


def test_critic_target_is_soft_bellman_with_expected_soft_value():
    model = DiscreteSAC("MlpPolicy", make_venv(normalize=False), seed=1, gamma=0.97, alpha=0.3)
    rng = np.random.default_rng(3)
    next_obs = rng.normal(size=(16, 13)).astype(np.float32)
    rewards = rng.normal(size=(16, 1)).astype(np.float32)
    dones = (rng.random(size=(16, 1)) < 0.3).astype(np.float32)
    dones[0], dones[1] = 1.0, 0.0
    # perturb the target critics so that they differ from the online ones and from each other
    with th.no_grad():
        for p in model.policy.critic_target.parameters():
            p.add_(0.05 * th.randn_like(p))
    got = model.critic_target_values(th.tensor(next_obs), th.tensor(rewards), th.tensor(dones)).numpy()

    x = next_obs.astype(np.float64)
    p, log_p = np_softmax(mlp_np(model.policy.actor, x))
    q1 = mlp_np(model.policy.critic_target.q1, x)
    q2 = mlp_np(model.policy.critic_target.q2, x)
    v = (p * (np.minimum(q1, q2) - 0.3 * log_p)).sum(axis=1)
    expected = rewards[:, 0] + 0.97 * (1.0 - dones[:, 0]) * v
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)
    assert got[0] == pytest.approx(rewards[0, 0], abs=1e-6)  # terminal: no bootstrap


def test_one_update_polyak_and_losses():
    model = DiscreteSAC("MlpPolicy", make_venv(), seed=2, learning_starts=128)
    model.learn(200)  # fills the buffer and starts updating
    critic_before = [p.detach().clone() for p in model.policy.critic.parameters()]
    target_before = [p.detach().clone() for p in model.policy.critic_target.parameters()]
    actor_before = [p.detach().clone() for p in model.policy.actor.parameters()]
    model.train(gradient_steps=1, batch_size=model.batch_size)
    critic_after = list(model.policy.critic.parameters())
    for c0, c1, t0, t1 in zip(critic_before, critic_after, target_before, model.policy.critic_target.parameters()):
        assert not th.equal(c0, c1)
        th.testing.assert_close(t1, (1 - 0.005) * t0 + 0.005 * c1.detach(), rtol=1e-6, atol=1e-7)
    assert any(not th.equal(a0, a1) for a0, a1 in zip(actor_before, model.policy.actor.parameters()))
    logged = model.logger.name_to_value
    for key in ("train/actor_loss", "train/critic_loss", "train/entropy", "train/q_mean"):
        assert np.isfinite(logged[key])
    assert 0.0 <= logged["train/entropy"] <= math.log(2) + 1e-6


def test_actor_loss_is_expectation_under_policy():
    model = DiscreteSAC("MlpPolicy", make_venv(normalize=False), seed=4)
    obs = th.randn(8, 13)
    loss, entropy = model.actor_loss(obs)
    x = obs.double().numpy()
    p, log_p = np_softmax(mlp_np(model.policy.actor, x))
    min_q = np.minimum(mlp_np(model.policy.critic.q1, x), mlp_np(model.policy.critic.q2, x))
    assert loss.item() == pytest.approx((p * (0.2 * log_p - min_q)).sum(axis=1).mean(), abs=1e-4)
    assert entropy.item() == pytest.approx(-(p * log_p).sum(axis=1).mean(), abs=1e-5)


@pytest.mark.parametrize("regime", ["run0", "run6"])
def test_learns_a_few_episodes(regime):
    venv = make_venv(regime, num_envs=4)
    model = DiscreteSAC("MlpPolicy", venv, seed=0)
    actor_before = [p.detach().clone() for p in model.policy.actor.parameters()]
    model.learn(4 * 50 * 4)  # 4 days of 4 envs
    assert model.num_timesteps == 800
    assert model._episode_num == 16
    assert model._n_updates == (800 - 128) // 4
    assert any(not th.equal(a, b) for a, b in zip(actor_before, model.policy.actor.parameters()))
    assert np.isfinite(model.logger.name_to_value["train/entropy"])
    obs = venv.reset()
    entropy = model.action_entropy(obs)
    probs = sac_action_probabilities(model, obs)
    assert entropy.shape == (4,) and probs.shape == (4, 2)
    np.testing.assert_allclose(entropy, -(probs * np.log(probs)).sum(axis=1), rtol=1e-4, atol=1e-6)
    actions, state = model.predict(obs, deterministic=True)
    assert state is None
    np.testing.assert_array_equal(actions, probs.argmax(axis=1))


def test_single_gym_env():
    model = DiscreteSAC("MlpPolicy", NutriRLEnv("run6"), seed=0)
    model.learn(250)
    assert model._episode_num == 5 and model._n_updates > 0


def test_save_load_round_trip(tmp_path):
    venv = make_venv(num_envs=4)
    model = DiscreteSAC("MlpPolicy", venv, seed=5)
    model.learn(400)
    model.save(tmp_path / "sac.zip")
    loaded = DiscreteSAC.load(tmp_path / "sac.zip", env=venv)
    obs = np.random.default_rng(0).normal(size=(256, 13)).astype(np.float32)
    a0, _ = model.predict(obs, deterministic=True)
    a1, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(a0, a1)
    np.testing.assert_allclose(sac_action_probabilities(model, obs), sac_action_probabilities(loaded, obs), atol=0)
    assert loaded.alpha == 0.2 and loaded.tau == 0.005
    assert loaded.policy.actor_optimizer.param_groups[0]["lr"] == pytest.approx(1e-4)
    assert loaded.policy.critic_optimizer.param_groups[0]["lr"] == pytest.approx(1e-3)
    for p, q in zip(model.policy.critic_target.parameters(), loaded.policy.critic_target.parameters()):
        assert th.equal(p, q)
    loaded.learn(100, reset_num_timesteps=False)  # keeps training after loading


def test_same_seed_same_parameters():
    def run():
        model = DiscreteSAC("MlpPolicy", make_venv(num_envs=4), seed=123)
        model.learn(600)
        return th.nn.utils.parameters_to_vector(model.policy.parameters()).detach().clone()

    a, b = run(), run()
    assert th.equal(a, b)
    other = DiscreteSAC("MlpPolicy", make_venv(num_envs=4), seed=124)
    other.learn(600)
    assert not th.equal(a, th.nn.utils.parameters_to_vector(other.policy.parameters()))
