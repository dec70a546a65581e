"""Double DQN for K agents at once: SB3's ``DQN.learn`` with nutribench's double-DQN target
(:class:`~nutribench.agents.builtin.ddqn.DoubleDQN`), every agent's parameters stacked along a
leading agent axis.

Per agent, everything is what ``algos.build_model`` builds from ``ddqn.toml``:

* Q-network ``obs -> 256 -> 128 -> 2`` (ReLU), PyTorch's default ``Linear`` initialisation
  (SB3's ``QNetwork``), a target network copied from it; Adam (eps 1e-8) whose learning rate
  falls linearly from ``learning_rate_start`` to ``learning_rate_end`` over the budget;
* ``VecNormalize`` of the observations (each agent its own running statistics); the replay
  stores raw observations and raw rewards and normalises observations when sampling, with
  the statistics of that moment (SB3's off-policy habit);
* actions: uniformly random for the first ``learning_starts`` steps, then epsilon-greedy with
  epsilon falling linearly from ``exploration_initial_eps`` to ``exploration_final_eps`` over
  the first ``exploration_fraction`` of the budget;
* SB3's off-policy loop (:class:`~nutribench.engine.off_policy.BatchedOffPolicyAlgorithm`), with SB3's
  n-step returns (``NStepReplayBuffer``: rewards summed until the day's end or the newest
  transition, the target discounted by gamma to the number of steps summed); Huber loss; the
  gradient clipped to ``max_grad_norm`` per agent;
* a hard copy to the target network every ``target_update_interval`` steps.

Randomness is per agent, from its job seed (as in :mod:`nutribench.engine.train`). Each
training day's diagnostics: the means over its gradient steps of the TD (Huber) loss as
``value_loss``, the gradient norm before clipping, the mean Q of the actions taken, the
learning rate and epsilon.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.utils import LinearSchedule
from torch.nn import functional as F

from nutribench import diagnostics as names
from nutribench.engine.envs import AgentEnvs
from nutribench.engine.evaluate import Greedy
from nutribench.engine.off_policy import OFF_POLICY_ADAM_EPS, Batch, BatchedOffPolicyAlgorithm
from nutribench.engine.stacked import (
    AgentMeans,
    StackedAdam,
    StackedMLP,
    clip_grad_norm_per_agent,
    linears,
    load_params,
)


def ddqn_update(
    q: StackedMLP,
    q_target: StackedMLP,
    optimizer: StackedAdam,
    batch: Batch,
    learning_rate: float,
    max_grad_norm: float,
    means: AgentMeans | None = None,
) -> np.ndarray:
    """One gradient step of :meth:`DoubleDQN.train` for the K agents; their Huber losses
    ``(K,)``. The losses, the gradient norms and the mean Q of the actions taken go to ``means``."""
    optimizer.rate = learning_rate  # the schedule's rate for this step (StackedAdam scales its rate-1 step)
    with th.no_grad():
        best = q.forward(batch.next_obs).argmax(dim=2, keepdim=True)
        next_q = th.gather(q_target.forward(batch.next_obs), 2, best).squeeze(2)
        target = batch.rewards + (1 - batch.dones) * batch.discounts * next_q
    current = th.gather(q.forward(batch.obs), 2, batch.actions.unsqueeze(2)).squeeze(2)
    loss = F.smooth_l1_loss(current, target, reduction="none").mean(dim=1)
    optimizer.zero_grad()
    loss.sum().backward()
    norms = clip_grad_norm_per_agent(q.params, max_grad_norm)
    optimizer.step()
    if means is not None:
        means.add(**{names.VALUE_LOSS: loss, names.GRAD_NORM: norms, names.Q_MEAN: current.mean(dim=1)})
    return loss.detach().cpu().numpy()


class BatchedDDQN(BatchedOffPolicyAlgorithm):
    """K double-DQN agents: Q-networks, target networks, one Adam, the epsilon schedule."""

    #: the online and target nets at the next states, the online net forward and backward
    FORWARDS_PER_SAMPLE = 5

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device, cfgs: list[Any] | None = None):
        super().__init__(cfg, envs, device, cfgs)
        sizes = [envs.obs_dim, *cfg.net_arch, 2]
        self.q = StackedMLP(self.k, sizes, generators=self.init_generators(), device=device)
        self.q_target = StackedMLP(self.k, sizes, device=device)
        load_params(self.q_target.params, self.q.params)
        self.optimizer = StackedAdam(self.q.params, cfg.learning_rate_start, OFF_POLICY_ADAM_EPS)
        #: SB3's schedules of the learning rate (over the budget) and of epsilon
        self.lr_schedule = LinearSchedule(cfg.learning_rate_start, cfg.learning_rate_end, 1.0)
        self.exploration = LinearSchedule(
            cfg.exploration_initial_eps, cfg.exploration_final_eps, cfg.exploration_fraction
        )
        # SB3's DQN: epsilon 0 until its first step's schedule update (read only if learning_starts = 0)
        self.state = {"epsilon": 0.0, "copies": 0}
        self.n_step = cfg.n_step

    def act(self, obs: np.ndarray, n: int, uniforms: np.ndarray, random_actions: np.ndarray) -> tuple[np.ndarray, None]:
        if n < self.cfg.learning_starts:
            return random_actions, None
        with th.no_grad():
            q = self.q.forward(th.as_tensor(obs, device=self.device).unsqueeze(1))
        greedy = q[:, 0].argmax(dim=1).cpu().numpy()
        return np.where(uniforms < self.state["epsilon"], random_actions, greedy), None

    def greedy(self) -> Greedy:
        return lambda obs: (self.q.forward(obs).argmax(dim=-1), None)  # SB3's DQN: argmax Q, no entropy

    def after_step(self, steps: int, progress_remaining: float) -> None:
        if steps % self.cfg.target_update_interval == 0:
            load_params(self.q_target.params, self.q.params)
            self.state["copies"] += 1
        self.state["epsilon"] = self.exploration(progress_remaining)

    def update(self, steps: int, progress_remaining: float, batch: Batch) -> None:
        lr, epsilon = self.lr_schedule(progress_remaining), self.state["epsilon"]
        losses = ddqn_update(self.q, self.q_target, self.optimizer, batch, lr, self.cfg.max_grad_norm, self.means)
        self.means.add(**{names.LEARNING_RATE: lr, names.EPSILON: epsilon})
        if self.on_update is not None:
            copies = self.state["copies"]
            self.on_update(
                {"steps": steps, "learning_rate": lr, "epsilon": epsilon, "target_copies": copies, "losses": losses}
            )

    def model_state_dict(self) -> dict[str, Any]:
        nets = {"q": list(self.q.params), "q_target": list(self.q_target.params)}
        return {**nets, "optimizer": self.optimizer.state_dict(), **self.state}  # the epsilon and the target copies

    def load_model_state_dict(self, state: dict[str, Any]) -> None:
        load_params(self.q.params, state["q"])
        load_params(self.q_target.params, state["q_target"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.state = {"epsilon": float(state["epsilon"]), "copies": int(state["copies"])}

    def store_weights(self, j: int, model: Any) -> None:
        self.q.store_sb3(j, linears(model.q_net.q_net))
        self.q_target.store_sb3(j, linears(model.q_net_target.q_net))
