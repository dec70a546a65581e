"""Training diagnostics: the vocabulary of the per-update rows both engines record.

A training job records one row per update, a ``dict[str, float]`` keyed by the names below; a
quantity an algorithm does not have is absent from the dict. The store writes a job's rows to
the ``diagnostics`` table in the same transaction as its episode rows, as a long table: one
row per (job, update, name) with its value (``timestep`` included; an absent quantity has no
row), so an algorithm of a plug-in may record a quantity of its own under a new name
(:func:`valid_name`) and the database stores it without a schema change.

Granularity: the on-policy agents (MC, PPO, GRU-PPO) record one row per rollout update; the
off-policy agents (DDQN, SAC) record one row per training day with gradient steps (none before
learning starts), each quantity the mean over that day's gradient steps (a 5000-day DDQN job
makes 62,500 gradient steps; a row each would be 12 M rows for the paper grid). Both engines
follow this.

Columns:

- ``update``: the row's index within its job, 0-based, consecutive.
- ``timestep``: environment steps of that job up to the end of this update.
- ``policy_loss``: the policy-gradient loss (MC, PPO, GRU-PPO; the clipped surrogate for the PPO
  family, the REINFORCE loss for MC).
- ``value_loss``: the value loss (MC, PPO, GRU-PPO), the critic loss (SAC), the TD loss (DDQN).
- ``entropy_loss``: the entropy term of the loss, minus the mean entropy (MC, PPO, GRU-PPO).
- ``approx_kl``: the approximate KL divergence between the old and the new policy (PPO, GRU-PPO).
- ``clip_fraction``: the share of samples whose probability ratio was clipped (PPO, GRU-PPO).
- ``explained_variance``: 1 - Var(returns - values) / Var(returns) of the rollout (MC, PPO, GRU-PPO).
- ``grad_norm``: the global gradient norm before clipping (all agents where the engine clips or
  can read it; the mean over the update's gradient steps).
- ``learning_rate``: the optimiser's learning rate at this update (all agents).
- ``epsilon``: the exploration rate of the epsilon-greedy policy (DDQN).
- ``q_mean``: the mean Q-value of the actions taken in the batch (DDQN; SAC: the mean of the
  twin critics' minimum).
- ``actor_loss``: the actor loss (SAC).
- ``ent_coef``: the entropy coefficient alpha (SAC).
- ``return_scale``: VecNormalize's reward scale sqrt(ret_rms.var + epsilon) when reward
  normalisation is on (absent otherwise).
"""

from __future__ import annotations

import re
from typing import Any

UPDATE = "update"
TIMESTEP = "timestep"

POLICY_LOSS = "policy_loss"
VALUE_LOSS = "value_loss"
ENTROPY_LOSS = "entropy_loss"
APPROX_KL = "approx_kl"
CLIP_FRACTION = "clip_fraction"
EXPLAINED_VARIANCE = "explained_variance"
GRAD_NORM = "grad_norm"
LEARNING_RATE = "learning_rate"
EPSILON = "epsilon"
Q_MEAN = "q_mean"
ACTOR_LOSS = "actor_loss"
ENT_COEF = "ent_coef"
RETURN_SCALE = "return_scale"

#: The float quantities of a row, in the database's column order.
QUANTITIES: tuple[str, ...] = (
    POLICY_LOSS,
    VALUE_LOSS,
    ENTROPY_LOSS,
    APPROX_KL,
    CLIP_FRACTION,
    EXPLAINED_VARIANCE,
    GRAD_NORM,
    LEARNING_RATE,
    EPSILON,
    Q_MEAN,
    ACTOR_LOSS,
    ENT_COEF,
    RETURN_SCALE,
)

#: Every column of a row: the two keys, then the quantities.
COLUMNS: tuple[str, ...] = (UPDATE, TIMESTEP, *QUANTITIES)

#: What a name may be: a quantity's (the built-in ones and a plug-in's: what the database, an
#: archive's column and a TensorBoard tag are named by), a regime's or an agent config's (what
#: files, figures and tables are named after: :func:`nutribench.store.archive.valid_config_name`).
NAME_PATTERN = re.compile(r"[a-z][a-z0-9_]*")
NAME_MAX = 64


def valid_name(name: Any) -> bool:
    """Whether ``name`` may name a diagnostics quantity: ``[a-z][a-z0-9_]*``, at most
    :data:`NAME_MAX` characters, and not ``update`` (a row's index, not a quantity)."""
    return (
        isinstance(name, str) and len(name) <= NAME_MAX and NAME_PATTERN.fullmatch(name) is not None and name != UPDATE
    )
