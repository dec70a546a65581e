"""sb3-contrib's RecurrentPPO as a nutribench plug-in agent.

The agent file ``examples/agents/recurrent_ppo.toml`` names this module::

    algo = "external"
    entry_point = "examples.recurrent_ppo:make_agent"
    [params]              # passed to RecurrentPPO as keyword arguments
    n_steps = 500

``nutribench run`` imports it by name in each worker (from an installed package or the current
folder), trains ``make_agent(params, env, seed)`` with ``learn(total_timesteps)``, evaluates it
greedily on the fixed evaluation days with its LSTM state carried through each day, and saves
it; ``load`` loads what it saved as data: the model rebuilt by ``make_agent`` from the params in
its ``.json`` sidecar, the weights read as tensors (SB3's own ``RecurrentPPO.load`` would unpickle
the zip's settings, running whatever a crafted file planted there). Needs the optional extra: ``pip install -e ".[contrib]"``.
"""

from __future__ import annotations

from typing import Any

from sb3_contrib import RecurrentPPO

from nutribench.agents.model_files import load_plugin_model


def make_agent(params: dict[str, Any], env: Any, seed: int) -> RecurrentPPO:
    """A RecurrentPPO on ``env`` (a Gymnasium-style SB3 VecEnv of one NutriRL day at a time)."""
    return RecurrentPPO("MlpLstmPolicy", env, seed=seed, device="cpu", verbose=0, **params)


def load(path: str) -> RecurrentPPO:
    """A saved RecurrentPPO (what nutribench saved: the zip and its ``.json``), never unpickled."""
    return load_plugin_model(path, make_agent)
