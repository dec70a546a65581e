"""The reference policies: four simple ones (random, never eat, always eat, and a
full-information planner) and two stronger ones, planned on a model of the day.

The simple ones are the reference points of every later figure: where "no learning" and "full
information" lie. Each works on a :class:`NutriRLVectorEnv` (batched, one action per env)
and on a single :class:`NutriRLEnv` (one action), reading only the env's public
inspection API.

The greedy planner is the benchmark's 100 % mark; it is not optimal. These two say how far
above it the optimum lies:

* :func:`lookahead_actions`, **lookahead**: the planner's information (the state, what is
  pending, the offered food; not the future foods). At each step it plays both actions on
  ``samples`` sampled futures of offered foods (drawn uniformly from the catalog, as the env
  draws them), finishes each with the greedy planner, and takes the action with the better
  mean return (skip on a tie). The futures of step ``t`` are drawn from ``[seed, t]`` and
  shared by both actions and by every day, so a day's actions depend on the seed and the day
  alone (not on which days are planned beside it).
* :func:`clairvoyant_actions`, **clairvoyant**: the day's foods known in advance. A beam
  search (``width`` nodes, ranked by return so far plus the upper bound below) finds a good
  day; then a branch and bound over the whole tree of the day's eat/skip decisions, breadth
  first, keeps every node whose return so far plus an upper bound on the rest of the day
  reaches the best return known (the beam's or the planner's) and merges nodes of the same
  state. When its frontier never exceeds ``max_nodes`` the day's best return is proven
  (``exact``, to a tolerance of 1e-9 in return); otherwise the beam's day stands (``beam``).

The upper bound on the rest of a day, from a node at step t: every nutrient only grows, so at
each later step u its amount lies between what is already due by u and that plus what every
food offered from t to u would deliver by u if all were eaten. The progress term telescopes
to ``lp (d_t - d_H)``; each comfort and overshoot term is bounded by its smallest value over
that box, and ``d_H`` by its smallest value. A sum of upper bounds is an upper bound.

:class:`DayModel` is the regime's dynamics and reward batched over nodes that may each be in
their own state, the model both searches plan on; the actions they return are meant to be
played in the env (:mod:`nutribench.baselines` does), whose returns are the ones reported
(the model matches the env to rounding, a test checks it).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from nutribench.config import EnvConfig
from nutribench.env.nutri_env import RegimeDynamics


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


#: Return tolerance of the exact search (a node is pruned only below the best known by more).
EXACT_TOLERANCE = 1e-9


@dataclass
class Nodes:
    """A batch of partial days at the same step: absorbed nutrients ``s`` (B, 3), what is due
    at each remaining step ``pending`` (B, H - t, 3; column 0 is due at the next step), what
    all that was eaten delivers by step H ``eventual`` (B, 3: ``s`` plus every pending
    amount, the planner's view), the distance ``d`` (B,), the return so far ``ret`` (B,) and
    the actions taken ``acts`` (B,), one bit per step (bit t set: ate at step t)."""

    s: np.ndarray
    pending: np.ndarray
    eventual: np.ndarray
    d: np.ndarray
    ret: np.ndarray
    acts: np.ndarray

    def take(self, idx: np.ndarray) -> Nodes:
        """The nodes ``idx`` (fresh arrays)."""
        return Nodes(self.s[idx], self.pending[idx], self.eventual[idx], self.d[idx], self.ret[idx], self.acts[idx])

    def __len__(self) -> int:
        return len(self.d)


class DayModel:
    """NutriRL's transition and reward from any state, batched over nodes (the env's own
    arithmetic: :class:`~nutribench.env.NutriRLVectorEnv`'s step, node by node)."""

    def __init__(self, regime: str | os.PathLike[str] | EnvConfig | RegimeDynamics):
        self.dyn = regime if isinstance(regime, RegimeDynamics) else RegimeDynamics(regime)
        self.lp, self.lc, self.lo, self.tau_c = self.dyn.coefficients
        self.horizon = self.dyn.horizon
        self.n_foods = self.dyn.n_foods
        self.schedule = self.dyn.schedule  # (N, H, 3)
        self.arrivals = self.dyn.arrivals  # (H, N, 3)
        self._delivered = np.cumsum(self.schedule, axis=1)  # (N, H, 3): arrived within offsets 0..k

    def start(self, n: int) -> Nodes:
        """``n`` days at their start."""
        H = self.horizon
        return Nodes(
            np.zeros((n, 3)),
            np.zeros((n, H, 3)),
            np.zeros((n, 3)),
            np.full(n, 3.0),
            np.zeros(n),
            np.zeros(n, dtype=np.int64),
        )

    def step(self, nodes: Nodes, t: int, food: np.ndarray, eat: np.ndarray) -> tuple[Nodes, np.ndarray]:
        """Nodes after step ``t`` (steps taken so far) with ``food`` (B,) offered and ``eat``
        (B,) bool, and the rewards (B,). ``nodes`` is consumed: its arrays may be updated in
        place (:meth:`Nodes.take` first to keep them)."""
        L = self.horizon - t
        pending, eventual = nodes.pending, nodes.eventual
        if eat.any():
            pending[eat] += self.schedule[food[eat], :L]
            eventual[eat] += self.arrivals[t, food[eat]]
        s = nodes.s + pending[:, 0]
        dev = s - 1.0
        d = np.abs(dev).sum(axis=1)
        over = np.maximum(dev, 0.0)
        r = self.lp * (nodes.d - d) - self.lc * np.tanh(d / self.tau_c) - self.lo * np.tanh((over * over).sum(axis=1))
        acts = nodes.acts | (eat.astype(np.int64) << t)
        return Nodes(s, pending[:, 1:], eventual, d, nodes.ret + r, acts), r

    def planner(self, nodes: Nodes, t: int, food: np.ndarray, min_gain: float = 0.05) -> np.ndarray:
        """The greedy planner's actions (:class:`PlannerPolicy`) at the
        nodes (the env sums what is pending where the nodes keep the sum: equal to rounding)."""
        return planner_eats(nodes.eventual, self.arrivals[t, food], 1.0, min_gain)

    def finish(self, nodes: Nodes, t: int, foods: np.ndarray) -> Nodes:
        """``nodes`` after step ``t`` played to the day's end by the greedy planner (:meth:`planner`),
        offered ``foods`` (B, H - t): column k at step t + k."""
        for u in range(t, self.horizon):
            f = foods[:, u - t]
            nodes, _ = self.step(nodes, u, f, self.planner(nodes, u, f))
        return nodes

    def most_added(self, foods: np.ndarray) -> list[np.ndarray]:
        """Per step t, ``(H - t, 3)``: the most that the foods offered at steps t .. t + j can
        deliver by step t + j (every one of them eaten), the day ``foods`` (H,)."""
        H = self.horizon
        out: list[np.ndarray] = [np.zeros((0, 3))] * (H + 1)
        for t in range(H - 1, -1, -1):
            m = self._delivered[foods[t], : H - t].copy()
            m[1:] += out[t + 1]
            out[t] = m
        return out

    def bound(self, nodes: Nodes, most_added: np.ndarray) -> np.ndarray:
        """An upper bound on the return the rest of the day can still bring each node (the
        module's docstring); ``most_added``: :meth:`most_added` at the nodes' step."""
        if nodes.pending.shape[1] == 0:
            return np.zeros(len(nodes))
        low = nodes.s[:, None, :] + np.cumsum(nodes.pending, axis=1)  # (B, L, 3)
        high = low + most_added[None]
        d_min = np.maximum(np.maximum(low - 1.0, 1.0 - high), 0.0).sum(axis=2)
        over_min = (np.maximum(low - 1.0, 0.0) ** 2).sum(axis=2)
        penalty = self.lc * np.tanh(d_min / self.tau_c) + self.lo * np.tanh(over_min)
        return self.lp * (nodes.d - d_min[:, -1]) - penalty.sum(axis=1)


# --------------------------------------------------------------------------- lookahead
def lookahead_actions(
    regime: str | EnvConfig | DayModel, foods: np.ndarray, samples: int = 64, seed: int = 0
) -> np.ndarray:
    """The lookahead policy's actions ``(n, H)`` on the days ``foods`` (n, H) (the module's
    docstring): at each step, both actions on ``samples`` sampled futures finished by the
    greedy planner; the better mean return is taken."""
    model = regime if isinstance(regime, DayModel) else DayModel(regime)
    foods = np.asarray(foods, dtype=np.int64)
    n, H = foods.shape
    K = int(samples)
    real = model.start(n)
    actions = np.zeros((n, H), dtype=np.int64)
    for t in range(H):
        futures = np.random.default_rng([int(seed), t]).integers(0, model.n_foods, size=(K, H - t - 1))
        # nodes: day-major, then action (skip, eat), then sample
        idx = np.repeat(np.arange(n), 2 * K)
        nodes = real.take(idx)
        nodes.ret = np.zeros(len(idx))
        eat = np.tile(np.repeat([False, True], K), n)
        nodes, _ = model.step(nodes, t, foods[idx, t], eat)
        nodes = model.finish(nodes, t + 1, np.tile(futures, (2 * n, 1)))  # the futures' foods from step t + 1
        mean = nodes.ret.reshape(n, 2, K).mean(axis=2)
        a = mean[:, 1] > mean[:, 0]
        actions[:, t] = a
        real, _ = model.step(real, t, foods[:, t], a)
    return actions


# --------------------------------------------------------------------------- clairvoyant
def _merge(nodes: Nodes) -> Nodes:
    """Nodes of the same state (to 12 decimals) merged, keeping the best return of each."""
    if not len(nodes):
        return nodes
    order = np.argsort(-nodes.ret, kind="stable")
    nodes = nodes.take(order)
    key = np.round(np.concatenate([nodes.s, nodes.pending.reshape(len(nodes), nodes.pending.shape[1] * 3)], axis=1), 12)
    key = np.ascontiguousarray(key + 0.0)  # -0.0 and 0.0 as one
    rows = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).ravel()
    _, first = np.unique(rows, return_index=True)
    return nodes.take(np.sort(first))


def _children(model: DayModel, nodes: Nodes, t: int, food: int) -> Nodes:
    B = len(nodes)
    both = nodes.take(np.concatenate([np.arange(B), np.arange(B)]))
    eat = np.concatenate([np.zeros(B, dtype=bool), np.ones(B, dtype=bool)])
    children, _ = model.step(both, t, np.full(2 * B, food), eat)
    return _merge(children)


def _best(nodes: Nodes) -> tuple[float, int]:
    """The best return among ``nodes`` and its actions (one bit per step)."""
    best = int(np.argmax(nodes.ret))
    return float(nodes.ret[best]), int(nodes.acts[best])


def _beam(model: DayModel, foods: np.ndarray, width: int, added: list[np.ndarray]) -> tuple[float, int]:
    nodes = model.start(1)
    for t in range(model.horizon):
        nodes = _children(model, nodes, t, int(foods[t]))
        if len(nodes) > width:
            key = nodes.ret + model.bound(nodes, added[t + 1])
            nodes = nodes.take(np.sort(np.argsort(-key, kind="stable")[:width]))
    return _best(nodes)


def _branch_and_bound(
    model: DayModel, foods: np.ndarray, incumbent: float, max_nodes: int, added: list[np.ndarray]
) -> tuple[float, int] | None:
    """The day's best return and its actions, proven; None when the frontier grows past ``max_nodes``."""
    nodes = model.start(1)
    for t in range(model.horizon):
        nodes = _children(model, nodes, t, int(foods[t]))
        keep = nodes.ret + model.bound(nodes, added[t + 1]) >= incumbent - EXACT_TOLERANCE
        nodes = nodes.take(np.flatnonzero(keep))
        if len(nodes) > max_nodes:
            return None
    return _best(nodes)


def clairvoyant_actions(
    regime: str | EnvConfig | DayModel, foods: np.ndarray, width: int = 256, max_nodes: int = 20_000
) -> tuple[np.ndarray, list[str]]:
    """The clairvoyant policy's actions ``(n, H)`` on the days ``foods`` (n, H) and, per day,
    ``"exact"`` (the best return of the day, proven by branch and bound) or ``"beam"`` (the
    beam search's day of ``width`` nodes: the proof would have held more than ``max_nodes``)."""
    model = regime if isinstance(regime, DayModel) else DayModel(regime)
    foods = np.asarray(foods, dtype=np.int64)
    n, H = foods.shape
    if H > 62:
        raise ValueError(f"the clairvoyant search keeps a day's actions in 63 bits: horizon {H} is too long")
    actions = np.zeros((n, H), dtype=np.int64)
    how: list[str] = []
    for i, day in enumerate(foods):
        added = model.most_added(day)
        # the first of equal returns stands: the beam's, then the planner's, then the proof's
        planned = _best(model.finish(model.start(1), 0, day[None]))  # the greedy planner's day
        best = max(_beam(model, day, width, added), planned, key=lambda found: found[0])
        proof = _branch_and_bound(model, day, best[0], max_nodes, added)
        how.append("beam" if proof is None else "exact")
        _, acts = max(best, proof or best, key=lambda found: found[0])
        actions[i] = (acts >> np.arange(H)) & 1  # one bit per step
    return actions, how
