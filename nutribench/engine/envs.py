"""The K agents' environments for the batched engine: one natively batched vector env per
regime (rows are agents), each agent's food days from its own seed, its observations
normalised by its own running statistics (SB3's ``VecNormalize``), and its training days'
metrics recorded as the SB3 engine records them. The observation is the vector env's at
each regime's observation level (the ladder of :mod:`nutribench.env.nutri_env`); one batch
needs one observation size, so its regimes share the catalog and the level."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from nutribench.agents.api import CLIP_OBS, NORM_EPS
from nutribench.config import EnvConfig, load_env_config
from nutribench.engine.stacked import RunningStats
from nutribench.env.metrics import EpisodeRecorder
from nutribench.env.vector_env import NutriRLVectorEnv

#: Mixed into each job seed for the batched engine's streams (foods, actions, minibatches and
#: replay samples, init).
STREAMS = {"foods": 1, "actions": 2, "minibatches": 3, "init": 4}

AgentEpisodeFn = Callable[[int, dict[str, Any]], None]


class OtherJobs(ValueError):
    """A checkpoint's envs are of other jobs than the batch reading it."""


class _Group:
    """The agents of one regime: one natively batched vector env, rows ``agents``."""

    def __init__(self, env_cfg: EnvConfig, agents: list[int]):
        self.agents = np.asarray(agents)
        self.env = NutriRLVectorEnv(len(agents), regime=env_cfg)
        self.recorder = EpisodeRecorder(len(agents))
        self.n_foods = len(env_cfg.catalog.food)


class AgentEnvs:
    """One env per ``(regime, seed)`` of ``jobs``, stepped together; every day starts and
    ends at once for all agents (one horizon)."""

    def __init__(
        self, jobs: Sequence[tuple[str | EnvConfig, int]], normalize_obs: bool, on_episode: AgentEpisodeFn | None = None
    ):
        self.env_cfgs = [load_env_config(r) for r, _ in jobs]
        self.seeds = [int(s) for _, s in jobs]
        self.k = len(jobs)
        horizons = {c.reward.horizon for c in self.env_cfgs}
        if len(horizons) != 1:
            raise ValueError(f"the agents of one batch need one horizon, got {sorted(horizons)}")
        self.horizon = horizons.pop()
        self.rng = {
            name: [np.random.default_rng([salt, seed]) for seed in self.seeds] for name, salt in STREAMS.items()
        }
        by_regime: dict[str, list[int]] = {}
        for j, c in enumerate(self.env_cfgs):
            by_regime.setdefault(c.sha256, []).append(j)
        self.groups = [_Group(self.env_cfgs[js[0]], js) for js in by_regime.values()]
        dims = {g.env.single_observation_space.shape[0] for g in self.groups}
        if len(dims) != 1:
            raise ValueError(
                f"the agents of one batch need one observation size (one food catalog and observation level), "
                f"got {sorted(dims)}"
            )
        self.obs_dim = dims.pop()
        self.obs_stats = RunningStats(self.k, (self.obs_dim,)) if normalize_obs else None
        self.on_episode = on_episode
        self.days_drawn: list[np.ndarray] = []  # each day's foods (K, horizon), for tests
        self.episodes: list[list[dict[str, Any]]] = [[] for _ in range(self.k)]
        #: each agent's validation rows so far (:mod:`nutribench.engine.evaluate`), kept in checkpoints
        self.validation: list[list[dict[str, Any]]] = [[] for _ in range(self.k)]
        self._entropy = np.zeros(self.k)

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint keeps of these envs, plain data only: the jobs (seeds, regime
        hashes), each random stream's bit generator state, the statistics, the days so far
        (the foods drawn as one ``(days, K, horizon)`` array), and each env's and recorder's
        arrays and counters (their ``_`` attributes)."""
        days = np.stack(self.days_drawn) if self.days_drawn else np.zeros((0, self.k, self.horizon), dtype=np.int64)
        return {
            "seeds": list(self.seeds),
            "regimes": [c.sha256 for c in self.env_cfgs],
            "rng": {name: [r.bit_generator.state for r in rs] for name, rs in self.rng.items()},
            "obs_stats": None if self.obs_stats is None else self.obs_stats.state_dict(),
            "days_drawn": days,
            "episodes": self.episodes,
            "validation": self.validation,
            "entropy": self._entropy,
            "groups": [{"env": _plain_state(g.env), "recorder": _plain_state(g.recorder)} for g in self.groups],
        }

    def load_state_dict(self, saved: dict[str, Any]) -> None:
        """Take over ``saved`` (:meth:`state_dict` of the same jobs, from a checkpoint),
        keeping this one's ``on_episode``; ValueError for a state of other jobs, or one that
        does not fit these envs (another code version)."""
        if saved["seeds"] != self.seeds or saved["regimes"] != [c.sha256 for c in self.env_cfgs]:
            raise OtherJobs("the checkpoint is of other jobs than this batch's")
        rng = saved["rng"]
        if not isinstance(rng, dict) or set(rng) != set(STREAMS) or any(len(rs) != self.k for rs in rng.values()):
            raise ValueError("the checkpoint's random streams do not fit this batch")
        if (saved["obs_stats"] is None) != (self.obs_stats is None) or len(saved["groups"]) != len(self.groups):
            raise ValueError("the checkpoint's envs do not fit this batch")
        for g, s in zip(self.groups, saved["groups"]):
            _set_plain_state(g.env, s["env"])
            _set_plain_state(g.recorder, s["recorder"])
        self.rng = {name: [_generator(state) for state in states] for name, states in rng.items()}
        if self.obs_stats is not None:
            self.obs_stats.load_state_dict(saved["obs_stats"])
        self._entropy = np.asarray(saved["entropy"], dtype=np.float64)
        self.days_drawn, self.episodes = list(saved["days_drawn"]), [list(e) for e in saved["episodes"]]
        self.validation[:] = [list(v) for v in saved.get("validation") or [[] for _ in range(self.k)]]  # in place

    def new_days(self) -> np.ndarray:
        """Start a day for every agent (foods from its own stream); the raw observations."""
        raw = np.empty((self.k, self.obs_dim))
        day = np.empty((self.k, self.horizon), dtype=np.int64)
        for g in self.groups:
            foods = np.stack([self.rng["foods"][j].integers(0, g.n_foods, size=self.horizon) for j in g.agents])
            o, _ = g.env.reset(options={"foods": foods})
            raw[g.agents], day[g.agents] = o, foods
        self.days_drawn.append(day)
        return raw

    def seen(self, raw: np.ndarray) -> np.ndarray:
        """Observations ``(K, obs_dim)`` as the policies see them: the statistics updated
        with them first, then normalised and clipped (``VecNormalize`` in training)."""
        if self.obs_stats is not None:
            self.obs_stats.update(raw)
        return self.normalize(raw)

    def normalize(self, raw: np.ndarray) -> np.ndarray:
        """``raw (K, ..., obs_dim)`` normalised by each agent's current statistics, no update."""
        if self.obs_stats is None:
            return raw.astype(np.float32)
        shape = (self.k,) + (1,) * (raw.ndim - 2) + (self.obs_dim,)
        mean, var = self.obs_stats.mean.reshape(shape), self.obs_stats.var.reshape(shape)
        return np.clip((raw - mean) / np.sqrt(var + NORM_EPS), -CLIP_OBS, CLIP_OBS).astype(np.float32)

    def step(self, actions: np.ndarray, entropy: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, bool]:
        """Step every agent: raw next observations, raw rewards, and whether the day ended
        (then recorded for each agent, with its policy's mean ``entropy`` over the day, or
        None for a policy without one)."""
        if entropy is not None:
            self._entropy += entropy
        raw_next = np.empty((self.k, self.obs_dim))
        rewards = np.empty(self.k)
        day_over = False
        for g in self.groups:
            o, r, term, trunc, info = g.env.step(actions[g.agents])
            raw_next[g.agents], rewards[g.agents] = o, r
            ended = term | trunc
            for row, metrics in zip(np.flatnonzero(ended), g.recorder.record(r, ended, info)):
                j = int(g.agents[row])
                day_entropy = None if entropy is None else float(self._entropy[j] / self.horizon)
                metrics = {"episode": len(self.episodes[j]), **metrics, "entropy": day_entropy}
                self.episodes[j].append(metrics)
                if self.on_episode is not None:
                    self.on_episode(j, metrics)
            day_over = bool(ended.all())
        if day_over:
            self._entropy[:] = 0.0
        return raw_next, rewards, day_over


def _generator(state: Any) -> np.random.Generator:
    """A numpy generator (PCG64, as ``default_rng`` makes them) in ``state``; ValueError for another."""
    if not isinstance(state, dict) or state.get("bit_generator") != "PCG64":
        raise ValueError("the checkpoint's random streams do not fit this batch")
    bit_generator = np.random.PCG64()
    bit_generator.state = state
    return np.random.Generator(bit_generator)


def _plain_state(obj: Any) -> dict[str, Any]:
    """``obj``'s own ``_`` attributes that are arrays or numbers: an env's or recorder's state."""
    return {k: v for k, v in vars(obj).items() if k.startswith("_") and isinstance(v, (np.ndarray, int, float))}


def _set_plain_state(obj: Any, state: dict[str, Any]) -> None:
    """Put ``state`` (:func:`_plain_state` of a like object) into ``obj``, each attribute of
    the type (arrays: dtype and shape) it has there; ValueError where one does not fit."""
    mine = _plain_state(obj)
    if not isinstance(state, dict) or set(state) != set(mine):
        raise ValueError(f"the checkpoint's {type(obj).__name__} state does not fit this batch")
    for key, value in state.items():
        have = mine[key]
        array = isinstance(have, np.ndarray)  # then of its dtype and shape too
        if type(value) is not type(have) or (array and (value.dtype, value.shape) != (have.dtype, have.shape)):
            raise ValueError(f"the checkpoint's {type(obj).__name__}.{key} does not fit this batch")
        setattr(obj, key, value)
