"""Tuning trials stacked in one batch: agents whose configs differ in continuous settings
(learning rate, discount, GAE lambda, clip range, entropy and value coefficients,
gradient-norm clip) train side by side bit for bit as each trains alone, and a frozen (pruned)
agent gets no more updates.

Bit for bit, not within a tolerance: each per-agent setting enters the arithmetic exactly as
the same setting given as one float does (StackedAdam takes each agent's rate into its own
step; GAE's gamma * lambda and the clip's max_norm round alike either way), so nothing is left
to differ but what batch invariance already pins (tests/test_engine_batch_invariance.py). A
tolerance was no bound here: a last-bit difference grows through Adam's normalised steps
(on an AMD EPYC to 0.7 % of a weight within one GRU-PPO update, docs/batched-engine.md)."""

from __future__ import annotations

import numpy as np
import pytest

from nutribench.agents.config import load_agent_config
from nutribench.engine.train import train_batched

VARIANTS = [
    {},
    {"learning_rate": 3e-4, "clip_range": 0.1},
    {"ent_coef": 0.01, "vf_coef": 0.9, "gamma": 0.95, "gae_lambda": 0.9, "max_grad_norm": 1.5},
]
#: days of one update: PPO and GRU-PPO's 500-step rollout, MC's one day
ONE_UPDATE = {"ppo": 10, "gru_ppo": 10, "mc": 1}


def weights(agent) -> list[np.ndarray]:
    return [p.detach().numpy().copy() for p in agent.model.policy.parameters()]


def variants(algo: str) -> list:
    base = load_agent_config(algo)
    out = []
    for v in VARIANTS:
        v = {
            k: x
            for k, x in v.items()
            if k in type(base).model_fields and not (algo == "mc" and k in ("clip_range", "gae_lambda"))
        }
        out.append(base.model_copy(update=v))
    return out


@pytest.mark.parametrize("algo", ["ppo", "mc", "gru_ppo"])
def test_stacked_trials_train_each_agent_as_a_batch_of_one_does(algo: str) -> None:
    cfgs = variants(algo)
    days = ONE_UPDATE[algo]
    stacked = train_batched([("run3", 7)] * len(cfgs), cfgs[0], days, agent_configs=cfgs)
    for j, cfg in enumerate(cfgs):
        (alone,) = train_batched([("run3", 7)], cfg, days)
        for a, b in zip(weights(stacked[j]), weights(alone)):
            np.testing.assert_array_equal(a, b)
        assert stacked[j].config == cfg
    # the settings did differ: the agents' weights differ from the first's
    assert not all(np.allclose(a, b) for a, b in zip(weights(stacked[0]), weights(stacked[1])))


def test_a_frozen_agent_gets_no_more_updates() -> None:
    cfgs = variants("ppo")
    active = np.array([True, False, True])
    stacked = train_batched([("run3", 7)] * 3, cfgs[0], 10, agent_configs=cfgs, active=active)
    (untrained,) = train_batched([("run3", 7)], cfgs[1], 1)  # no update before day 10: its first weights
    for a, b in zip(weights(stacked[1]), weights(untrained)):
        np.testing.assert_array_equal(a, b)
    (trained,) = train_batched([("run3", 7)], cfgs[2], 10)  # the others train as they would alone
    for a, b in zip(weights(stacked[2]), weights(trained)):
        np.testing.assert_array_equal(a, b)


def test_configs_that_differ_in_structure_or_off_policy_stacks_are_refused() -> None:
    ppo = load_agent_config("ppo")
    with pytest.raises(ValueError, match="must agree on n_epochs"):
        train_batched([("run3", 7)] * 2, ppo, 1, agent_configs=[ppo, ppo.model_copy(update={"n_epochs": 5})])
    sac = load_agent_config("sac")
    with pytest.raises(ValueError, match="must agree on batch_size"):
        train_batched([("run3", 7)] * 2, sac, 1, agent_configs=[sac, sac.model_copy(update={"batch_size": 64})])
    ddqn = load_agent_config("ddqn")
    with pytest.raises(ValueError, match="takes neither per-agent settings"):
        train_batched([("run3", 7)] * 2, ddqn, 1, agent_configs=[ddqn, ddqn.model_copy(update={"gamma": 0.9})])


def test_stacked_sac_trials_train_each_agent_as_a_batch_of_one_does() -> None:
    """SAC, off-policy: four gradient steps (learning from step 96 of a 100-step budget) with
    each agent's own learning rates, temperature, target rate and discount."""
    base = load_agent_config("sac").model_copy(update={"learning_starts": 95})
    cfgs = [
        base,
        base.model_copy(update={"actor_learning_rate": 1e-3, "alpha": 0.05}),
        base.model_copy(update={"critic_learning_rate": 3e-4, "tau": 0.02, "gamma": 0.95}),
    ]
    stacked = train_batched([("run3", 7)] * 3, base, 2, agent_configs=cfgs)
    for j, cfg in enumerate(cfgs):
        (alone,) = train_batched([("run3", 7)], cfg, 2)
        for a, b in zip(weights(stacked[j]), weights(alone)):
            np.testing.assert_array_equal(a, b)
    assert not all(np.allclose(a, b) for a, b in zip(weights(stacked[0]), weights(stacked[2])))
    frozen = train_batched([("run3", 7)] * 3, base, 2, agent_configs=cfgs, active=np.array([True, False, True]))
    (first,) = train_batched([("run3", 7)], cfgs[1], 1)  # before learning starts: its first weights
    for a, b in zip(weights(frozen[1]), weights(first)):
        np.testing.assert_array_equal(a, b)
