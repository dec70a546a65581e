"""GRU-PPO's ``memory = false``: the state zeroed before every step in both engines, in acting,
training and every evaluation (during training, on test days, a saved and loaded agent); and
the option enters a config's content only when false, so every GRU-PPO file written before it
keeps its hash. (That it trains the same runs as ``reports/gru_memory/without_memory.py``'s
patched agent is that finished study's own check: ``python -m pytest reports/gru_memory``.)"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch as th

from nutribench.agents.api import TrainedAgent, eval_food_streams, evaluate, validation_food_streams
from nutribench.agents.config import (
    agent_config_content,
    agent_config_sha256,
    agent_config_to_toml,
    load_agent_config,
    parse_agent_config,
)
from nutribench.agents.gru_ppo import GRUPPO
from nutribench.config.loading import read_toml
from nutribench.engine.gru_ppo import RecurrentActor, StackedGRUActorCritic
from nutribench.engine.train import train_batched
from nutribench.env.sb3 import NutriRLSB3VecEnv
from tests.policy_probes import gru_action_entropy, gru_action_probabilities

ROOT = Path(__file__).resolve().parents[1]
NOMEM = ROOT / "reports" / "ladder" / "agents" / "gru_ppo_nomem.toml"
#: the content hash of the shipped gru_ppo.toml v2, as the paper grid's archive recorded it
GRU_PPO_V2_SHA256 = "c6d9fded8856d8a9a0ad03215ceec226fced2ae052a3e8bc84782be2b461618f"
#: every gru_ppo file with memory, by version: v2 (the paper grid's, copied by the studies) and
#: v3 (the shipped file since its description says what the algorithm is; settings unchanged)
GRU_PPO_SHA256 = {2: GRU_PPO_V2_SHA256, 3: "c2cfe14bf0913c8dcdaf801eaf65b387feb03ea9497c5bf1141f4484f6d08c2f"}


def _nomem():
    return load_agent_config(NOMEM)


def _gru_ppo_files() -> list[Path]:
    files = [*ROOT.glob("regimes/agents/*.toml"), *ROOT.glob("reports/*/agents*/*.toml")]
    return sorted(p for p in files if read_toml(p).get("algo") == "gru_ppo")


# --------------------------------------------------------------------------- the config and its hash
def test_every_gru_ppo_file_keeps_its_hash_and_memory_enters_the_content_only_when_off() -> None:
    meta = json.loads(np.load(ROOT / "reports/paper/data/gru_ppo.npz", allow_pickle=False)["meta"].tobytes())
    (archived,) = [c for c in meta["agent_configs"] if c["name"] == "gru_ppo"]
    assert archived["sha256"] == GRU_PPO_V2_SHA256 and "memory" not in archived["body"]
    assert agent_config_sha256(parse_agent_config(archived["body"])) == GRU_PPO_V2_SHA256
    files = _gru_ppo_files()
    with_memory = [p for p in files if load_agent_config(p).memory]
    assert len(with_memory) >= 3 and NOMEM in files  # regimes/, reports/ladder/, reports/sensitivity/
    for path in with_memory:
        cfg = load_agent_config(path)
        assert "memory" not in agent_config_content(cfg), path
        if cfg.name == "gru_ppo":  # the shipped file and the studies' copies of it
            assert cfg.version in GRU_PPO_SHA256, path  # a new one: pin its hash here
            assert agent_config_sha256(cfg) == GRU_PPO_SHA256[cfg.version], path
    # the ladder study's file without memory is its copy of gru_ppo v2 with memory off
    nomem, shipped = _nomem(), load_agent_config(NOMEM.with_name("gru_ppo.toml"))
    assert agent_config_content(nomem)["memory"] is False and agent_config_sha256(nomem) != GRU_PPO_V2_SHA256
    own = ("name", "description", "memory")
    strip = lambda c: {k: v for k, v in agent_config_content(c).items() if k not in own}  # noqa: E731
    assert strip(nomem) == strip(shipped)  # the shipped file with memory off, nothing else
    assert parse_agent_config(read_toml_text(agent_config_to_toml(nomem))) == nomem
    assert parse_agent_config(read_toml_text(agent_config_to_toml(shipped))).memory is True


def read_toml_text(text: str) -> dict:
    import tomllib

    return tomllib.loads(text)


# --------------------------------------------------------------------------- the SB3 policy
def _sb3_model(memory: bool, seed: int = 0) -> GRUPPO:
    model = GRUPPO(NutriRLSB3VecEnv(num_envs=1, regime="run3"), n_steps=50, seed=seed, memory=memory)
    th.nn.init.orthogonal_(model.policy.actor_head[2].weight, gain=5.0)  # outputs of ordinary scale
    return model


def _histories(t: int = 6, d: int = 13) -> np.ndarray:
    """Two days ``(2, t, d)`` that differ before their last step and share it."""
    rng = np.random.default_rng(3)
    days = rng.normal(size=(2, t, d)).astype(np.float32)
    days[1, -1] = days[0, -1]
    return days


def test_sb3_without_memory_the_output_at_a_step_depends_on_that_step_alone() -> None:
    days = _histories()
    for memory in (False, True):
        model = _sb3_model(memory)
        probs = []
        for day in days:  # acting and evaluation: predict's conventions, the state carried
            state, start = None, np.ones(1, dtype=bool)
            for obs in day:
                p, state = gru_action_probabilities(model, obs[None], state, start)
                start = np.zeros(1, dtype=bool)
            probs.append(p)
        alone, _ = gru_action_probabilities(model, days[0, -1][None])  # the last step from the zero state
        if memory:
            assert np.abs(probs[0] - probs[1]).max() > 1e-3  # the history matters
            continue
        np.testing.assert_array_equal(probs[0], probs[1])
        np.testing.assert_array_equal(probs[0], alone)
        pol = model.policy
        x = th.as_tensor(days)
        starts = th.zeros(2, days.shape[1])
        starts[:, 0] = 1.0
        with th.no_grad():  # training: whole days replayed give each step alone
            values, logp, _ = pol.evaluate_actions(x, th.zeros(2, days.shape[1]), pol.initial_state(2), starts)
            one, _ = pol.unroll(x.reshape(-1, 1, 13), pol.initial_state(x.shape[0] * x.shape[1]), th.ones(12, 1))
            np.testing.assert_allclose(
                values.numpy(), pol.critic_head(one[:, 0]).flatten().numpy(), rtol=1e-6, atol=1e-6
            )
        assert model.day_entropy(days[0]) == pytest.approx(
            float(np.mean([gru_action_entropy(model, o[None])[0][0] for o in days[0]])), abs=1e-6
        )


# --------------------------------------------------------------------------- the batched engine
def test_batched_without_memory_every_path_plays_each_step_from_the_zero_state_as_the_sb3_policy() -> None:
    """Replayed days (the update), acting step by step and the greedy play of days side by side
    (the evaluation during training) give each step's output from its observation alone, and
    the SB3 policy's with the same weights."""
    days = th.as_tensor(_histories())
    model = _sb3_model(False)
    net = StackedGRUActorCritic(1, 13, 128, memory=False)
    net.load_sb3(0, model.policy)
    with th.no_grad():
        replayed, _ = net.sequences(days.unsqueeze(0))  # (1, 2, T, 2)
        actor, acted = RecurrentActor(net), []
        for t in range(days.shape[1]):  # one day, then the other, state carried
            acted.append(actor(days[0, t : t + 1], th.tensor([float(t == 0)]))[0])
        state, played = th.zeros(2, 2, 128), []
        for t in range(days.shape[1]):
            logits, _, state = net.step_days(days[:, t].unsqueeze(0), state)
            played.append(logits[0])
        alone, _ = net.sequences(days.reshape(1, -1, 1, 13))
        feats, _ = model.policy.unroll(days, model.policy.initial_state(2), th.zeros(2, days.shape[1]))
        sb3 = model.policy.actor_head(feats)
    alone = alone.reshape(2, -1, 2)
    np.testing.assert_allclose(replayed[0], alone, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(th.cat(acted), alone[0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(th.stack(played, dim=1), alone, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(sb3, alone, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(alone[0, -1], alone[1, -1], rtol=1e-6, atol=1e-7)  # the history does not matter


def test_a_batch_must_agree_on_memory() -> None:
    with pytest.raises(ValueError, match="agree on memory"):
        train_batched([("run0", 0), ("run0", 1)], "gru_ppo", 1, agent_configs=["gru_ppo", NOMEM])


# --------------------------------------------------------------------------- evaluation
def test_evaluation_during_training_on_test_days_and_after_loading_is_without_memory(tmp_path: Path) -> None:
    """The batched engine's evaluation during training (days side by side) equals the SB3
    policy's evaluation of the returned agent on those days; on test days each action is the
    one of its observation alone; a saved and loaded agent plays the same."""
    jobs = [("run3", 1), ("run6", 5)]
    agents = train_batched(jobs, _nomem(), 2, eval_every=2, val_episodes=2)
    for (regime, seed), agent in zip(jobs, agents):
        post = evaluate(agent, regime, validation_food_streams(regime, seed, 2), record_steps=False).episodes
        assert [r["foods"] for r in agent.validation] == [r["foods"] for r in post]
        for d, p in zip(agent.validation, post):
            assert d["return"] == pytest.approx(p["return"], abs=1e-5)
            assert d["entropy"] == pytest.approx(p["entropy"], abs=1e-5)
    agent, (regime, seed) = agents[1], jobs[1]
    seen, act = [], agent.act

    def recording(obs, state=None, episode_start=None):
        seen.append(agent.normalize(obs))  # each step's observations of the days, as the policy sees them
        return act(obs, state, episode_start)

    agent.act = recording
    tested = evaluate(agent, regime, eval_food_streams(regime, seed, 3))
    del agent.act
    alone, _ = agent.model.predict(np.concatenate(seen), deterministic=True)  # each from the zero state
    steps = sorted(tested.steps, key=lambda s: (s["step"], s["episode"]))
    assert [s["action"] for s in steps] == alone.astype(int).tolist()
    agent.save(tmp_path / "nomem.zip")
    loaded = TrainedAgent.load(tmp_path / "nomem.zip")
    assert loaded.config.memory is False and loaded.model.policy.memory is False
    again = evaluate(loaded, regime, eval_food_streams(regime, seed, 3))
    assert again.episodes == tested.episodes


def test_part3_copy_without_memory_differs_from_the_v2_tuned_file_in_memory_only() -> None:
    """reports/tuned_v2's arm C is its arm B (``gru_ppo_tuned_v2``) with memory off, nothing else."""
    folder = ROOT / "reports" / "tuned_v2" / "agents"
    tuned, nomem = (load_agent_config(folder / f"{n}.toml") for n in ("gru_ppo_tuned_v2", "gru_ppo_tuned_v2_nomem"))
    assert tuned.memory is True and nomem.memory is False
    own = ("name", "description", "memory")
    strip = lambda c: {k: v for k, v in agent_config_content(c).items() if k not in own}  # noqa: E731
    assert strip(nomem) == strip(tuned) and nomem.name == "gru_ppo_tuned_v2_nomem"
    assert agent_config_sha256(nomem) != agent_config_sha256(tuned)
