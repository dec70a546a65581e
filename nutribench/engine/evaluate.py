"""The batched engine's greedy evaluation during training (:mod:`nutribench.agents.validation`
says when and what): all K agents at once, each on its own validation days
(:func:`~nutribench.agents.days.validation_food_streams` of its regime and seed, the days the
SB3 engine plays), in envs of their own (one vector env per regime, a row per agent and
day), each agent's observations normalised by its statistics of that moment (no update),
and its greedy actions from the algorithm's :meth:`~nutribench.engine.algorithm.BatchedAlgorithm.greedy`.
Nothing of the training is read but the weights and the statistics; nothing is changed.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch as th

from nutribench.agents.days import validation_food_streams
from nutribench.agents.validation import ValidationFn, Validator
from nutribench.engine.envs import AgentEnvs
from nutribench.env.metrics import EpisodeRecorder
from nutribench.env.vector_env import NutriRLVectorEnv

#: a greedy player: normalised observations ``(K, n, d)`` -> actions ``(K, n)`` and the
#: policy's entropy at each ``(K, n)`` (None for a policy without one); a fresh one per evaluation
Greedy = Callable[[th.Tensor], tuple[th.Tensor, th.Tensor | None]]


def greedy_categorical(logits: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """The mode of categorical policies ``logits (K, n, n_actions)`` (SB3's deterministic
    action: the most probable one) and their entropies, each ``(K, n)``."""
    logp = th.log_softmax(logits, dim=-1)
    return logits.argmax(dim=-1), -(logp.exp() * logp).sum(-1)


class BatchValidator(Validator):
    """The evaluations of the K agents of ``envs`` during training, every ``every`` days on
    ``n_days`` validation days each."""

    def __init__(self, envs: AgentEnvs, every: int, n_days: int, on_validation: ValidationFn | None = None):
        super().__init__(every, envs.k, on_validation)
        self.envs, self.rows = envs, envs.validation  # one list: a checkpoint keeps the rows
        self.streams = np.stack([validation_food_streams(c, s, n_days) for c, s in zip(envs.env_cfgs, envs.seeds)])
        self._played = [
            NutriRLVectorEnv(len(g.agents) * n_days, regime=envs.env_cfgs[g.agents[0]]) for g in envs.groups
        ]

    def at(self, steps: int, make_greedy: Callable[[], Greedy], device: th.device | str = "cpu") -> None:
        """Called before every training step (``steps`` taken so far) and at the end: plays the
        evaluation that is due after a day boundary, with a fresh ``make_greedy()`` on ``device``."""
        if steps % self.envs.horizon == 0 and self.due(steps // self.envs.horizon):
            self.add(steps // self.envs.horizon, self.play(make_greedy(), device))

    def play(self, greedy: Greedy, device: th.device | str = "cpu") -> list[list[dict]]:
        """Every agent's greedy play of its validation days: per agent, one metrics row per
        day (``episode``, the metrics, ``entropy``: the mean over the day's steps, or None)."""
        envs, streams = self.envs, self.streams
        k, n, horizon = streams.shape
        raw = np.empty((k, n, envs.obs_dim))
        for g, env in zip(envs.groups, self._played):
            obs, _ = env.reset(options={"foods": streams[g.agents].reshape(-1, horizon)})
            raw[g.agents] = obs.reshape(len(g.agents), n, -1)
        recorders = [EpisodeRecorder(env.num_envs) for env in self._played]
        rows: list[list[dict]] = [[{} for _ in range(n)] for _ in range(k)]
        entropy = np.zeros((k, n))  # summed over the steps; None for a policy without one
        for _ in range(horizon):
            with th.no_grad():
                actions, step_entropy = greedy(th.as_tensor(envs.normalize(raw), device=device))
            entropy = None if entropy is None or step_entropy is None else entropy + step_entropy.cpu().numpy()
            actions = actions.cpu().numpy()
            for g, env, rec in zip(envs.groups, self._played, recorders):
                obs, rewards, term, trunc, info = env.step(actions[g.agents].reshape(-1))
                raw[g.agents] = obs.reshape(len(g.agents), n, -1)
                ended = term | trunc
                for row, m in zip(np.flatnonzero(ended), rec.record(rewards, ended, info)):
                    j, i = int(g.agents[row // n]), int(row % n)  # a day ends at its last step: its entropy is summed
                    day_entropy = None if entropy is None else float(entropy[j, i] / horizon)
                    rows[j][i] = {"episode": i, **m, "entropy": day_entropy}
        return rows
