"""What every batched algorithm is: :class:`BatchedAlgorithm`, the interface the training loops
(:mod:`nutribench.engine.on_policy`, :mod:`nutribench.engine.off_policy`) call and each
algorithm module implements (:mod:`~nutribench.engine.mc`, :mod:`~nutribench.engine.ppo`,
:mod:`~nutribench.engine.gru_ppo`, :mod:`~nutribench.engine.ddqn`, :mod:`~nutribench.engine.sac`),
as SB3's ``BaseAlgorithm`` is for its algorithms; :func:`~nutribench.engine.train.train_batched`
picks the class by the config's ``algo`` in one lookup.

An algorithm is made for one agent config and one batch of envs (:class:`~nutribench.engine.envs.AgentEnvs`,
K agents); :meth:`BatchedAlgorithm.learn` trains it for a number of env steps (resuming from a
checkpoint when it holds a state), and each agent is then handed back with
:meth:`BatchedAlgorithm.store_weights`. While it learns, an algorithm records each agent's
per-update diagnostics (:attr:`BatchedAlgorithm.diagnostics`, the vocabulary of
:mod:`nutribench.diagnostics`).

Its whole training state is explicit, as a torch module's is: :meth:`BatchedAlgorithm.state_dict`
gives it as plain data (tensors, numpy arrays, numbers, strings, lists, dicts: the envs and
random streams, the networks' parameters, the optimisers' ``state_dict``, the statistics,
the replay, the diagnostics so far), which :class:`~nutribench.engine.checkpoint.Checkpoint`
writes; :meth:`BatchedAlgorithm.load_state_dict` puts such a state back into a freshly made
algorithm of the same jobs and config (in place: parameters copied into the networks the
optimisers already hold), so that training goes on exactly where it was saved.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np
import torch as th

from nutribench import diagnostics as names
from nutribench.agents.algos import build_model
from nutribench.agents.api import TrainedAgent, make_train_env, training_provenance
from nutribench.engine.checkpoint import Checkpoint, CheckpointRefused
from nutribench.engine.envs import AgentEnvs, OtherJobs
from nutribench.engine.evaluate import BatchValidator, Greedy
from nutribench.engine.stacked import AgentMeans, RunningStats
from nutribench.engines import Engine


class BatchedAlgorithm:
    """K agents of one algorithm and agent config, trained together on ``envs``.

    Subclasses implement :meth:`learn` (through a loop's base class) and
    :meth:`store_weights`; the algorithm registry names the class for its configs' ``algo``
    (:mod:`nutribench.agents.registry`)."""

    #: the config fields that may differ between the agents of one batch (tuning trials
    #: stacked: :mod:`nutribench.tuning.stack`); empty: every agent has the batch's config
    PER_AGENT: ClassVar[tuple[str, ...]] = ()

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device, cfgs: Sequence[Any] | None = None):
        self.cfg, self.envs, self.device, self.k = cfg, envs, device, envs.k
        #: the agent configs' ``algo`` (what a checkpoint records)
        self.algo: str = cfg.algo
        #: each agent's config: ``cfg`` for all, or (tuning trials stacked in one batch) one
        #: each, differing only in continuous settings (the algorithm checks which it can take)
        self.cfgs: list[Any] = [cfg] * envs.k if cfgs is None else list(cfgs)
        if len(self.cfgs) != envs.k:
            raise ValueError(f"{len(self.cfgs)} agent configs for {envs.k} agents")
        #: per agent, one dict per update (on-policy: rollout; off-policy: training day), keys
        #: from :mod:`nutribench.diagnostics`
        self.diagnostics: list[list[dict[str, float]]] = [[] for _ in range(envs.k)]
        #: on-policy: called before each update with the rollout's arrays (``train_batched``'s ``on_rollout``)
        self.on_rollout: Callable[[dict[str, np.ndarray]], None] | None = None
        #: off-policy: called after each gradient step with its step count and losses (``on_update``)
        self.on_update: Callable[[dict[str, Any]], None] | None = None
        #: env steps of each agent so far (SB3's ``num_timesteps`` with one env)
        self.num_timesteps = 0
        #: the evaluations during training (``train_batched``'s ``eval_every``), None: none
        self.validator: BatchValidator | None = None
        #: the agents' running statistics of the discounted return (reward scaling), if any
        self.ret_stats: RunningStats | None = None
        #: the quantities of the update (off-policy: the day) in progress, their means then recorded
        self.means = AgentMeans()
        #: the observations the agents act on next, as the policies see them (None until the first day starts)
        self.last_obs: np.ndarray | None = None

    def trained_agents(self, episodes: int, wall: float) -> list[TrainedAgent]:
        """Each agent (trained for ``episodes`` days in ``wall`` seconds, the batch's) as the SB3
        engine's :class:`~nutribench.agents.api.TrainedAgent` of its config, as ``agents.train``
        returns it: the SB3 model of its config in its ``VecNormalize``, with the trained weights
        (:meth:`store_weights`; the model is on the CPU whatever the device that trained it, its
        provenance names that device), its training days, ``diagnostics`` and ``validation``."""
        envs, agents = self.envs, []
        share = wall / self.k
        batched = {"engine": Engine.BATCHED.value, "device": str(self.device), "batch_wall_seconds_per_agent": share}
        for j, cfg in enumerate(self.cfgs):
            env_cfg, seed, obs_stats = envs.env_cfgs[j], envs.seeds[j], envs.obs_stats
            _, env = make_train_env(env_cfg, cfg)
            model = build_model(cfg, env, seed=seed, horizon=env_cfg.reward.horizon)
            self.store_weights(j, model)
            mean = var = None
            if obs_stats is not None:
                mean, var = obs_stats.mean[j].copy(), obs_stats.var[j].copy()
                rms = env.obs_rms
                rms.mean, rms.var, rms.count = mean.copy(), var.copy(), float(obs_stats.count[j])
            if self.ret_stats is not None:
                for name in ("mean", "var", "count"):
                    setattr(env.ret_rms, name, float(getattr(self.ret_stats, name)[j]))
            provenance = training_provenance(env_cfg, cfg, seed, episodes) | batched
            vec_normalize = env if hasattr(env, "obs_rms") else None
            agent = TrainedAgent(model, cfg.algo, cfg, mean, var, vec_normalize=vec_normalize, provenance=provenance)
            agent.train_episodes = envs.episodes[j]
            agent.diagnostics, agent.validation = self.diagnostics[j], envs.validation[j]
            agents.append(agent)
        return agents

    def set_active(self, active: np.ndarray | None) -> None:
        """Apply updates only to the agents where ``active`` (a ``(K,)`` bool array the caller
        may change while training: a pruned tuning trial's agents are frozen); None: all. Only
        algorithms with per-agent settings (``PER_AGENT``) take it, into their ``settings``."""
        if not self.PER_AGENT:
            if active is not None or any(c != self.cfg for c in self.cfgs):
                raise ValueError(f"the batched {self.algo} takes neither per-agent settings nor frozen agents yet")
            return
        if active is not None and np.shape(active) != (self.k,):
            raise ValueError(f"active: a ({self.k},) bool array, got shape {np.shape(active)}")
        self.settings.active = active  # type: ignore[attr-defined]

    def init_generators(self) -> list[th.Generator]:
        """One CPU generator per agent for its initial weights, seeded from its ``init`` stream."""
        return [th.Generator().manual_seed(int(r.integers(2**62))) for r in self.envs.rng["init"]]

    def learn(self, total_steps: int, checkpoint: Checkpoint | None = None) -> float:
        """Train for ``total_steps`` env steps of each agent (from ``checkpoint``'s state if it
        holds one, saving to it when due); the wall seconds, those before a resume included."""
        raise NotImplementedError

    def store_weights(self, j: int, model: Any) -> None:
        """Put agent ``j``'s trained weights into ``model``, the SB3 model of its config (here:
        the algorithm's stacked network ``net`` into the model's policy)."""
        self.net.store_sb3(j, model.policy)  # type: ignore[attr-defined]

    def resume(self, checkpoint: Checkpoint | None) -> float:
        """Take over ``checkpoint``'s state when it holds one (read onto this algorithm's
        device); the training seconds spent before it (0 when there is none). A state that
        does not fit raises :class:`~nutribench.engine.checkpoint.CheckpointRefused`."""
        saved = checkpoint.read_onto(self.device) if checkpoint is not None else None
        if saved is None:
            return 0.0
        try:
            self.load_state_dict(saved)
        except OtherJobs:
            raise  # a checkpoint named for another batch: a bug to see, not a state to drop
        except (KeyError, IndexError, TypeError, ValueError, RuntimeError) as exc:
            raise CheckpointRefused(f"its state does not fit this batch: {exc}") from exc
        return checkpoint.seconds_before

    def state_dict(self) -> dict[str, Any]:
        """The training state as plain data (the module docstring): here what every algorithm
        has (its ``algo``, the env steps, the envs, the diagnostics); each loop adds its own."""
        return {
            "algo": self.algo,
            "steps": self.num_timesteps,
            "envs": self.envs.state_dict(),
            "diagnostics": self.diagnostics,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Take over ``state`` (a :meth:`state_dict` of an algorithm of the same jobs and
        config); ValueError where it does not fit (other jobs, another algorithm)."""
        if state.get("algo") != self.algo:
            raise ValueError(f"the checkpoint is of algorithm {state.get('algo')!r}, not {self.algo!r}")
        self.envs.load_state_dict(state["envs"])
        self.diagnostics = [list(rows) for rows in state["diagnostics"]]
        self.num_timesteps = int(state["steps"])

    def greedy(self) -> Greedy:
        """A fresh greedy player of the K agents' current policies for days played side by
        side (:data:`nutribench.engine.evaluate.Greedy`; a recurrent one starts each day from
        the zero state), as the SB3 model of each agent acts with ``deterministic=True``."""
        raise NotImplementedError

    def day_boundary(self, steps: int) -> None:
        """The loops call this before every env step (``steps`` taken so far by each agent):
        after a day's end, the evaluation during training that is due (:attr:`validator`)."""
        if self.validator is not None:
            self.validator.at(steps, self.greedy, self.device)

    def record(self, timestep: int, values: dict[str, Any]) -> None:
        """Append one diagnostics dict to each agent's list: ``update`` (its index), ``timestep``
        (env steps of each agent so far) and ``values``: per name, K floats (a list or array:
        agent ``j`` gets the ``j``-th) or one float (every agent gets it). A name of a
        subclass's own is stored as it is (:func:`nutribench.diagnostics.valid_name`; ValueError
        at the first update for another, not once the job has trained)."""
        bad = [n for n in values if not names.valid_name(n) or n == names.TIMESTEP]
        if bad:
            raise ValueError(
                f"diagnostics: {bad[0]!r} is not a quantity's name ([a-z][a-z0-9_]*, at most 64 characters)"
            )
        update = len(self.diagnostics[0])
        shared = {n: float(v) for n, v in values.items() if np.ndim(v) == 0}
        columns = {n: np.asarray(v, dtype=np.float64).tolist() for n, v in values.items() if n not in shared}
        for j in range(self.k):
            row = {names.UPDATE: update, names.TIMESTEP: timestep, **{n: v[j] for n, v in columns.items()}}
            self.diagnostics[j].append(row | shared)
