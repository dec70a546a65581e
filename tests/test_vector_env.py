"""The batched env equals N single envs; autoreset modes; the SB3 adapter."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from nutribench.config import EnvConfig, load_env_config
from nutribench.config.models import Regime
from nutribench.env import NutriRLEnv, NutriRLVectorEnv
from nutribench.env.sb3 import NutriRLSB3VecEnv


def with_clock(name: str) -> EnvConfig:
    """The shipped regime ``name`` with ``observe_clock = true``."""
    cfg = load_env_config(name)
    regime = Regime.model_validate({**cfg.regime.model_dump(mode="json"), "observe_clock": True})
    return EnvConfig(regime=regime, catalog=cfg.catalog, reward=cfg.reward)


@pytest.mark.parametrize("regime", ["run0", "run2", "run5", "run6", "run3+clock", "run6+clock"])
def test_vector_env_equals_single_envs(regime):
    if regime.endswith("+clock"):
        regime = with_clock(regime.removesuffix("+clock"))
    n, rng = 6, np.random.default_rng(11)
    venv = NutriRLVectorEnv(n, regime=regime)
    H = venv.horizon
    foods = rng.integers(0, 10, size=(n, H))
    actions = rng.integers(0, 2, size=(H, n))
    singles = [NutriRLEnv(regime) for _ in range(n)]
    vobs, vinfo = venv.reset(options={"foods": foods})
    sobs = np.stack([e.reset(options={"foods": foods[j]})[0] for j, e in enumerate(singles)])
    np.testing.assert_array_equal(vobs, sobs)
    for t in range(H):
        vobs, vr, vterm, vtrunc, vinfo = venv.step(actions[t])
        res = [e.step(int(actions[t, j])) for j, e in enumerate(singles)]
        np.testing.assert_array_equal(vobs, np.stack([x[0] for x in res]))
        np.testing.assert_allclose(vr, [x[1] for x in res], rtol=0, atol=1e-12)
        assert vtrunc.tolist() == [x[3] for x in res]
        assert vterm.tolist() == [x[2] for x in res]
        for key in (
            "state",
            "distance",
            "overshoot",
            "foods_consumed",
            "reward_progress",
            "reward_comfort",
            "reward_overshoot",
        ):
            np.testing.assert_allclose(
                np.asarray(vinfo[key], dtype=float),
                np.stack([np.asarray(x[4][key], dtype=float) for x in res]),
                atol=1e-12,
            )
        np.testing.assert_allclose(
            venv.pending_by_horizon(), np.stack([e.pending_by_horizon() for e in singles]), atol=1e-12
        )


def test_next_step_autoreset():
    venv = NutriRLVectorEnv(4, regime="run1")
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    venv.reset(seed=0)
    for _ in range(venv.horizon):
        obs, r, term, trunc, info = venv.step(np.ones(4, dtype=int))
    assert trunc.all()
    obs, r, term, trunc, info = venv.step(np.ones(4, dtype=int))  # the reset step
    assert np.all(r == 0) and not trunc.any() and np.all(obs[:, :3] == 0) and info == {}
    obs, r, term, trunc, info = venv.step(np.ones(4, dtype=int))
    assert np.all(info["foods_consumed"] == 1)


def test_same_step_autoreset():
    venv = NutriRLVectorEnv(4, regime="run0", autoreset_mode="SameStep")
    venv.reset(seed=0)
    for _ in range(venv.horizon):
        obs, r, term, trunc, info = venv.step(np.ones(4, dtype=int))
    assert trunc.all()
    assert np.all(obs[:, :3] == 0) and np.all(obs[:, 3:].sum(axis=1) == 1)  # first obs of the next day
    assert np.all(info["final_obs"][:, 3:] == 0) and np.all(info["final_obs"][:, :3] > 0)
    _, _, _, _, info = venv.step(np.zeros(4, dtype=int))
    assert np.all(info["foods_consumed"] == 0)


def test_vector_seeding_reproducible():
    a = NutriRLVectorEnv(3, regime="run0")
    b = NutriRLVectorEnv(3, regime="run0")
    assert np.array_equal(a.reset(seed=5)[0], b.reset(seed=5)[0])
    assert np.array_equal(a.offered, b.offered)
    c = NutriRLVectorEnv(3, regime="run0")
    c.reset(seed=6)
    assert not np.array_equal(a._foods, c._foods)


def test_sb3_adapter_reports_days_as_episodes():
    venv = NutriRLSB3VecEnv(num_envs=3, regime="run3")
    venv.seed(0)
    obs = venv.reset()
    assert obs.shape == (3, 13)
    for t in range(50):
        obs, rewards, dones, infos = venv.step(np.ones(3, dtype=int))
        assert rewards.dtype == np.float32
        assert dones.all() == (t == 49)
    assert all("terminal_observation" in i and "TimeLimit.truncated" not in i for i in infos)
    assert venv.last_info["foods_consumed"].tolist() == [50, 50, 50]


def test_sb3_ppo_learns_a_little_on_the_adapter():
    from stable_baselines3 import PPO

    venv = NutriRLSB3VecEnv(num_envs=2, regime="run0")
    model = PPO("MlpPolicy", venv, n_steps=50, batch_size=50, n_epochs=1, seed=0, device="cpu")
    model.learn(200)
    assert model.num_timesteps == 200


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_the_last_steps_info_survives_the_next_days_reset(mode):
    """The day's last info (and SAME_STEP's final_info) keeps its own copy of the distance,
    not a reference to the env's array, which the next day's reset sets back to 3.0 in place."""
    env = NutriRLVectorEnv(4, regime="run0", autoreset_mode=mode)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(50):
        _, _, _, truncated, info = env.step(rng.integers(0, 2, size=4))
    assert truncated.all()
    env.step(np.zeros(4, dtype=int))  # NEXT_STEP: this is the reset step; SAME_STEP: day 2, step 1
    for i in (info, info.get("final_info", info)):
        expected = np.abs(np.asarray(i["state"]) - 1.0).sum(axis=1)
        np.testing.assert_allclose(i["distance"], expected)
        assert not np.allclose(i["distance"], 3.0)


def test_sb3_adapter_passes_each_envs_info_through():
    """VecMonitor(info_keywords=...) gets the env's info per env."""
    from stable_baselines3.common.vec_env import VecMonitor

    base = NutriRLSB3VecEnv(num_envs=3, regime="run0")
    base.seed(0)
    venv = VecMonitor(base, info_keywords=("foods_consumed", "distance"))
    venv.reset()
    for t in range(50):
        _, _, dones, infos = venv.step(np.array([1, 0, int(t % 10 == 0)]))
        assert [int(i["step"]) for i in infos] == [t + 1] * 3
    assert dones.all()
    assert [i["episode"]["foods_consumed"] for i in infos] == [50, 0, 5]
    for i in infos:
        np.testing.assert_allclose(i["episode"]["distance"], np.abs(i["state"] - 1.0).sum())
        assert i["terminal_observation"].shape == (13,)


def test_the_clock_is_the_step_of_the_day_over_the_horizon():
    cfg = with_clock("run3")
    env, venv = NutriRLEnv(cfg), NutriRLVectorEnv(3, regime=cfg)
    H = env.horizon
    assert env.observation_space.shape == venv.single_observation_space.shape == (14,)
    assert env.observation_space.high[-1] == 1.0
    obs, _ = env.reset(seed=1)
    vobs, _ = venv.reset(seed=1)
    assert obs[-1] == 0.0 and np.all(vobs[:, -1] == 0.0)
    rng = np.random.default_rng(0)
    for t in range(1, H + 1):
        obs, _, _, trunc, info = env.step(int(rng.integers(0, 2)))
        vobs, *_ = venv.step(rng.integers(0, 2, size=3))
        assert obs[-1] == np.float32(t / H) and np.all(vobs[:, -1] == np.float32(t / H)), t
        assert env.observation_space.contains(obs) and info["step"] == t
        assert obs[3:-1].sum() == (0.0 if t == H else 1.0)  # the food part still one-hot, then empty
    assert trunc and obs[-1] == 1.0
    plain = NutriRLEnv("run3")
    assert plain.observation_space.shape == (13,) and plain.reset(seed=1)[0].shape == (13,)


def test_the_sb3_adapter_and_the_batched_engine_see_the_clock():
    from nutribench.engine.envs import AgentEnvs

    venv = NutriRLSB3VecEnv(num_envs=2, regime=with_clock("run6"))
    assert venv.observation_space.shape == (14,)
    venv.seed(0)
    obs = venv.reset()
    assert np.all(obs[:, -1] == 0.0)
    for t in range(1, 51):
        obs, _, dones, infos = venv.step(np.ones(2, dtype=int))
        if t < 50:
            assert np.all(obs[:, -1] == np.float32(t / 50))
    assert dones.all() and np.all(obs[:, -1] == 0.0)  # the next day's first observation
    assert all(i["terminal_observation"][-1] == 1.0 for i in infos)
    envs = AgentEnvs([(with_clock("run3"), 0), (with_clock("run6"), 1)], normalize_obs=True)
    raw = envs.new_days()
    assert raw.shape == (2, 14) and np.all(raw[:, -1] == 0.0)
    raw, _, done = envs.step(np.ones(2, dtype=np.int64))
    assert np.all(raw[:, -1] == np.float32(1 / 50)) and not done
    with pytest.raises(ValueError, match="one observation size"):  # the clock is another observation
        AgentEnvs([(with_clock("run3"), 0), ("run3", 1)], normalize_obs=False)
