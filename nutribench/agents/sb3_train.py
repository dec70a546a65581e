"""SB3's ``PPO.train`` and ``A2C.train`` that also log the gradient norm before clipping.

SB3 clips each gradient step with ``th.nn.utils.clip_grad_norm_`` and drops the norm it
returns. These classes override the algorithm's own ``train()`` with SB3's (2.x) code, as
sb3-contrib's algorithms override it, the one change being that the norm each step's call
returns is kept (a tensor a step, read once per update) and logged as ``train/grad_norm``:
the mean over the update's gradient steps of the finite ones, as DDQN's and GRU-PPO's own
updates log it. The update itself is SB3's operation for operation (the same weights, the
same logged values: ``tests/test_diagnostics.py``), and nothing outside the algorithm is
touched: torch's ``clip_grad_norm_`` stays torch's for every other model in the process.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.utils import explained_variance
from torch.nn import functional as F


def record_grad_norm(logger: Any, norms: list[th.Tensor]) -> None:
    """Log ``train/grad_norm``: the mean of the finite ``norms`` (none finite: nothing)."""
    kept = th.stack(norms) if norms else th.empty(0)
    finite = kept[th.isfinite(kept)]
    if finite.numel():  # a step whose norm is not finite is left out, as the logger leaves it out
        logger.record("train/grad_norm", float(finite.mean()))


def _actions(algo: Any, actions: th.Tensor) -> th.Tensor:
    """SB3's discrete actions as ``long`` (a float buffer's)."""
    return actions.long().flatten() if isinstance(algo.action_space, spaces.Discrete) else actions


class GradNormPPO(PPO):
    """SB3's ``PPO`` whose ``train()`` also logs ``train/grad_norm`` (the module docstring)."""

    #: the update logs ``train/grad_norm`` itself (so the diagnostics install no gradient probe)
    records_grad_norm: ClassVar[bool] = True

    def _minibatch_loss(self, data: Any, clip_range: float, clip_range_vf: float | None, logs: dict) -> tuple:
        """SB3's loss on one minibatch, its statistics appended to ``logs``; the loss and the approximate KL."""
        values, log_prob, entropy = self.policy.evaluate_actions(data.observations, _actions(self, data.actions))
        values = values.flatten()
        advantages = data.advantages
        if self.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        ratio = th.exp(log_prob - data.old_log_prob)
        policy_loss_1 = advantages * ratio
        policy_loss_2 = advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)
        policy_loss = -th.min(policy_loss_1, policy_loss_2).mean()
        logs["policy_gradient_loss"].append(policy_loss.item())
        logs["clip_fraction"].append(th.mean((th.abs(ratio - 1) > clip_range).float()).item())
        if clip_range_vf is None:
            values_pred = values
        else:
            values_pred = data.old_values + th.clamp(values - data.old_values, -clip_range_vf, clip_range_vf)
        value_loss = F.mse_loss(data.returns, values_pred)
        logs["value_loss"].append(value_loss.item())
        entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
        logs["entropy_loss"].append(entropy_loss.item())
        loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
        with th.no_grad():
            log_ratio = log_prob - data.old_log_prob
            approx_kl_div = th.mean((th.exp(log_ratio) - 1) - log_ratio).cpu().numpy()
        return loss, approx_kl_div

    def train(self) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)  # type: ignore[operator]
        clip_range_vf = None
        if self.clip_range_vf is not None:
            clip_range_vf = self.clip_range_vf(self._current_progress_remaining)  # type: ignore[operator]
        logs: dict[str, list] = {k: [] for k in ("entropy_loss", "policy_gradient_loss", "value_loss", "clip_fraction")}
        grad_norms: list[th.Tensor] = []
        continue_training = True
        for epoch in range(self.n_epochs):
            approx_kl_divs = []
            for rollout_data in self.rollout_buffer.get(self.batch_size):
                loss, approx_kl_div = self._minibatch_loss(rollout_data, clip_range, clip_range_vf, logs)
                approx_kl_divs.append(approx_kl_div)
                if self.target_kl is not None and approx_kl_div > 1.5 * self.target_kl:
                    continue_training = False
                    if self.verbose >= 1:
                        print(f"Early stopping at step {epoch} due to reaching max kl: {approx_kl_div:.2f}")
                    break
                self.policy.optimizer.zero_grad()
                loss.backward()
                grad_norms.append(th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm))
                self.policy.optimizer.step()
            self._n_updates += 1
            if not continue_training:
                break
        explained_var = explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten())
        for key, values in logs.items():
            self.logger.record(f"train/{key}", np.mean(values))
        self.logger.record("train/approx_kl", np.mean(approx_kl_divs))
        self.logger.record("train/loss", loss.item())
        self.logger.record("train/explained_variance", explained_var)
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)
        if clip_range_vf is not None:
            self.logger.record("train/clip_range_vf", clip_range_vf)
        record_grad_norm(self.logger, grad_norms)


class GradNormA2C(A2C):
    """SB3's ``A2C`` whose ``train()`` also logs ``train/grad_norm`` (the module docstring)."""

    #: the update logs ``train/grad_norm`` itself (so the diagnostics install no gradient probe)
    records_grad_norm: ClassVar[bool] = True

    def train(self) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        grad_norms: list[th.Tensor] = []
        for rollout_data in self.rollout_buffer.get(batch_size=None):  # one batch: the whole rollout
            actions = _actions(self, rollout_data.actions)
            values, log_prob, entropy = self.policy.evaluate_actions(rollout_data.observations, actions)
            values = values.flatten()
            advantages = rollout_data.advantages
            if self.normalize_advantage:
                advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
            policy_loss = -(advantages * log_prob).mean()
            value_loss = F.mse_loss(rollout_data.returns, values)
            entropy_loss = -th.mean(-log_prob) if entropy is None else -th.mean(entropy)
            loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
            self.policy.optimizer.zero_grad()
            loss.backward()
            grad_norms.append(th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm))
            self.policy.optimizer.step()
        explained_var = explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten())
        self._n_updates += 1
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/explained_variance", explained_var)
        self.logger.record("train/entropy_loss", entropy_loss.item())
        self.logger.record("train/policy_loss", policy_loss.item())
        self.logger.record("train/value_loss", value_loss.item())
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())
        record_grad_norm(self.logger, grad_norms)
