"""NutriRL: regulating three macronutrients under delayed, overlapping absorption.

## Description

Each step (~30 minutes) one food from a catalog of N items is offered; the agent skips it
or eats it. What it eats is absorbed gradually over later steps through Gaussian kernels,
overlapping with earlier meals and irreversible, so the observed state lags behind the
decisions. The agent must bring its cumulative absorbed carbohydrates, fats and proteins
to a hidden daily target without overshooting. This is the NutriRL environment; the
delay statistics come from a regime file (``regimes/run0.toml`` .. ``run6.toml``).

## Action space

``Discrete(2)``: 0 skips the offered food, 1 eats it.

## Observation space

A flat ``Box(low, high, (3 + N,), float32)``: the absorbed nutrients ``s_t = (C, F, P)`` in
units of the daily target, followed by the one-hot embedding of the food offered next
(N = 10 for the shipped catalog). This is level 1 of the observation ladder, the paper's
observation: the backlog of pending absorption, the target and the time of day are not
observed (a POMDP). A regime file climbs the ladder with its observation options (all
``false`` by default, none set by a shipped regime; a rung needs the ones below it); each
rung appends its columns, in this order:

* level 2, ``observe_clock = true``: the clock ``t / H`` (steps taken over the horizon: 0 at
  reset, 1 in the final observation), 1 column;
* level 3, ``+ observe_pending = true``: per nutrient, what is eaten but not yet absorbed and
  will still arrive by step H (``pending_by_horizon()``), 3 columns;
* level 4, ``+ observe_latent = true``: the pending schedule, the amounts of C, F and P due at
  each of the next W = H - 1 steps, step by step (``[C, F, P]`` due at step t + 1, then at
  t + 2, ...; zero past step H), 3 W columns, and the target ``T`` (in target units, always
  (1, 1, 1)), 3 columns. W = H - 1 is every step the day still has after the first, so the
  schedule holds everything still to arrive and the observation is the full state (the
  future foods are exogenous and drawn fresh): the task is Markov. One W for every regime
  (run6's kernels reach past the day, run0 has none) keeps one observation size per catalog.

Sizes for the shipped catalog and horizon: 13, 14, 17, 167. ``columns`` (inspection) names
each part's slice. Bounds: 0 below; above, nothing can exceed eating the richest food every
step (nutrients, pending), 1 (one-hot, clock, target), and one meal per earlier step at its
own offset (each schedule entry). The target's columns are always exactly 1; their lower
bound is 0, not 1, because Gymnasium warns about a Box whose bounds are equal. A flat Box rather than a Dict
so that every Stable-Baselines3 policy and normaliser works on it unchanged; the recurrent
agent splits it by index (``obs[:3]`` nutrients, ``obs[3:]`` the rest: the food one-hot and
any rungs above level 1 go to its food stream). The observation returned by the final step
has an all-zero food part: the day is over and nothing is offered.

## Transition

Eating food i at step t (steps are numbered 1..H) schedules ``m_n(i) * w_k`` of nutrient
n at step t + k, with the kernel weights w of :func:`~nutribench.env.nutri_env.kernel` (window
t+1 .. t+ceil(6 sigma); with sigma = 0 everything at t + round(tau); with tau = sigma = 0
in the same step, so the observation returned by that step already contains it). Then
``s_t = s_{t-1} + (everything due at step t)``. Absorption due after step H never arrives.

## Reward

With ``d_t = |s_t - T|_1`` and ``d_0 = |T|_1`` (T = (1, 1, 1) in target units)::

    r_t = lp (d_{t-1} - d_t) - lc tanh(d_t / tau_c) - lo tanh(|max(0, s_t - T)|_2^2)

(progress, comfort, overshoot), with the coefficients of ``regimes/reward.toml``.
Its version 2 (lp = lc = 1, tau_c = 6.5, lo = 1) gives the authors' reward landscape in
target units (their units divide each nutrient by its catalog column's L2 norm, where
d_0 = 2.29 and tau_c = 5): comfort ``tanh(d / 6.5)`` is nearly linear over a day, so on
run0 never eating scores -21.6 a day, eating at random about -76 and the planner of
:mod:`nutribench.env.policies` about -3.

## Episode end

No termination; the episode is truncated after H = 50 steps (``truncated=True``).

## Info

``state`` (s_t in float64), ``distance`` (d_t), ``overshoot`` (per-nutrient bool array, s_t > T), ``foods_consumed``
(so far), ``ate`` (this step), ``food`` (index offered this step), ``step`` (t), and the
reward's three signed terms ``reward_progress``, ``reward_comfort``, ``reward_overshoot``
(they sum to the reward).

## Arguments

``regime``: a regime name (``"run3"``), a path to a regime file, or an
:class:`~nutribench.config.EnvConfig`. ``render_mode``: ``None``, ``"ansi"`` or
``"rgb_array"`` (a 240 x 320 picture of the three nutrients against the target, drawn with
numpy alone). ``reset(seed=...)`` seeds the food stream (the only randomness);
``reset(options={"foods": [i_1, ..., i_H]})`` plays a given food stream instead.

## Inspection

``masses`` (N x 3, target units), ``tau`` and ``sigma`` (N x 3, steps), ``target`` (3,),
``reward_config``, ``horizon``, ``food_names``, ``schedule`` (N x H x 3 absorption per
offset), ``state`` and ``pending_by_horizon()`` (what is still due by step H); on ``dyn``,
``observation_level``, ``columns`` and ``window``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from nutribench.config import EnvConfig, load_env_config


def kernel(tau: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets k (steps after consumption) and weights (summing to 1) of one absorption kernel
    (pure numpy, computed once per regime).

    A food consumed at step t with mean delay ``tau`` and spread ``sigma`` (steps) delivers its
    amount over steps u = t+1 .. t+ceil(6 sigma) with weights
    ``exp(-0.5 ((u - (t + tau)) / sigma) ** 2)`` normalised to sum to 1 over that window.
    With sigma = 0 the whole amount arrives at step t + round(tau) (round half up), which is
    the same step t when tau = 0. Kernels are indexed by the offset k = u - t >= 0."""
    if sigma < 0 or tau < 0:
        raise ValueError(f"tau and sigma must be >= 0, got tau={tau}, sigma={sigma}")
    if sigma == 0:
        return np.array([int(math.floor(tau + 0.5))]), np.ones(1)  # round half up
    offsets = np.arange(1, math.ceil(6 * sigma) + 1)
    with np.errstate(over="ignore"):
        logw = -0.5 * ((offsets - tau) / sigma) ** 2
    if np.isfinite(logw.max()):
        # Subtracting the max before exp changes nothing after normalisation but keeps a
        # window far from tau (all weights tiny) from underflowing to 0/0.
        w = np.exp(logw - logw.max())
    else:  # sigma so small that every weight overflows: the limit puts all on the nearest offset(s)
        dist = np.abs(offsets - tau)
        w = (dist == dist.min()).astype(np.float64)
    return offsets, w / w.sum()


def absorption_schedule(masses: np.ndarray, tau: np.ndarray, sigma: np.ndarray, length: int) -> np.ndarray:
    """``A[i, k, n]``: amount of nutrient n of food i absorbed k steps after eating it.

    Offsets at or beyond ``length`` are dropped: with ``length = horizon`` that is exactly
    what can never arrive within an episode (eaten at step t >= 1, arriving after step H).
    """
    n_foods, n_nut = masses.shape
    A = np.zeros((n_foods, length, n_nut))
    for i in range(n_foods):
        for n in range(n_nut):
            offsets, w = kernel(float(tau[i, n]), float(sigma[i, n]))
            keep = offsets < length
            A[i, offsets[keep], n] = masses[i, n] * w[keep]
    return A


def arrivals_by_horizon(schedule: np.ndarray, horizon: int) -> np.ndarray:
    """``R[t, i, n]``: amount of nutrient n of food i that arrives by step H when eaten after
    t steps have been taken (i.e. at step t + 1). Used by the planner."""
    cums = np.cumsum(schedule, axis=1)  # (N, L, 3): arrived within offsets 0..k
    # R[t] = cums[:, H - t - 1]: eaten at step t+1, offsets up to H-(t+1)
    return np.ascontiguousarray(cums[:, horizon - 1 :: -1, :].transpose(1, 0, 2))


class RegimeDynamics:
    """Everything precomputed once per regime and shared by the single and vector envs."""

    def __init__(self, regime: str | os.PathLike[str] | EnvConfig):
        self.config = cfg = load_env_config(regime)
        self.reward_config = cfg.reward
        #: The reward's coefficients (lp, lc, lo, tau_c), which each stepping model keeps at hand.
        self.coefficients = (cfg.reward.lp, cfg.reward.lc, cfg.reward.lo, cfg.reward.tau_c)
        self.horizon = cfg.reward.horizon
        self.masses = cfg.masses()
        self.tau = cfg.tau()
        self.sigma = cfg.sigma()
        self.n_foods = self.masses.shape[0]
        self.food_names = list(cfg.catalog.keys)
        self.target = np.ones(3)
        self.schedule = absorption_schedule(self.masses, self.tau, self.sigma, self.horizon)
        self.arrivals = arrivals_by_horizon(self.schedule, self.horizon)
        #: The observation options of the regime (the observation ladder, levels 1..4).
        self.observe_clock = cfg.regime.observe_clock
        self.observe_pending = cfg.regime.observe_pending
        self.observe_latent = cfg.regime.observe_latent
        self.observation_level = cfg.regime.observation_level
        #: Steps of the pending schedule in a level-4 observation: every step still in the day.
        self.window = self.horizon - 1 if self.observe_latent else 0
        self._layout()
        self.action_space = spaces.Discrete(2)

    def _layout(self) -> None:
        """Column slices of the observation's parts, honest bounds, and one template row per
        food offered (the last row: nothing offered)."""
        H, N, W = self.horizon, self.n_foods, self.window
        # Nothing can exceed eating the richest food every step; an amount due at one step is at
        # most one meal per earlier step, each at its own offset.
        eaten = H * self.masses.max(axis=0)
        parts = [("state", np.zeros(3), eaten), ("food", np.zeros(N), np.ones(N))]
        if self.observe_clock:
            parts.append(("clock", np.zeros(1), np.ones(1)))
        if self.observe_pending:
            parts.append(("pending", np.zeros(3), eaten))
        if self.observe_latent:
            parts.append(("schedule", np.zeros(3 * W), np.tile(self.schedule.max(axis=0).sum(axis=0), W)))
            parts.append(("target", np.zeros(3), self.target.copy()))  # exactly T; 0 below: see the docstring
        self.columns: dict[str, slice] = {}
        start = 0
        for name, low, _ in parts:
            self.columns[name] = slice(start, start + low.size)
            start += low.size
        low = np.concatenate([p[1] for p in parts]).astype(np.float32)
        high = np.concatenate([p[2] for p in parts]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.has_extras = self.observe_clock or self.observe_pending or self.observe_latent
        self.obs_template = np.zeros((N + 1, start), dtype=np.float32)
        self.obs_template[np.arange(N), 3 + np.arange(N)] = 1.0
        if self.observe_latent:
            self.obs_template[:, self.columns["target"]] = self.target

    def write_extras(self, obs: np.ndarray, t: int, pending: np.ndarray) -> None:
        """Fill the rungs above level 1 into ``obs`` ``(n, width)`` (a template's copies) after
        ``t`` steps, from ``pending`` ``(H, 3, n)``: row u holds what arrives at step u + 1."""
        H, cols = self.horizon, self.columns
        if self.observe_clock:
            obs[:, cols["clock"]] = t / H
        if self.observe_pending:
            obs[:, cols["pending"]] = pending[t:].sum(axis=0).T
        if self.observe_latent:
            w = min(self.window, H - t)  # nothing arrives after step H: the rest stays zero
            start = cols["schedule"].start
            obs[:, start : start + 3 * w] = pending[t : t + w].transpose(2, 0, 1).reshape(pending.shape[2], 3 * w)

    def check_foods(self, foods: Any, shape: tuple[int, ...]) -> np.ndarray:
        arr = np.asarray(foods)
        if arr.shape != shape or not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"options['foods'] must be integers of shape {shape}, got {arr.dtype} {arr.shape}")
        if arr.size and (arr.min() < 0 or arr.max() >= self.n_foods):
            raise ValueError(f"options['foods'] must index the catalog (0..{self.n_foods - 1})")
        return arr.astype(np.int64)


class DynamicsView:
    """The inspection API the single and the vector env share: the regime's constants,
    read from ``self.dyn`` (:class:`RegimeDynamics`), and ``steps_taken`` (the steps of the day so far)."""

    dyn: RegimeDynamics
    steps_taken = property(lambda self: self._t)
    config = property(lambda self: self.dyn.config)
    masses = property(lambda self: self.dyn.masses)
    tau = property(lambda self: self.dyn.tau)
    sigma = property(lambda self: self.dyn.sigma)
    target = property(lambda self: self.dyn.target)
    reward_config = property(lambda self: self.dyn.reward_config)
    horizon = property(lambda self: self.dyn.horizon)
    food_names = property(lambda self: self.dyn.food_names)
    schedule = property(lambda self: self.dyn.schedule)


class NutriRLEnv(DynamicsView, gym.Env[np.ndarray, int]):
    __doc__ = __doc__
    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 4}

    def __init__(self, regime: str | os.PathLike[str] | EnvConfig = "run0", render_mode: str | None = None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.dyn = RegimeDynamics(regime)
        self.render_mode = render_mode
        self.observation_space = self.dyn.observation_space
        self.action_space = self.dyn.action_space
        self._lp, self._lc, self._lo, self._tau_c = self.dyn.coefficients
        self._H = self.dyn.horizon
        self._A = self.dyn.schedule
        self._pending = np.zeros((self._H, 3))
        self._foods = np.zeros(self._H, dtype=np.int64)
        self._t = self._H  # must reset first
        self._s = [0.0, 0.0, 0.0]
        self._d = 3.0
        self._eaten = 0

    @property
    def state(self) -> np.ndarray:
        """Absorbed nutrients s_t (target units)."""
        return np.array(self._s)

    @property
    def offered(self) -> int:
        """Index of the food offered at the next step (-1 once the episode is over)."""
        return int(self._foods[self._t]) if self._t < self._H else -1

    def pending_by_horizon(self) -> np.ndarray:
        """Nutrients already eaten but not yet absorbed that will arrive by step H."""
        return self._pending[self._t :].sum(axis=0)

    # ---- gymnasium API ----
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if options and "foods" in options:
            self._foods = self.dyn.check_foods(options["foods"], (self._H,))
        else:
            self._foods = self.np_random.integers(0, self.dyn.n_foods, size=self._H)
        self._pending[:] = 0.0
        self._t = 0
        self._s = [0.0, 0.0, 0.0]
        self._d = 3.0
        self._eaten = 0
        obs = self.dyn.obs_template[self._foods[0]].copy()
        info = {
            "state": np.zeros(3),
            "distance": self._d,
            "overshoot": np.zeros(3, dtype=bool),
            "foods_consumed": 0,
            "step": 0,
        }
        return obs, info

    def step(self, action):
        t = self._t
        H = self._H
        if t >= H:
            raise RuntimeError("step() called after the episode ended: call reset() first")
        food = self._foods[t]
        pending = self._pending
        ate = action == 1
        if ate:
            pending[t:] += self._A[food, : H - t]
            self._eaten += 1
        elif action != 0:
            raise ValueError(f"action must be 0 (skip) or 1 (eat), got {action!r}")
        c, f, p = pending[t].tolist()
        s = self._s
        C, F, P = s[0] + c, s[1] + f, s[2] + p
        self._s = [C, F, P]
        d = abs(C - 1.0) + abs(F - 1.0) + abs(P - 1.0)
        oc, of, op = max(0.0, C - 1.0), max(0.0, F - 1.0), max(0.0, P - 1.0)
        progress = self._lp * (self._d - d)
        comfort = -self._lc * math.tanh(d / self._tau_c)
        overshoot = -self._lo * math.tanh(oc * oc + of * of + op * op)
        self._d = d
        self._t = t = t + 1
        truncated = t == H
        obs = self.dyn.obs_template[-1 if truncated else self._foods[t]].copy()
        obs[0], obs[1], obs[2] = C, F, P
        if self.dyn.has_extras:
            self.dyn.write_extras(obs[None], t, pending[:, :, None])
        info = {
            "state": np.array(self._s),
            "distance": d,
            "overshoot": np.array((oc > 0.0, of > 0.0, op > 0.0)),
            "foods_consumed": self._eaten,
            "ate": bool(ate),
            "food": int(food),
            "step": t,
            "reward_progress": progress,
            "reward_comfort": comfort,
            "reward_overshoot": overshoot,
        }
        return obs, progress + comfort + overshoot, False, truncated, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='ansi' or 'rgb_array'")
            return None
        if self.render_mode == "rgb_array":  # numpy alone: the nutrients, absorbed and on their way, against the target
            return nutrient_picture(self._s, self.pending_by_horizon(), self._t, self.horizon)
        C, F, P = self._s
        offered = self.food_names[self.offered] if self.offered >= 0 else "-"
        return (
            f"step {self._t:2d}/{self.horizon}  C {C:5.2f}  F {F:5.2f}  P {P:5.2f}  (target 1.00)  "
            f"distance {self._d:5.2f}  eaten {self._eaten:2d}  offered: {offered}\n"
        )


# ---- the ``render_mode="rgb_array"`` picture (:func:`nutrient_picture`), drawn with numpy alone ----

#: The picture's size, (height, width) in pixels.
SIZE: tuple[int, int] = (240, 320)
#: C, F, P: the colours of the three nutrients (RGB).
COLORS: tuple[tuple[int, int, int], ...] = ((76, 114, 176), (221, 132, 82), (85, 168, 104))
_WHITE, _BLACK, _GREY = (255, 255, 255), (0, 0, 0), (170, 170, 170)
#: 3 x 5 pixel letters under the bars (1 = ink), each scaled up when drawn.
_GLYPHS = {
    "C": ("111", "100", "100", "100", "111"),
    "F": ("111", "100", "110", "100", "100"),
    "P": ("111", "101", "111", "100", "100"),
}


def _glyph(img: np.ndarray, letter: str, top: int, left: int, scale: int) -> None:
    ink = np.kron([[c == "1" for c in row] for row in _GLYPHS[letter]], np.ones((scale, scale))) > 0
    img[top : top + 5 * scale, left : left + 3 * scale][ink] = _BLACK  # each pixel of the letter a scale x scale block


def nutrient_picture(absorbed: Sequence[float], pending: Sequence[float], step: int, horizon: int) -> np.ndarray:
    """An RGB picture (uint8, shape ``SIZE + (3,)``) of the nutrients ``absorbed`` (C, F, P,
    as multiples of the daily target) and those ``pending`` (eaten, arriving by the end of the
    day) against the target, after ``step`` of ``horizon`` steps.

    The environment's ``render_mode="rgb_array"`` picture, drawn with numpy alone (the base
    install, gymnasium, numpy and pydantic, has no plotting library; Gymnasium's ``check_env``
    renders every mode the metadata lists).

    It draws three bars, carbohydrates, fats and proteins in the colours the
    report gives them, each the amount absorbed so far (solid) with what is eaten and still on its
    way by the end of the day stacked on it (striped), against the daily target (a dashed black
    line at 1.0); under each bar its letter, and along the top a bar of the day's progress (steps
    taken of the horizon). The vertical scale runs from 0 to 1.5 times the target, or further when
    a bar reaches higher. Pixels only, no text rendering: a picture a video recorder can store."""
    h, w = SIZE
    img = np.full((h, w, 3), _WHITE, dtype=np.uint8)
    absorbed = np.clip(np.asarray(absorbed, dtype=float), 0.0, None)
    pending = np.clip(np.asarray(pending, dtype=float), 0.0, None)
    top_value = max(1.5, float(np.max(absorbed + pending)) * 1.1)
    plot_top, plot_bottom, left, right = 28, h - 30, 24, w - 16
    span = plot_bottom - plot_top

    def y_of(value: float) -> int:  # the pixel row of a value (0 at the bottom of the plot)
        return int(round(plot_bottom - span * min(value, top_value) / top_value))

    # the day's progress along the top
    img[8:16, left:right] = _GREY
    done = left + int(round((right - left) * min(max(step, 0), horizon) / max(horizon, 1)))
    img[8:16, left:done] = _BLACK
    # the bars
    slot = (right - left) // 3
    bar = int(slot * 0.6)
    rows = np.arange(h)[:, None]
    cols = np.arange(w)[None, :]
    for i, (a, p, color) in enumerate(zip(absorbed, pending, COLORS)):
        x0 = left + i * slot + (slot - bar) // 2
        x1 = x0 + bar
        y_abs, y_all = y_of(a), y_of(a + p)
        img[y_abs:plot_bottom, x0:x1] = color
        if y_all < y_abs:  # pending: diagonal stripes of the nutrient's colour over white, outlined
            stripes = ((rows[y_all:y_abs] + cols[:, x0:x1]) // 4) % 2 == 0
            region = img[y_all:y_abs, x0:x1]
            region[stripes] = color
            img[y_all:y_abs, [x0, x1 - 1]] = _GREY
            img[y_all, x0:x1] = _GREY
        _glyph(img, "CFP"[i], plot_bottom + 6, x0 + bar // 2 - 6, 4)
    # the axis and the target, dashed
    img[plot_bottom : plot_bottom + 2, left - 4 : right] = _BLACK
    img[plot_top:plot_bottom, left - 4 : left - 2] = _BLACK
    y_target = y_of(1.0)
    for x in range(left - 4, right, 12):
        img[y_target - 1 : y_target + 1, x : min(x + 7, right)] = _BLACK
    return img
