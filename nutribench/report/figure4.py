"""Figure 4's agent configs: the pair it compares (``--pair``; default PPO and GRU-PPO,
``nutribench.report.build.DEFAULT_PAIR``) and, beside the pair, its memory ablation: each
config the database holds that is one of the pair's configs with ``memory = false`` and
nothing else changed (its name, version and description apart; GRU-PPO's option: the state
zeroed before every step). Such a config is drawn as ``<label> without memory (<name>)``, so
that with the ladder study's archives (``reports/ladder/``) the figure shows PPO, GRU-PPO and
GRU-PPO without memory. A database without one draws the pair alone, as before the option
existed. :func:`check_pair` checks ``--pair``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

from nutribench.report.data import ReportError, check_names
from nutribench.report.palette import label as algo_label

#: what may differ between a config and its copy without memory
_OWN = ("name", "version", "description", "memory")


def check_pair(pair: Sequence[str] | None, default: tuple[str, str]) -> tuple[str, str]:
    """``pair`` as a tuple (None: ``default``); :class:`ReportError` unless two different names."""
    if pair is None:
        return default
    if len(pair) != 2 or pair[0] == pair[1]:
        raise ReportError(f"--pair {','.join(pair)}: give two different agent configs, e.g. --pair ppo,gru_ppo")
    check_names(pair, "agent config", "--pair")
    return (pair[0], pair[1])


def _rest(body: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in body.items() if k not in _OWN}


def without_memory(
    pair: Sequence[str], stored: Mapping[str, Any] | None, metrics: pd.DataFrame | None = None
) -> dict[str, str]:
    """The configs of ``stored`` (:func:`~nutribench.report.data.stored_agent_configs`) that
    are a config of ``pair`` with ``memory = false`` and nothing else changed, each mapped to
    that config of the pair, in ``stored``'s order; only those with evaluation episodes in
    ``metrics`` (rows of ``episode_metrics``) when it is given; none where ``stored`` is None."""
    out: dict[str, str] = {}
    members = {m: stored[m].model_dump(mode="json") for m in pair if stored and m in stored}
    evaluated = None if metrics is None else set(metrics.loc[metrics["phase"] == "eval", "algo"])
    for name, cfg in (stored or {}).items():
        body = cfg.model_dump(mode="json")
        if name in pair or body.get("memory", True) is not False or (evaluated is not None and name not in evaluated):
            continue
        same = [m for m, mb in members.items() if mb.get("memory", True) is True and _rest(mb) == _rest(body)]
        if same:
            out[name] = same[0]
    return out


def labels(ablation: Mapping[str, str]) -> dict[str, str]:
    """The legend labels of the ablation's configs: ``GRU-PPO without memory (gru_ppo_nomem)``."""
    return {name: f"{algo_label(member)} without memory ({name})" for name, member in ablation.items()}


def title(pair: Sequence[str], ablation: Mapping[str, str]) -> str:
    """The figure's first title line: ``PPO against GRU-PPO with and without memory``."""
    ablated = set(ablation.values())
    a, b = (f"{algo_label(m)} with and without memory" if m in ablated else algo_label(m) for m in pair)
    return f"{a} against {b}: fixed-policy inference across regimes"
