"""reports/gru_memory/without_memory.py: its memoryless GRU-PPO has no memory anywhere, leaving
the diagnostic restores the real agent, and the package's ``memory = false`` option trains what
its patch of ``gru_ppo`` trained, bit for bit. This study's own check, run from the checkout:
``python -m pytest -p no:cacheprovider reports/gru_memory``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch as th
from report_scripts import load_script

from nutribench.agents.api import TrainedAgent, train
from nutribench.agents.config import load_agent_config
from nutribench.engine.gru_ppo import RecurrentActor as _Recurrent
from nutribench.engine.gru_ppo import StackedGRUActorCritic
from nutribench.engine.train import train_batched

NOMEM = Path(__file__).resolve().parents[1] / "ladder" / "agents" / "gru_ppo_nomem.toml"


def _diagnostic():
    return load_script("gru_memory", "without_memory")


def _day_outputs(net: StackedGRUActorCritic, obs: th.Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Logits of a day replayed whole, logits of the same day acted step by step, and of
    its last step acted alone from the zero state (agent 0)."""
    with th.no_grad():
        replayed, _ = net.sequences(obs.reshape(1, 1, *obs.shape))
        actor = _Recurrent(net)
        acted = [actor(obs[t : t + 1], th.tensor([float(t == 0)]))[0] for t in range(len(obs))]
        alone = _Recurrent(net)(obs[-1:], th.ones(1))[0]
    return replayed[0, 0].numpy(), th.cat(acted).numpy(), alone.numpy()


def test_without_memory_every_step_is_played_from_the_zero_state_and_the_agent_is_restored_after() -> None:
    module = _diagnostic()
    net = StackedGRUActorCritic(1, 13, 16, generators=[th.Generator().manual_seed(0)])
    obs = th.randn(8, 13, generator=th.Generator().manual_seed(1))

    replayed, acted, alone = _day_outputs(net, obs)
    np.testing.assert_allclose(replayed, acted, rtol=1e-5, atol=1e-6)  # the real agent: replay = acting
    assert not np.allclose(acted[-1], alone[0], atol=1e-4)  # ... and it remembers the day

    with module.no_memory():
        replayed_nm, acted_nm, alone_nm = _day_outputs(net, obs)
        np.testing.assert_allclose(acted_nm[-1], alone_nm[0], rtol=1e-5, atol=1e-6)  # no memory when acting
        np.testing.assert_allclose(replayed_nm, acted_nm, rtol=1e-5, atol=1e-6)  # nor in the update's replay
        from nutribench.agents.gru_ppo.policy import GRUActorCriticPolicy

        policy = GRUActorCriticPolicy(*_spaces(), lr_schedule=lambda _: 1e-3, hidden_size=16)
        feats, _ = policy.unroll(obs.unsqueeze(0), policy.initial_state(1), th.zeros(1, 8))
        last, _ = policy.unroll(obs[-1:].unsqueeze(0), policy.initial_state(1), th.ones(1, 1))
        np.testing.assert_allclose(
            feats[0, -1].detach().numpy(), last[0, 0].detach().numpy(), rtol=1e-5, atol=1e-6
        )  # nor in evaluation

    np.testing.assert_allclose(_day_outputs(net, obs)[1], acted, rtol=0, atol=0)  # restored


def _spaces():
    from gymnasium import spaces

    return spaces.Box(-np.inf, np.inf, shape=(13,), dtype=np.float32), spaces.Discrete(2)


# --------------------------------------------------------------------------- the same runs as the diagnostic
def _same_weights(a: TrainedAgent, b: TrainedAgent) -> None:
    assert a.train_episodes == b.train_episodes
    wa, wb = a.model.policy.state_dict(), b.model.policy.state_dict()
    assert wa.keys() == wb.keys() and all(th.equal(wa[k], wb[k]) for k in wa)


def test_both_engines_train_the_diagnostic_s_patched_agent_bit_for_bit() -> None:
    """``memory = false`` trains what ``without_memory.py``'s patch of ``gru_ppo`` trained
    (the same food days, actions and weights), in each engine, on one rollout and update."""
    th.set_num_threads(1)
    jobs = [("run0", 0), ("run6", 1)]
    option = train_batched(jobs, load_agent_config(NOMEM), 10)
    sb3_option = train("run6", load_agent_config(NOMEM), seed=2, episodes=10, diagnostics=False)
    with _diagnostic().no_memory():
        patched = train_batched(jobs, "gru_ppo", 10)
        sb3_patched = train("run6", "gru_ppo", seed=2, episodes=10, diagnostics=False)
    for a, b in [*zip(option, patched), (sb3_option, sb3_patched)]:
        _same_weights(a, b)
    assert not option[0].model.policy.memory and option[0].config.memory is False
