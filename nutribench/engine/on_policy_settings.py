"""The on-policy algorithms' settings (PPO, MC, GRU-PPO): :class:`OnPolicySettings`, read
from an agent config, one value for all K agents or, for tuning trials stacked in one batch,
one per agent (:meth:`OnPolicySettings.for_agents`; a loss reads one with
:func:`nutribench.engine.stacked.per_agent`)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

from nutribench.agents.algos import model_arguments


@dataclass
class OnPolicySettings:
    """What the rollout and the update read from an agent config (PPO, MC or GRU-PPO): the
    one place the on-policy loop and updates take their settings from (never the config).
    Each continuous setting is one float for all K agents, read only in :func:`gradient_step`
    (``ent_coef``, ``vf_coef``, ``max_grad_norm``), :func:`~nutribench.engine.ppo.ppo_update`
    (``clip_range``), :meth:`BatchedOnPolicyAlgorithm.scale_rewards` (``gamma``),
    :meth:`BatchedOnPolicyAlgorithm.compute_returns` (``gamma``, ``gae_lambda``), the optimiser
    (:class:`~nutribench.engine.stacked.StackedAdam`) and :meth:`BatchedOnPolicyAlgorithm.log_update`
    (``learning_rate``), so a per-agent value (a ``(K,)`` array) changes those reads only."""

    learning_rate: float | np.ndarray
    n_steps: int
    batch_size: int
    n_epochs: int
    gamma: float | np.ndarray
    gae_lambda: float | np.ndarray
    clip_range: float | np.ndarray | None  # None: A2C's update (MC)
    ent_coef: float | np.ndarray
    vf_coef: float | np.ndarray
    max_grad_norm: float | np.ndarray
    normalize_advantage: bool
    sequence_length: int | None = None  # GRU-PPO: minibatches of whole days (batch_size counts days)
    #: agents whose updates are applied (``(K,)`` bool, the caller's array, read at every step);
    #: None: all. A frozen agent's parameters stay as they are (a pruned tuning trial's).
    active: np.ndarray | None = None

    #: the settings that may differ between the agents of one batch (each a ``(K,)`` array then)
    CONTINUOUS: ClassVar[tuple[str, ...]] = (
        "learning_rate",
        "gamma",
        "gae_lambda",
        "clip_range",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
    )

    @classmethod
    def for_agents(cls, cfgs: list[Any], horizon: int) -> OnPolicySettings:
        """The settings of K agents, one config each: the structural settings must agree (they
        shape the rollout and the minibatches); each continuous one (:attr:`CONTINUOUS`) is a
        ``(K,)`` array where the configs differ, else the one value (the single-config path,
        unchanged)."""
        each = [cls.from_config(c, horizon) for c in cfgs]
        first = each[0]
        for name in first.__dataclass_fields__:
            if name in cls.CONTINUOUS or name == "active":
                continue
            values = {getattr(e, name) for e in each}
            if len(values) > 1:
                raise ValueError(f"agents of one batch must agree on {name} (got {sorted(values, key=str)})")
        for name in cls.CONTINUOUS:
            values = [getattr(e, name) for e in each]
            if len(set(values)) > 1:
                setattr(first, name, np.asarray(values, dtype=np.float64))
        return first

    @classmethod
    def from_config(cls, cfg: Any, horizon: int) -> OnPolicySettings:
        """The settings of the SB3 model that ``algos.model_arguments`` builds for ``cfg``
        on days of ``horizon`` steps: the fields its arguments name, as written (PPO's); MC's as A2C gets them (a
        rollout of one day, one step on all of it, lambda 1, no advantage normalisation);
        GRU-PPO's batch in whole days (as ``GRUPPO.sequences_per_batch``)."""
        _, args = model_arguments(cfg, horizon)
        settings = {"n_epochs": 1, "clip_range": None}  # A2C's (MC's): one pass, no clipping
        settings |= {f.name: args[f.name] for f in fields(cls) if f.name in args}
        seq = args.get("sequence_length")
        batch_size = args.get("batch_size", args["n_steps"])
        settings["batch_size"] = batch_size if seq is None else max(1, round(batch_size / seq))
        return cls(**settings, gamma=cfg.gamma)
