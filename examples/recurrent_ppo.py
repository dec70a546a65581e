"""sb3-contrib's RecurrentPPO as a nutribench plug-in agent.

The agent file ``examples/agents/recurrent_ppo.toml`` names this module::

    algo = "external"
    entry_point = "examples.recurrent_ppo:make_agent"
    [params]              # passed to RecurrentPPO as keyword arguments
    n_steps = 500

``nutribench run`` imports it by name in each worker (from an installed package or the current
folder), trains ``make_agent(params, env, seed)`` with ``learn(total_timesteps)``, evaluates it
greedily on the fixed evaluation days with its LSTM state carried through each day, and saves
it; ``load`` loads what it saved. Needs the optional extra: ``pip install -e ".[contrib]"``.
"""

from __future__ import annotations

from typing import Any

from sb3_contrib import RecurrentPPO


def make_agent(params: dict[str, Any], env: Any, seed: int) -> RecurrentPPO:
    """A RecurrentPPO on ``env`` (a Gymnasium-style SB3 VecEnv of one NutriRL day at a time)."""
    return RecurrentPPO("MlpLstmPolicy", env, seed=seed, device="cpu", verbose=0, **params)


def load(path: str) -> RecurrentPPO:
    """A saved RecurrentPPO (what ``make_agent(...).save(path)`` wrote)."""
    return RecurrentPPO.load(path, device="cpu")
