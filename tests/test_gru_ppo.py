"""GRU-PPO (the paper's Table 6): architecture, memory carried in acting/training/evaluation,
backpropagation through time, learning, save/load, seeding."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.vec_env import VecNormalize

from nutribench.agents.gru_ppo import (
    GRUPPO,
    GRUActorCriticPolicy,
    RecurrentRolloutBuffer,
    RecurrentRolloutBufferSamples,
)
from nutribench.env import NutriRLEnv
from nutribench.env.sb3 import NutriRLSB3VecEnv
from tests.policy_probes import gru_action_probabilities

th.set_num_threads(1)

OBS_DIM = 13


def make_venv(regime: str = "run0", num_envs: int = 4, normalize: bool = True):
    venv = NutriRLSB3VecEnv(num_envs=num_envs, regime=regime)
    return VecNormalize(venv, norm_obs=True, norm_reward=False) if normalize else venv


def obs_vec(nutrients=(0.0, 0.0, 0.0), food: int = 0) -> np.ndarray:
    o = np.zeros(OBS_DIM, dtype=np.float32)
    o[:3] = nutrients
    o[3 + food] = 1.0
    return o


@pytest.fixture(scope="module")
def model() -> GRUPPO:
    return GRUPPO(make_venv(num_envs=2), n_steps=100, seed=0)


# ---- architecture ----


def test_architecture(model):
    policy = model.policy
    assert isinstance(policy, GRUActorCriticPolicy)
    for gru, n_in in ((policy.nutrient_gru, 3), (policy.food_gru, 10)):
        assert isinstance(gru, th.nn.GRU)
        assert (gru.input_size, gru.hidden_size, gru.num_layers) == (n_in, 128, 1)
    for head, n_out in ((policy.actor_head, 2), (policy.critic_head, 1)):
        assert [type(m) for m in head] == [th.nn.Linear, th.nn.ReLU, th.nn.Linear]
        assert (head[0].in_features, head[0].out_features) == (256, 128)
        assert (head[2].in_features, head[2].out_features) == (128, n_out)
    assert isinstance(policy.optimizer, th.optim.Adam)
    assert policy.optimizer.param_groups[0]["lr"] == pytest.approx(1e-3)
    assert (model.gamma, model.gae_lambda, model.clip_range(1.0), model.max_grad_norm) == (0.99, 0.95, 0.2, 0.5)
    assert (model.ent_coef, model.vf_coef) == (0.0, 0.5)


def _assert_orthogonal(w: th.Tensor, gain: float) -> None:
    w = w.detach().double()
    gram = w @ w.T if w.shape[0] <= w.shape[1] else w.T @ w
    th.testing.assert_close(gram, gain**2 * th.eye(gram.shape[0], dtype=th.float64), atol=1e-5, rtol=0)


def test_orthogonal_init_and_zero_biases(model):
    policy = GRUPPO(make_venv(num_envs=1), n_steps=50, seed=7).policy
    for gru in (policy.nutrient_gru, policy.food_gru):
        for name, p in gru.named_parameters():
            if name.startswith("bias"):
                assert th.count_nonzero(p) == 0
            else:
                for k in range(3):  # reset, update and new gate blocks
                    _assert_orthogonal(p[k * 128 : (k + 1) * 128], 1.0)
    for layer, gain in (
        (policy.actor_head[0], math.sqrt(2)),
        (policy.actor_head[2], 0.01),
        (policy.critic_head[0], math.sqrt(2)),
        (policy.critic_head[2], 1.0),
    ):
        _assert_orthogonal(layer.weight, gain)
        assert th.count_nonzero(layer.bias) == 0


def test_n_steps_must_be_a_multiple_of_the_episode_length():
    with pytest.raises(ValueError, match="multiple of sequence_length=50"):
        GRUPPO(make_venv(num_envs=1), n_steps=64)


# ---- memory (acting / evaluation) ----


def test_earlier_observations_change_current_action_probabilities(model):
    start = np.ones(1, dtype=bool)
    current = obs_vec((0.3, 0.3, 0.3), food=4)[None]
    _, state_a = model.predict(obs_vec((0.0, 0.0, 0.0), food=1)[None], episode_start=start)
    _, state_b = model.predict(obs_vec((2.0, 1.5, 1.0), food=7)[None], episode_start=start)
    p_a, next_a = gru_action_probabilities(model, current, state_a)
    p_b, next_b = gru_action_probabilities(model, current, state_b)
    # same current observation, different histories: different hidden states and probabilities
    assert np.abs(next_a[0] - next_b[0]).max() > 1e-2 and np.abs(next_a[1] - next_b[1]).max() > 1e-2
    assert np.abs(p_a - p_b).max() > 1e-6  # the untrained policy output is small (gain 0.01)
    # with a policy output of ordinary scale the difference is large
    policy = GRUPPO(make_venv(num_envs=1), n_steps=50, seed=0).policy
    th.nn.init.orthogonal_(policy.actor_head[2].weight, gain=5.0)
    ps = []
    for first in (obs_vec((0.0, 0.0, 0.0), 1), obs_vec((2.0, 1.5, 1.0), 7)):
        _, state = policy.predict(first[None], episode_start=start)
        with th.no_grad():
            dist, _ = policy.get_distribution(th.tensor(current), tuple(th.tensor(s) for s in state), th.zeros(1))
        ps.append(dist.distribution.probs.numpy())
    assert np.abs(ps[0] - ps[1]).max() > 1e-3


def test_episode_start_resets_to_initial_behaviour(model):
    rng = np.random.default_rng(0)
    first = rng.normal(size=(3, OBS_DIM)).astype(np.float32)
    p0, s0 = gru_action_probabilities(model, first)  # state=None: fresh episode
    state = s0
    for _ in range(5):
        _, state = gru_action_probabilities(model, rng.normal(size=(3, OBS_DIM)).astype(np.float32), state)
    p_carried, _ = gru_action_probabilities(model, first, state)
    assert np.abs(p_carried - p0).max() > 0
    p_reset, s_reset = gru_action_probabilities(model, first, state, episode_start=np.ones(3, dtype=bool))
    np.testing.assert_array_equal(p_reset, p0)
    for a, b in zip(s_reset, s0):
        np.testing.assert_array_equal(a, b)
    # per-env reset: only env 1 starts an episode
    p_mixed, _ = gru_action_probabilities(model, first, state, episode_start=np.array([False, True, False]))
    np.testing.assert_array_equal(p_mixed[1], p0[1])
    np.testing.assert_array_equal(p_mixed[[0, 2]], p_carried[[0, 2]])
    # predict() follows the same convention and returns (1, n_envs, 128) states
    actions, st = model.predict(first, state=state, episode_start=np.ones(3, dtype=bool), deterministic=True)
    assert actions.shape == (3,) and [s.shape for s in st] == [(1, 3, 128), (1, 3, 128)]
    np.testing.assert_array_equal(actions, p0.argmax(axis=1))


def test_step_by_step_acting_equals_sequence_evaluation(model):
    """Carrying the state one step at a time (acting) gives what training recomputes over the
    whole sequence, including a mid-sequence episode start."""
    policy = model.policy
    rng = np.random.default_rng(1)
    B, T = 3, 12
    obs = th.tensor(rng.normal(size=(B, T, OBS_DIM)).astype(np.float32))
    actions = th.tensor(rng.integers(0, 2, size=(B, T)))
    starts = th.zeros(B, T)
    starts[:, 0] = 1.0
    starts[1, 7] = 1.0  # env 1 starts a new episode at step 7
    init = tuple(th.tensor(rng.normal(size=(1, B, 128)).astype(np.float32)) for _ in range(2))
    with th.no_grad():
        values, log_prob, _ = policy.evaluate_actions(obs, actions, init, starts)
        state = init
        for t in range(T):
            dist, new_state = policy.get_distribution(obs[:, t], state, starts[:, t])
            v = policy.predict_values(obs[:, t], state, starts[:, t])
            th.testing.assert_close(dist.log_prob(actions[:, t]), log_prob.reshape(B, T)[:, t], atol=1e-5, rtol=0)
            th.testing.assert_close(v[:, 0], values.reshape(B, T)[:, t], atol=1e-5, rtol=0)
            state = new_state
        # fast path (no start inside the sequences) equals the step-by-step path
        starts2 = th.zeros(B, T)
        starts2[:, 0] = 1.0
        fast, _ = policy.unroll(obs, init, starts2)
        starts3 = starts2.clone()
        starts3[2, 5] = 1.0
        slow, _ = policy.unroll(obs, init, starts3)
        th.testing.assert_close(fast[:2], slow[:2], atol=1e-6, rtol=0)
        th.testing.assert_close(fast[2, :5], slow[2, :5], atol=1e-6, rtol=0)


def test_rollout_carries_the_state_and_the_buffer_serves_whole_episodes():
    model = GRUPPO(make_venv(num_envs=2), n_steps=100, seed=3)
    model._setup_learn(100 * 2)
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    buf = model.rollout_buffer
    assert isinstance(buf, RecurrentRolloutBuffer) and buf.full
    # episode starts exactly at steps 0 and 50 of each env
    np.testing.assert_array_equal(np.flatnonzero(buf.episode_starts[:, 0]), [0, 50])
    # the state stored at step t (carried into t) is the GRU state after steps start..t-1 of the episode
    policy = model.policy
    obs = th.tensor(buf.observations[:50].swapaxes(0, 1))  # (n_envs, 50, obs_dim), episode 0
    starts = th.zeros(2, 50)
    starts[:, 0] = 1.0
    with th.no_grad():
        feats, _ = policy.unroll(obs, policy.initial_state(2), starts)
    stored = th.tensor(buf.hidden_states[1:50].swapaxes(0, 1))  # (n_envs, 49, 2, 128)
    th.testing.assert_close(stored[..., 0, :], feats[:, :49, :128], atol=1e-5, rtol=0)
    th.testing.assert_close(stored[..., 1, :], feats[:, :49, 128:], atol=1e-5, rtol=0)
    assert th.count_nonzero(stored) > 0
    # minibatches are whole 50-step sequences starting at episode starts
    batches = list(buf.get(1))
    assert len(batches) == buf.n_sequences == 4
    for b in batches:
        assert isinstance(b, RecurrentRolloutBufferSamples)
        assert b.observations.shape == (1, 50, OBS_DIM) and b.actions.shape == (1, 50)
        assert b.old_log_prob.shape == (50,) and b.advantages.shape == (50,)
        np.testing.assert_array_equal(b.episode_starts.numpy(), np.eye(1, 50))


def test_to_sequences_keeps_each_envs_time_line():
    import gymnasium as gym

    buf = RecurrentRolloutBuffer(
        100, gym.spaces.Box(-1, 1, (13,)), gym.spaces.Discrete(2), n_envs=3, sequence_length=50
    )
    arr = (1000 * np.arange(3)[None, :] + np.arange(100)[:, None]).astype(np.float32)  # value = 1000 * env + step
    seq = buf.to_sequences(arr)
    assert seq.shape == (6, 50)
    for s in range(6):
        chunk, env = divmod(s, 3)
        np.testing.assert_array_equal(seq[s], 1000 * env + 50 * chunk + np.arange(50))


# ---- training: gradient through time ----


def test_gradient_flows_through_time():
    model = GRUPPO(make_venv(num_envs=1), n_steps=50, seed=0)
    policy = model.policy
    obs = th.randn(2, 50, OBS_DIM, requires_grad=True)
    actions = th.randint(0, 2, (2, 50))
    starts = th.zeros(2, 50)
    starts[:, 0] = 1.0
    values, log_prob, _ = policy.evaluate_actions(obs, actions, policy.initial_state(2), starts)
    t = 30
    (log_prob.reshape(2, 50)[:, t].sum() + values.reshape(2, 50)[:, t].sum()).backward()
    grad = obs.grad.abs().sum(dim=(0, 2))  # per step
    assert grad[0] > 0 and grad[t - 1] > 0 and grad[t] > 0
    assert th.count_nonzero(grad[t + 1 :]) == 0  # causal


def test_ppo_loss_at_a_later_step_depends_on_the_first_step():
    """The actual training loss, on buffer data: with only step 30 carrying an advantage (and no
    value/entropy terms), d loss / d obs[step 0] is non-zero: the gradient goes through time."""
    model = GRUPPO(make_venv(num_envs=1), n_steps=50, seed=0, normalize_advantage=False, vf_coef=0.0, ent_coef=0.0)
    model._setup_learn(50)
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    (data,) = list(model.rollout_buffer.get(1))
    obs = data.observations.clone().requires_grad_(True)
    adv = th.zeros_like(data.advantages)
    adv[30] = 1.0
    data = data._replace(observations=obs, advantages=adv)
    loss, _ = model.ppo_loss(data, clip_range=0.2)
    loss.backward()
    grad = obs.grad[0].abs().sum(dim=1)
    assert grad[0] > 0 and grad[29] > 0 and grad[30] > 0
    assert th.count_nonzero(grad[31:]) == 0


def test_train_uses_whole_episode_sequences(monkeypatch):
    model = GRUPPO(make_venv(num_envs=2), n_steps=100, seed=0, n_epochs=2, batch_size=64)
    shapes = []
    original = model.policy.evaluate_actions

    def spy(obs, actions, state, starts):
        shapes.append((tuple(obs.shape), tuple(starts[:, 0].tolist()), state[0].shape))
        return original(obs, actions, state, starts)

    monkeypatch.setattr(model.policy, "evaluate_actions", spy)
    model.learn(200)
    assert model.sequences_per_batch == 1
    assert len(shapes) == 2 * 4  # 2 epochs x 4 episodes, one episode per minibatch
    assert all(s == ((1, 50, OBS_DIM), (1.0,), (1, 1, 128)) for s in shapes)
    assert GRUPPO(make_venv(num_envs=2), n_steps=100, batch_size=64 * 50).sequences_per_batch == 64


# ---- learning, save/load, seeding ----


@pytest.mark.parametrize("regime", ["run0", "run6"])
def test_learns_a_few_episodes(regime):
    venv = make_venv(regime, num_envs=4)
    model = GRUPPO(venv, n_steps=100, n_epochs=2, seed=0)
    before = th.nn.utils.parameters_to_vector(model.policy.parameters()).detach().clone()
    model.learn(2 * 100 * 4)  # two rollouts of 2 days x 4 envs
    assert model.num_timesteps == 800
    after = th.nn.utils.parameters_to_vector(model.policy.parameters()).detach()
    assert not th.equal(before, after) and th.isfinite(after).all()
    logged = model.logger.name_to_value
    for key in ("train/policy_gradient_loss", "train/value_loss", "train/entropy", "train/approx_kl"):
        assert np.isfinite(logged[key])
    assert 0.0 < logged["train/entropy"] <= math.log(2) + 1e-6
    # the env is left at an episode boundary and the carried state matches the env count
    assert model._last_episode_starts.all() and model._last_gru_states[0].shape == (1, 4, 128)


def test_single_gym_env():
    model = GRUPPO(NutriRLEnv("run6"), n_steps=50, n_epochs=1, seed=0)
    model.learn(100)
    assert model.num_timesteps == 100


def _rollout_actions(m: GRUPPO, observations: np.ndarray) -> list[np.ndarray]:
    state, start, out = None, np.ones(observations.shape[1], dtype=bool), []
    for obs in observations:
        action, state = m.predict(obs, state=state, episode_start=start, deterministic=True)
        out.append(action)
        start = np.zeros_like(start)
    return out


def test_save_load_round_trip(tmp_path):
    venv = make_venv(num_envs=2)
    model = GRUPPO(venv, n_steps=50, n_epochs=2, seed=4)
    model.learn(200)
    model.save(tmp_path / "gru.zip")
    loaded = GRUPPO.load(tmp_path / "gru.zip", env=venv)
    assert loaded.n_steps == 50 and loaded.sequence_length == 50 and loaded.hidden_size == 128
    for p, q in zip(model.policy.state_dict().values(), loaded.policy.state_dict().values()):
        assert th.equal(p, q)
    obs_seq = np.random.default_rng(0).normal(size=(20, 8, OBS_DIM)).astype(np.float32)
    for a, b in zip(_rollout_actions(model, obs_seq), _rollout_actions(loaded, obs_seq)):
        np.testing.assert_array_equal(a, b)
    p0, _ = gru_action_probabilities(model, obs_seq[0])
    p1, _ = gru_action_probabilities(loaded, obs_seq[0])
    np.testing.assert_array_equal(p0, p1)
    loaded.learn(100, reset_num_timesteps=False)  # keeps training after loading
    # loading without an env is enough to predict
    GRUPPO.load(tmp_path / "gru.zip").predict(obs_seq[0], deterministic=True)


def test_same_seed_same_parameters():
    def run(seed):
        m = GRUPPO(make_venv(num_envs=2), n_steps=50, n_epochs=2, seed=seed)
        m.learn(200)
        return th.nn.utils.parameters_to_vector(m.policy.parameters()).detach().clone()

    a, b = run(11), run(11)
    assert th.equal(a, b)
    assert not th.equal(a, run(12))
