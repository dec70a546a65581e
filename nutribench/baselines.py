"""The simple policies' table: every policy on every regime, on the same food streams; and
the yardsticks of the share of the never -> planner gap (:func:`gap_closed`) on given days:
:func:`day_yardsticks` (the test days of a report, the validation days of a tuner) and
:func:`validation_yardsticks` (a job's validation days)."""

from __future__ import annotations

import numpy as np

from nutribench.config import EnvConfig, load_env_config
from nutribench.env import NutriRLVectorEnv
from nutribench.env.metrics import play
from nutribench.env.policies import make_policy

POLICY_ORDER = ("random", "never", "always", "planner")
SUMMARY_KEYS = ("return", "foods", "final_distance", "overshoot_ratio")


def gap_closed(value: float, never: float, planner: float) -> float:
    """Share of the never -> planner gap that ``value`` closes (0 = never eat, 1 = the
    planner; the planner is greedy, not optimal, so more than 1 is possible); NaN where the
    two coincide (no gap to close)."""
    return float((value - never) / (planner - never)) if planner != never else float("nan")


def play_simple_policy(policy: str, regime: str | EnvConfig, foods: np.ndarray, seed: int = 0) -> list[dict]:
    """Per-episode metrics of ``policy`` on the given days ``(n, horizon)`` of food indices."""
    env = NutriRLVectorEnv(len(foods), regime=regime)
    return play(env, make_policy(policy, seed), episodes=len(foods), foods=foods)


#: the two policies the share of the gap is measured between
YARDSTICKS = ("never", "planner")


def day_yardsticks(regime: str | EnvConfig, foods: np.ndarray) -> list[dict]:
    """The ``never`` and ``planner`` returns on each of the days ``(n, horizon)``: one dict per
    day (``episode``, ``never``, ``planner``)."""
    played = {name: [float(r["return"]) for r in play_simple_policy(name, regime, foods)] for name in YARDSTICKS}
    return [{"episode": e, **{name: played[name][e] for name in YARDSTICKS}} for e in range(len(foods))]


def validation_yardsticks(regime: str | EnvConfig, seed: int, n: int = 5) -> dict[str, float]:
    """The mean returns of ``never`` and ``planner`` over the ``n`` validation days of
    ``(regime, seed)`` (:func:`~nutribench.agents.days.validation_food_streams`), the
    yardsticks of an evaluation during training: its share of the gap is
    ``gap_closed(mean return, never, planner)``."""
    from nutribench.agents.days import validation_food_streams

    days = day_yardsticks(regime, validation_food_streams(regime, seed, n))
    return {name: float(np.mean([d[name] for d in days])) for name in YARDSTICKS}


def evaluate_simple_policy(policy: str, regime: str, episodes: int = 200, seed: int = 0) -> list[dict]:
    """Per-episode metrics of ``policy`` on ``episodes`` days drawn with ``seed``."""
    cfg = load_env_config(regime)
    foods = np.random.default_rng(seed).integers(0, len(cfg.catalog.food), size=(episodes, cfg.reward.horizon))
    return play_simple_policy(policy, cfg, foods, seed)


def baseline_table(regimes: list[str], episodes: int = 200, seed: int = 0) -> list[dict]:
    """One row per (regime, policy): the mean of each per-day metric (:data:`~nutribench.env.metrics.METRIC_KEYS`)."""
    rows = []
    for regime in regimes:
        for policy in POLICY_ORDER:
            eps = evaluate_simple_policy(policy, regime, episodes, seed)
            rows.append(
                {"regime": regime, "policy": policy, **{k: float(np.mean([e[k] for e in eps])) for k in SUMMARY_KEYS}}
            )
    return rows
