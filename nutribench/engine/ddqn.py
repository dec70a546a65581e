"""Double DQN for K agents at once: SB3's ``DQN.learn`` with nutribench's double-DQN target
(:class:`~nutribench.agents.algos.DoubleDQN`), every agent's parameters stacked along a
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
* SB3's off-policy loop (:func:`~nutribench.engine.off_policy.run_off_policy`), with SB3's
  n-step returns (``NStepReplayBuffer``: rewards summed until the day's end or the newest
  transition, the target discounted by gamma to the number of steps summed); Huber loss; the
  gradient clipped to ``max_grad_norm`` per agent;
* a hard copy to the target network every ``target_update_interval`` steps.

Randomness is per agent, from its job seed (as in :mod:`nutribench.engine.train`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch as th
from torch.nn import functional as F

from nutribench.agents.api import TrainedAgent
from nutribench.config import EnvConfig
from nutribench.engine import check_supported
from nutribench.engine.actor_critic import clip_grad_norm_per_agent, linears, make_adam
from nutribench.engine.checkpoint import Checkpoint, resumed
from nutribench.engine.device import resolve_device
from nutribench.engine.envs import AgentEnvs, AgentEpisodeFn, as_trained_agent
from nutribench.engine.off_policy import OFF_POLICY_ADAM_EPS, Batch, StackedMLP, linear_schedule, run_off_policy


def q_linears(q_net: th.nn.Module) -> list[th.nn.Linear]:
    """The ``Linear`` layers of an SB3 ``QNetwork``, input to output."""
    return linears(q_net.q_net)


def ddqn_update(
    q: StackedMLP,
    q_target: StackedMLP,
    optimizer: th.optim.Optimizer,
    batch: Batch,
    learning_rate: float,
    max_grad_norm: float,
) -> np.ndarray:
    """One gradient step of :meth:`DoubleDQN.train` for the K agents; their Huber losses ``(K,)``."""
    for group in optimizer.param_groups:
        group["lr"] = learning_rate
    with th.no_grad():
        best = q.forward(batch.next_obs).argmax(dim=2, keepdim=True)
        next_q = th.gather(q_target.forward(batch.next_obs), 2, best).squeeze(2)
        target = batch.rewards + (1 - batch.dones) * batch.discounts * next_q
    current = th.gather(q.forward(batch.obs), 2, batch.actions.unsqueeze(2)).squeeze(2)
    loss = F.smooth_l1_loss(current, target, reduction="none").mean(dim=1)
    optimizer.zero_grad()
    loss.sum().backward()
    clip_grad_norm_per_agent(q.params, max_grad_norm)
    optimizer.step()
    return loss.detach().cpu().numpy()


def train_ddqn_batched(
    jobs: Sequence[tuple[str | EnvConfig, int]],
    cfg: Any,
    episodes: int,
    on_episode: AgentEpisodeFn | None = None,
    on_update: Callable[[dict[str, Any]], None] | None = None,
    checkpoint: Checkpoint | None = None,
    device: str | th.device = "cpu",
) -> list[TrainedAgent]:
    """Train one DDQN agent of ``cfg`` per ``(regime, seed)`` of ``jobs`` for ``episodes`` days,
    all at once (resuming from ``checkpoint`` if it holds a state), on ``device``
    (:func:`~nutribench.engine.device.resolve_device`).

    :param on_update: called after each update with ``steps`` (env steps so far), the
        ``learning_rate`` and ``epsilon`` in force, ``target_copies`` so far and the K ``losses``.
    """
    check_supported(cfg)  # e.g. normalize_reward, which this replay does not apply
    device = resolve_device(device)
    if checkpoint is not None:
        checkpoint.read_onto(device)
    envs = AgentEnvs(jobs, cfg.normalize_obs, on_episode)
    k = envs.k
    sizes = [envs.obs_dim, *cfg.net_arch, 2]
    q = StackedMLP(
        k,
        sizes,
        generators=[th.Generator().manual_seed(int(r.integers(2**62))) for r in envs.rng["init"]],
        device=device,
    )
    q_target = StackedMLP(k, sizes, device=device)
    q_target.copy_from(q)
    optimizer = make_adam(q.params, cfg.learning_rate_start, OFF_POLICY_ADAM_EPS)
    # SB3's DQN: epsilon 0 until its first step's schedule update (read only if learning_starts = 0)
    state = {"epsilon": 0.0, "copies": 0}
    q, q_target, optimizer, state = resumed(checkpoint, "model") or (q, q_target, optimizer, state)

    def act(obs: np.ndarray, n: int, uniforms: np.ndarray, random_actions: np.ndarray) -> tuple[np.ndarray, None]:
        if n < cfg.learning_starts:
            return random_actions, None
        with th.no_grad():
            greedy = q.forward(th.as_tensor(obs, device=device).unsqueeze(1))[:, 0].argmax(dim=1).cpu().numpy()
        return np.where(uniforms < state["epsilon"], random_actions, greedy), None

    def after_step(steps: int, progress: float) -> None:
        if steps % cfg.target_update_interval == 0:
            q_target.copy_from(q)
            state["copies"] += 1
        state["epsilon"] = linear_schedule(
            cfg.exploration_initial_eps, cfg.exploration_final_eps, cfg.exploration_fraction, progress
        )

    def update(steps: int, progress: float, batch: Batch) -> None:
        lr = linear_schedule(cfg.learning_rate_start, cfg.learning_rate_end, 1.0, progress)
        losses = ddqn_update(q, q_target, optimizer, batch, lr, cfg.max_grad_norm)
        if on_update is not None:
            on_update(
                {
                    "steps": steps,
                    "learning_rate": lr,
                    "epsilon": state["epsilon"],
                    "target_copies": state["copies"],
                    "losses": losses,
                }
            )

    wall = run_off_policy(
        envs,
        cfg,
        episodes * envs.horizon,
        act,
        update,
        after_step,
        n_step=cfg.n_step,
        checkpoint=checkpoint,
        model=(q, q_target, optimizer, state),
        device=device,
    )
    return [
        as_trained_agent(
            envs, j, cfg, episodes, lambda model, j=j: _store(q, q_target, j, model), None, wall / k, str(device)
        )
        for j in range(k)
    ]


def _store(q: StackedMLP, q_target: StackedMLP, j: int, model: Any) -> None:
    q.store_linears(j, q_linears(model.q_net))
    q_target.store_linears(j, q_linears(model.q_net_target))
