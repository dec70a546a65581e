"""Simple reference policies: random, never eat, always eat, and a full-information planner.

They are the reference points of every later figure: where "no learning" and "full
information" lie. Each works on a :class:`NutriRLVectorEnv` (batched, one action per env)
and on a single :class:`NutriRLEnv` (one action), reading only the env's public
inspection API.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


class RandomPolicy:
    """Eats each offered food with probability 1/2."""

    name = "random"

    def __init__(self, seed: int | None = None):
        self.rng = np.random.default_rng(seed)

    def __call__(self, env):
        n = np.atleast_1d(env.offered).shape[0]
        a = self.rng.integers(0, 2, size=n)
        return a if np.ndim(env.state) == 2 else int(a[0])


class ConstantPolicy:
    """Never eats (0) or always eats (1)."""

    def __init__(self, action: int):
        self.action = action
        self.name = "always" if action == 1 else "never"

    def __call__(self, env):
        if np.ndim(env.state) == 2:
            return np.full(env.state.shape[0], self.action)
        return self.action


class PlannerPolicy:
    """Full-information greedy planner.

    It knows the target and the pending absorption (not the future foods): it eats the
    offered food only if, counting everything already eaten that will still arrive by
    step H plus what this food would deliver by step H, no nutrient ends above target and
    the eventual L1 distance to target shrinks by at least ``min_gain`` (in units of the
    daily target; the default 0.05 keeps it from eating foods that would arrive almost
    entirely after the day ends).
    """

    name = "planner"

    def __init__(self, min_gain: float = 0.05):
        self.min_gain = min_gain

    def __call__(self, env):
        gain = env.dyn.arrivals[env.steps_taken, np.atleast_1d(env.offered)]  # (n, 3) arriving by H if eaten now
        eventual = np.atleast_2d(env.state) + np.atleast_2d(env.pending_by_horizon())
        a = planner_eats(eventual, gain, env.target, self.min_gain).astype(np.int64)
        return int(a[0]) if np.ndim(env.state) == 1 else a


def planner_eats(eventual: np.ndarray, gain: np.ndarray, target: np.ndarray | float, min_gain: float) -> np.ndarray:
    """The greedy planner's rule (:class:`PlannerPolicy`), batched: given what will have arrived
    by step H, ``eventual`` (n, 3), and what the offered food would add by then, ``gain`` (n, 3),
    whether to eat it: no nutrient ends above ``target`` and the L1 distance to it shrinks by at
    least ``min_gain``."""
    after = eventual + gain
    no_over = np.all(after <= target + 1e-9, axis=1)
    closer = np.abs(eventual - target).sum(1) - np.abs(after - target).sum(1) >= min_gain
    return no_over & closer


POLICIES: dict[str, Callable[[int | None], object]] = {
    "random": lambda seed=None: RandomPolicy(seed),
    "never": lambda seed=None: ConstantPolicy(0),
    "always": lambda seed=None: ConstantPolicy(1),
    "planner": lambda seed=None: PlannerPolicy(),
}


def make_policy(name: str, seed: int | None = None):
    try:
        return POLICIES[name](seed)
    except KeyError:
        raise ValueError(f"unknown policy '{name}': known policies are {', '.join(POLICIES)}") from None
