"""The observation ladder (issue 38): levels 1-4 as regime options, equal in the single env, the
vector env, the SB3 adapter and the batched engine; the default observation and the stored
hashes unchanged; honest bounds; the level-4 observation is the full state; short trainings."""

from __future__ import annotations

import hashlib
import warnings
from pathlib import Path

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from nutribench.config import ConfigError, EnvConfig, load_env_config
from nutribench.config.generate import regime_to_toml
from nutribench.config.models import Regime
from nutribench.engine.envs import AgentEnvs
from nutribench.env import NutriRLEnv, NutriRLVectorEnv
from nutribench.env.sb3 import NutriRLSB3VecEnv

LADDER = Path(__file__).resolve().parents[1] / "reports" / "ladder"
LEVELS = (1, 2, 3, 4)
FLAGS = ("observe_clock", "observe_pending", "observe_latent")


def at_level(name: str, level: int) -> EnvConfig:
    """The shipped regime ``name`` with the observation options of ``level``."""
    cfg = load_env_config(name)
    flags = {flag: level > rung for rung, flag in enumerate(FLAGS, start=1)}
    regime = Regime.model_validate({**cfg.regime.model_dump(mode="json"), **flags})
    return EnvConfig(regime=regime, catalog=cfg.catalog, reward=cfg.reward)


def fingerprint(regime) -> str:
    """sha256 of the observation space's bounds and one day's observations (seed 38, random actions)."""
    h = hashlib.sha256()
    env = NutriRLEnv(regime)
    sp = env.observation_space
    h.update(repr((sp.shape, str(sp.dtype))).encode())
    h.update(sp.low.tobytes())
    h.update(sp.high.tobytes())
    rng = np.random.default_rng(38)
    obs, _ = env.reset(seed=38)
    h.update(obs.tobytes())
    for _ in range(env.horizon):
        obs, *_ = env.step(int(rng.integers(0, 2)))
        h.update(obs.tobytes())
    return h.hexdigest()


#: Made by the code before the ladder existed (commit 6495241): the paper's observation and the
#: sensitivity study's clock observation must not move.
STORED_FINGERPRINTS = {
    "run0": "1c4f004f1c69b08029e6d09f41e5039d8bd1673fb8aea6e2f6e9e7202c3e3471",
    "run3": "1177e214d99a52b5f6b348a816b70ad95926a2cd05dd6e85c6623d4a731d7867",
    "run6": "b67f3fcd397f21dfd949b22ad33f13dc2019fd6da11379c0ab92ca7d14ffdacc",
    "clock run6": "5a6bcfa4fd71c329abe261596a6c6845b312d88f30157aab16680402968bf158",
}
#: reports/sensitivity/regimes_clock's hashes, as its archives store them.
CLOCK_SHA256 = {
    "run0": "79882162860e0f33278f1d2f89786d30bd875ae97bf161b961ef2fa356ac522a",
    "run3": "60be3372de4765cae1afb57482e51557b37ad191843697c1ab6874af9525131c",
    "run6": "9ca649d94938e6950ca853d4d670cdbca69aefd33516a47da8194a7dce6f4c67",
}


def test_the_default_and_the_clock_observation_are_those_of_before():
    for name in ("run0", "run3", "run6"):
        assert fingerprint(name) == STORED_FINGERPRINTS[name]
        assert load_env_config(name).regime.observation_level == 1
    clock = LADDER.parent / "sensitivity" / "regimes_clock"
    assert fingerprint(clock / "run6.toml") == STORED_FINGERPRINTS["clock run6"]
    for name, sha in CLOCK_SHA256.items():
        assert load_env_config(clock / f"{name}.toml").sha256 == sha


def test_options_written_out_off_keep_the_hash_and_each_rung_changes_it(tmp_path):
    cfg = load_env_config("run3")
    for name in ("foods.toml", "reward.toml"):
        (tmp_path / name).write_text((cfg.path.parent / name).read_text())
    off = "\n".join(f"{flag} = false" for flag in FLAGS)
    text = cfg.path.read_text().replace('reward = "reward.toml"', f'reward = "reward.toml"\n{off}')
    (tmp_path / "run3.toml").write_text(text)
    assert load_env_config(tmp_path / "run3.toml").sha256 == cfg.sha256
    hashes = {at_level("run3", k).sha256 for k in LEVELS}
    assert len(hashes) == 4 and cfg.sha256 in hashes
    top = at_level("run3", 4)
    assert {f: top.content()["regime"][f] for f in FLAGS} == dict.fromkeys(FLAGS, True)
    (tmp_path / "run3.toml").write_text(regime_to_toml(top.regime))
    again = load_env_config(tmp_path / "run3.toml")
    assert again.sha256 == top.sha256 and again.regime.observation_level == 4  # the writer keeps every rung


@pytest.mark.parametrize(
    ("upper", "lower"), [("observe_pending", "observe_clock"), ("observe_latent", "observe_pending")]
)
def test_a_rung_needs_the_ones_below(tmp_path, upper, lower):
    cfg = load_env_config("run3")
    for name in ("foods.toml", "reward.toml"):
        (tmp_path / name).write_text((cfg.path.parent / name).read_text())
    flags = {"observe_clock": True, "observe_pending": True, "observe_latent": True, lower: False}
    on = "\n".join(f"{f} = {str(v).lower()}" for f, v in flags.items() if FLAGS.index(f) <= FLAGS.index(upper))
    (tmp_path / "run3.toml").write_text(
        cfg.path.read_text().replace('reward = "reward.toml"', f'reward = "reward.toml"\n{on}')
    )
    with pytest.raises(ConfigError, match=f"run3.toml: .*{upper} = true needs {lower} = true"):
        load_env_config(tmp_path / "run3.toml")


@pytest.mark.parametrize("level", (2, 3, 4))
def test_the_study_s_variant_files_change_only_the_observation(level):
    for name in ("run0", "run3", "run6"):
        shipped, variant = load_env_config(name), load_env_config(LADDER / f"regimes_obs{level}" / f"{name}.toml")
        assert variant.regime.observation_level == level and variant.version == 380 + level
        assert variant.regime.foods == shipped.regime.foods and variant.regime.seed == shipped.regime.seed
        assert variant.catalog == shipped.catalog and variant.reward == shipped.reward
        assert variant.sha256 != shipped.sha256


@pytest.mark.parametrize("level", LEVELS)
def test_layout_sizes_and_bounds(level):
    env = NutriRLEnv(at_level("run6", level))
    sizes = {1: 13, 2: 14, 3: 17, 4: 13 + 1 + 3 + 3 * 49 + 3}
    assert env.observation_space.shape == (sizes[level],) and env.dyn.observation_level == level
    low, high = env.observation_space.low, env.observation_space.high
    cols = env.dyn.columns
    assert (
        list(cols)[: 1 + level + (level == 4)]
        == ["state", "food", "clock", "pending", "schedule", "target"][: 1 + level + (level == 4)]
    )
    assert np.all(low == 0)
    if level == 4:
        assert np.all(high[cols["target"]] == 1) and env.dyn.window == env.horizon - 1


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("name", ["run0", "run1", "run3", "run6"])
def test_observations_stay_within_the_bounds_when_eating_everything(name, level):
    """Eating every food offered (the largest amounts a day can hold), the richest food included."""
    env = NutriRLEnv(at_level(name, level))
    for foods in (np.zeros(env.horizon, dtype=np.int64) + int(env.masses.sum(axis=1).argmax()), None):
        obs, _ = env.reset(seed=3, options=None if foods is None else {"foods": foods})
        assert env.observation_space.contains(obs)
        for _ in range(env.horizon):
            obs, *_ = env.step(1)
            assert env.observation_space.contains(obs), obs


@pytest.mark.parametrize("level", LEVELS)
def test_check_env_passes_at_every_level(level):
    env = NutriRLEnv(at_level("run3", level))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning from Gymnasium's checks either
        check_env(env, skip_render_check=True)
    sb3_check_env(NutriRLEnv(at_level("run3", level)), warn=True)


def _batched_engine_days(cfgs: list[EnvConfig], actions: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The batched engine's raw observations ``(H + 1, K, dim)`` playing ``actions (H, K)``, and its days."""
    envs = AgentEnvs([(c, 7 + j) for j, c in enumerate(cfgs)], normalize_obs=False)
    seen = [envs.new_days()]
    for a in actions:
        seen.append(envs.step(a)[0])
    return np.stack(seen), envs.days_drawn[-1]


@pytest.mark.parametrize("level", LEVELS)
def test_single_vector_sb3_and_batched_engine_observe_the_same(level):
    cfgs = [at_level(name, level) for name in ("run0", "run3", "run6", "run6")]
    H, k = 50, len(cfgs)
    actions = np.random.default_rng(level).integers(0, 2, size=(H, k))
    engine, foods = _batched_engine_days(cfgs, actions)
    singles = [NutriRLEnv(c) for c in cfgs]
    single = [np.stack([e.reset(options={"foods": foods[j]})[0] for j, e in enumerate(singles)])]
    for t in range(H):
        single.append(np.stack([e.step(int(actions[t, j]))[0] for j, e in enumerate(singles)]))
    single = np.stack(single)
    np.testing.assert_array_equal(engine, single)
    assert single.shape == (H + 1, k, singles[0].observation_space.shape[0])
    for j, cfg in enumerate(cfgs):  # one vector env per regime, and the SB3 adapter over it
        venv, sb3 = NutriRLVectorEnv(2, regime=cfg), NutriRLSB3VecEnv(num_envs=2, regime=cfg)
        both = np.stack([foods[j], foods[j]])
        sb3.set_options({"foods": both})
        np.testing.assert_array_equal(venv.reset(options={"foods": both})[0][1], single[0, j])
        np.testing.assert_array_equal(sb3.reset()[1], single[0, j])
        for t in range(H):
            a = np.full(2, actions[t, j])
            np.testing.assert_array_equal(venv.step(a)[0][0], single[t + 1, j])
            obs, _, done, infos = sb3.step(a)
            last = infos[0]["terminal_observation"] if done[0] else obs[0]
            np.testing.assert_array_equal(last, single[t + 1, j])


@pytest.mark.parametrize("name", ["run3", "run6"])
def test_the_rungs_hold_what_they_say(name):
    env = NutriRLEnv(at_level(name, 4))
    cols, H = env.dyn.columns, env.horizon
    obs, _ = env.reset(seed=5)
    rng = np.random.default_rng(5)
    for t in range(1, H + 1):
        obs, *_ = env.step(int(rng.random() < 0.3))
        assert obs[cols["clock"]][0] == np.float32(t / H)
        np.testing.assert_allclose(obs[cols["pending"]], env.pending_by_horizon(), rtol=1e-6)
        schedule = obs[cols["schedule"]].reshape(H - 1, 3)
        due = env._pending[t:]  # row u: what arrives at step u + 1
        np.testing.assert_array_equal(schedule[: H - t], due.astype(np.float32))
        assert np.all(schedule[H - t :] == 0)
        np.testing.assert_allclose(schedule.sum(axis=0), obs[cols["pending"]], rtol=1e-5, atol=1e-6)
        assert np.all(obs[cols["target"]] == 1)
    assert obs[cols["pending"]].sum() == 0  # after the day nothing more can arrive


@pytest.mark.parametrize("name", ["run3", "run6"])
def test_the_level_4_observation_determines_the_rest_of_the_day(name):
    """A fresh env put in the state read off a level-4 observation (and nothing else) earns the
    same rewards as the original over the rest of the day, for the same foods and actions."""
    cfg = at_level(name, 4)
    env, rng = NutriRLEnv(cfg), np.random.default_rng(9)
    obs, _ = env.reset(seed=9)
    t0 = 20
    for _ in range(t0):
        obs, *_ = env.step(int(rng.random() < 0.3))
    cols, H = env.dyn.columns, env.horizon
    copy = NutriRLEnv(cfg)
    copy.reset(options={"foods": env._foods.copy()})
    t = int(round(float(obs[cols["clock"]][0]) * H))
    s = obs[cols["state"]].astype(np.float64)
    copy._t, copy._s = t, s.tolist()
    copy._d = float(np.abs(s - obs[cols["target"]]).sum())
    copy._pending[t:] = obs[cols["schedule"]].reshape(H - 1, 3)[: H - t]
    assert t == t0 and copy.offered == int(np.argmax(obs[cols["food"]]))
    for _ in range(H - t0):
        a = int(rng.random() < 0.3)
        r1, r2 = env.step(a)[1], copy.step(a)[1]
        assert r2 == pytest.approx(r1, abs=1e-5)


@pytest.mark.parametrize("level", LEVELS)
def test_a_short_training_at_every_level_through_both_engines(level):
    from nutribench.agents import eval_food_streams, evaluate
    from nutribench.agents.api import train
    from nutribench.agents.config import load_agent_config
    from nutribench.engine.train import train_batched
    from tests.conftest import two_day_rollouts

    cfg = at_level("run3", level)
    # at the top of the ladder, one update each: rollouts of 2 days (n_steps 100, minibatches of
    # one whole day) instead of the files' 10, so that 3 days hold exactly one update
    days = 3 if level == 4 else 2
    for name in ("ppo", "gru_ppo"):
        algo = load_agent_config(name)
        if level == 4:
            algo = two_day_rollouts(algo)
        sb3 = train(cfg, algo, 0, days)
        batched = train_batched([(cfg, 0), (at_level("run6", level), 1)], algo, days)
        assert len(sb3.train_episodes) == days and all(len(b.train_episodes) == days for b in batched)
        for agent in (sb3, batched[0]):
            assert agent.provenance["regime_sha256"] == cfg.sha256
            result = evaluate(agent, cfg, eval_food_streams(cfg, 0, 2))
            assert len(result.episodes) == 2 and all(np.isfinite(e["return"]) for e in result.episodes)
        if level == 4:
            assert len(sb3.diagnostics) == 1 and len(batched[0].diagnostics) == 1  # one update each
