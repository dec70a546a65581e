"""The batched training engine: K agents of one agent config trained at once, their
parameters stacked along an agent axis. The SB3 agents in :mod:`nutribench.agents` stay the
reference implementation; each algorithm here is tested to make the same update as its SB3
counterpart. One module per algorithm (:mod:`~nutribench.engine.mc`,
:mod:`~nutribench.engine.ppo`, :mod:`~nutribench.engine.gru_ppo`,
:mod:`~nutribench.engine.ddqn`, :mod:`~nutribench.engine.sac`), each a class of the interface
in :mod:`~nutribench.engine.algorithm` on one of the two loops
(:mod:`~nutribench.engine.on_policy`, :mod:`~nutribench.engine.off_policy`), built of the
stacked primitives in :mod:`~nutribench.engine.stacked`; the entry point is
:func:`nutribench.engine.train.train_batched`.

The engine never silently differs from the reference: a config with a setting it does not
implement is refused (:func:`supports` says why, :func:`check_supported` raises
:class:`UnsupportedConfig`), and the scheduler trains such a config's jobs with the SB3
engine instead. Which algorithms have a batched class, and what of a config it cannot train,
their registry entries say (:mod:`nutribench.agents.registry`: ``batched``, ``batch_limits``).
This module imports neither torch nor the engine's code.
"""

from __future__ import annotations

import math
import os
from typing import Any

import nutribench.agents.registry as registry
from nutribench.errors import UserError


class UnsupportedConfig(UserError, ValueError):
    """An agent config the batched engine cannot train as the SB3 engine does (one line)."""


#: how often a batch saves its state (seconds of wall time, checked at day boundaries)
DEFAULT_EVERY_SECONDS = 300.0
#: the environment variable that sets the seconds between saves (a short call on a lent machine)
EVERY_SECONDS_ENV = "NUTRIBENCH_CHECKPOINT_SECONDS"


def every_seconds_from_env() -> float:
    """The seconds between a batch's saves: ``$NUTRIBENCH_CHECKPOINT_SECONDS`` when set (a positive
    number), else :data:`DEFAULT_EVERY_SECONDS`. A value that is not raises ``ValueError`` (one line)."""
    raw = os.environ.get(EVERY_SECONDS_ENV, "").strip()
    if not raw:
        return DEFAULT_EVERY_SECONDS
    try:
        seconds = float(raw)
    except ValueError:
        seconds = float("nan")
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(
            f"{EVERY_SECONDS_ENV}={raw!r} is not a positive number of seconds: set it to e.g. 60, or unset it"
        )
    return seconds


def supports(cfg: Any, horizon: int | None = None) -> str | None:
    """None if the batched engine trains agent config ``cfg`` (a config model, name or path)
    exactly as the SB3 engine does (on regimes of ``horizon`` steps a day, when given); else
    the reason, one line: what, which config, how to fix."""
    if isinstance(cfg, str) or not hasattr(cfg, "algo"):
        from nutribench.agents.config import load_agent_config

        cfg = load_agent_config(cfg)
    name, algo = getattr(cfg, "name", "?"), cfg.algo
    known = registry.batched_names()
    if algo not in known:
        return f"agent config {name!r} ({algo}): the batched engine trains {', '.join(known)} only; use --engine sb3"
    reason = registry.batch_limit(cfg, horizon)
    return None if reason is None else f"agent config {name!r} ({algo}): {reason}, or use --engine sb3"


def check_supported(cfg: Any, horizon: int | None = None) -> None:
    """Raise :class:`UnsupportedConfig` with :func:`supports`'s reason if the batched engine
    does not train ``cfg`` as the SB3 engine does."""
    reason = supports(cfg, horizon)
    if reason is not None:
        raise UnsupportedConfig(reason)
