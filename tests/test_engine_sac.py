"""The batched engine's discrete SAC against ``nutribench.agents.sac.DiscreteSAC``: one
update of stacked agents (critics, actor, targets), the loop's update timing, and the agents
it hands back."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from nutribench.agents.api import TrainedAgent, eval_food_streams, evaluate
from nutribench.agents.config import load_agent_config
from nutribench.agents.sac import DiscreteSAC
from nutribench.engine.sac import StackedSAC, linears, sac_update
from nutribench.engine.train import train_batched
from tests.conftest import random_batch, sb3_model, sb3_updates, shake

OBS_DIM = 13


def _sb3_sac(seed: int):
    cfg, model = sb3_model("sac", seed)
    shake(model.policy.critic_target.parameters(), seed)  # so that the target network matters
    return cfg, model


def _params(net: StackedSAC, j: int) -> list[th.Tensor]:
    """Agent ``j``'s actor, critic and target-critic weights, laid out as SB3 holds them."""
    out = []
    for stack, rows in ((net.actor, [j]), (net.critic, [j, net.k + j]), (net.critic_target, [j, net.k + j])):
        for r in rows:
            for i in range(0, len(stack.params), 2):
                out += [stack.params[i][r].detach().T, stack.params[i + 1][r, 0].detach()]
    return out


def _sb3_params(policy) -> list[th.Tensor]:
    out = []
    for seq in (policy.actor, policy.critic.q1, policy.critic.q2, policy.critic_target.q1, policy.critic_target.q2):
        for lin in linears(seq):
            out += [lin.weight.detach(), lin.bias.detach()]
    return out


def test_one_sac_update_of_stacked_agents_equals_discrete_sac_s_update_of_each_alone() -> None:
    """Two updates of three stacked agents, each against ``DiscreteSAC.train`` of that agent
    alone on the same samples: critic and actor losses, and the new actor, critic and target
    weights."""
    k, b = 3, 32
    models = [_sb3_sac(seed) for seed in range(k)]
    cfg = models[0][0]
    net = StackedSAC(k, [OBS_DIM, *cfg.net_arch, 2], cfg.actor_learning_rate, cfg.critic_learning_rate)
    for j, (_, m) in enumerate(models):
        net.load_sb3(j, m.policy)
    for j, (_, m) in enumerate(models):
        for ours, theirs in zip(_params(net, j), _sb3_params(m.policy)):
            assert th.equal(ours, theirs)
    rng = np.random.default_rng(5)
    for _ in range(2):
        batch = random_batch(rng, k, b, OBS_DIM, 3.0, cfg.gamma)
        losses = sac_update(net, batch, cfg.alpha, cfg.gamma, cfg.tau)
        for j, (_, m) in enumerate(models):
            sample = ReplayBufferSamples(
                batch.obs[j],
                batch.actions[j].unsqueeze(1),
                batch.next_obs[j],
                batch.dones[j].unsqueeze(1),
                batch.rewards[j].unsqueeze(1),
            )
            m.replay_buffer.sample = lambda *a, s=sample, **kw: s
            m.train(gradient_steps=1, batch_size=b)
            assert losses["critic_loss"][j] == pytest.approx(m.logger.name_to_value["train/critic_loss"], rel=1e-5)
            assert losses["actor_loss"][j] == pytest.approx(
                m.logger.name_to_value["train/actor_loss"], rel=1e-4, abs=1e-6
            )
            for ours, theirs in zip(_params(net, j), _sb3_params(m.policy)):
                np.testing.assert_allclose(ours, theirs, rtol=1e-4, atol=1e-6)


def test_the_sac_loop_updates_when_discrete_sac_does() -> None:
    """Three days: SB3's ``learn`` and the batched loop update at the same steps (after
    ``learning_starts``, every step, none on the budget's last)."""
    cfg = load_agent_config("sac")
    ours: list[int] = []
    train_batched([("run0", 0), ("run6", 1)], cfg, episodes=3, on_update=lambda u: ours.append(u["steps"]))
    theirs = sb3_updates(DiscreteSAC, "run0", cfg, 3, lambda m: m.num_timesteps)
    assert ours == theirs == list(range(cfg.learning_starts + 1, 150))


def test_batched_sac_agents_are_discrete_sacs_the_single_agent_api_uses(tmp_path) -> None:
    cfg = load_agent_config("sac")
    agents = train_batched([("run0", 0), ("run3", 0)], cfg, episodes=3)
    assert [len(a.train_episodes) for a in agents] == [3, 3]
    assert all(0.0 <= m["entropy"] <= np.log(2) + 1e-6 for a in agents for m in a.train_episodes)
    streams = eval_food_streams("run0", 0, 2)
    for a in agents:
        assert isinstance(a.model, DiscreteSAC) and a.provenance["engine"] == "batched"
        back = TrainedAgent.load(a.save(tmp_path / f"{a.provenance['regime']}.zip"))
        assert [e["return"] for e in evaluate(a, "run0", streams, record_steps=False).episodes] == [
            e["return"] for e in evaluate(back, "run0", streams, record_steps=False).episodes
        ]
    actors = [next(a.model.policy.actor.parameters()).detach() for a in agents]
    assert not th.equal(actors[0], actors[1])
