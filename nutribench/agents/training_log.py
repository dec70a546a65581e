"""The SB3 engine's training diagnostics: what SB3's logger records, one row per update.

:class:`DiagnosticsLogger` is SB3's :class:`~stable_baselines3.common.logger.Logger` that also
keeps, for the keys of :data:`SB3_KEYS`, the running mean of every value recorded since the
last row (SB3's own ``record`` keeps only the last one). :class:`TrainingDiagnostics` (an SB3
callback) closes a row at the end of each update and hands it to the logger's output formats:

* on-policy (MC, PPO, GRU-PPO): a row after each rollout's update (closed when the next rollout
  starts, and when training ends);
* off-policy (DDQN, SAC): a row at the end of each training day with gradient steps, each
  quantity the mean over that day's gradient steps (days before learning starts have none).

Row keys are the vocabulary of :mod:`nutribench.diagnostics`. The gradient norm before
clipping is the value ``clip_grad_norm_`` returns: DDQN and GRU-PPO record it in updates of
their own, and so do PPO and A2C (MC), whose ``train()`` is SB3's with that value kept
(:mod:`nutribench.agents.sb3_train`). An on-policy plug-in algorithm whose update does not
log ``train/grad_norm`` itself gets :class:`GradNormProbe` (the norm taken when backward has
accumulated every gradient); nothing here changes torch or SB3 for the rest of the process. SAC does not clip and its gradient norm is
not recorded. VecNormalize's return scale is read
off the training env at the end of each update.

``tensorboard``: SB3's own :class:`~stable_baselines3.common.logger.TensorBoardOutputFormat`
joins the logger, so SB3's keys (``train/*``, ``rollout/*``, ``time/*``) and every row's
quantities (as ``diagnostics/<name>``) are written as TensorBoard events, at the job's env step.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import HumanOutputFormat, KVWriter, Logger
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.dqn import DQN

from nutribench import diagnostics as d

#: SB3 logger keys -> the diagnostics vocabulary (every algorithm; DQN's ``train/loss`` below).
SB3_KEYS: dict[str, str] = {
    "train/policy_gradient_loss": d.POLICY_LOSS,  # PPO, GRU-PPO
    "train/policy_loss": d.POLICY_LOSS,  # A2C (MC)
    "train/value_loss": d.VALUE_LOSS,
    "train/critic_loss": d.VALUE_LOSS,  # SAC
    "train/entropy_loss": d.ENTROPY_LOSS,
    "train/approx_kl": d.APPROX_KL,
    "train/clip_fraction": d.CLIP_FRACTION,
    "train/explained_variance": d.EXPLAINED_VARIANCE,
    "train/grad_norm": d.GRAD_NORM,
    "train/learning_rate": d.LEARNING_RATE,
    "train/critic_learning_rate": d.LEARNING_RATE,  # SAC: the critic's (SB3's lr_schedule)
    "rollout/exploration_rate": d.EPSILON,  # DQN
    "train/q_mean": d.Q_MEAN,
    "train/actor_loss": d.ACTOR_LOSS,
    "train/alpha": d.ENT_COEF,  # our discrete SAC
    "train/ent_coef": d.ENT_COEF,  # SB3's SAC
}
#: DQN's ``train/loss`` is its TD loss; PPO's is the total loss, which has no column.
DQN_KEYS: dict[str, str] = {**SB3_KEYS, "train/loss": d.VALUE_LOSS}


class DiagnosticsLogger(Logger):
    """SB3's logger (no folder) that also averages the diagnostics it is given between rows."""

    def __init__(self, keys: dict[str, str], output_formats: list[KVWriter] | None = None):
        super().__init__(folder=None, output_formats=list(output_formats or []))
        self.keys = keys
        self.sums: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        #: whether a training update recorded anything since the last row (``train/n_updates``)
        self.updated = False

    def record(self, key: str, value: Any, exclude: str | tuple[str, ...] | None = None) -> None:
        super().record(key, value, exclude)
        name = self.keys.get(key)
        if name is not None:
            self.add(name, value)
        elif key == "train/n_updates":
            self.updated = True

    def add(self, name: str, value: Any) -> None:
        """One more value of quantity ``name`` (non-finite values are left out)."""
        x = float(value)
        if math.isfinite(x):
            self.sums[name] = self.sums.get(name, 0.0) + x
            self.counts[name] = self.counts.get(name, 0) + 1

    def take(self) -> dict[str, float]:
        """The means since the last call, then forget them."""
        out = {k: self.sums[k] / self.counts[k] for k in d.QUANTITIES if k in self.sums}
        self.sums.clear()
        self.counts.clear()
        self.updated = False
        return out


class GradNormProbe:
    """The global gradient norm of ``params`` before clipping, for an on-policy plug-in's
    update (which may not clip with ``clip_grad_norm_``, nor log what it returns).

    Backward accumulates each parameter's gradient in turn; when the last of them has arrived
    (a hook counts them), the global norm of all of them is taken at once, before
    the update clips anything, and handed to ``logger`` when ``optimizer`` steps (so one norm,
    and one read of it, per gradient step). A step whose backward left some parameter without a
    gradient records nothing (its norm could no longer be read before clipping).
    """

    def __init__(self, params: list[th.nn.Parameter], optimizer: th.optim.Optimizer, logger: DiagnosticsLogger):
        self.logger = logger
        self.params = [p for p in params if p.requires_grad]
        self.arrived = 0
        self.norm: th.Tensor | None = None
        self.handles = [p.register_post_accumulate_grad_hook(self._grad) for p in self.params]
        self.handles.append(optimizer.register_step_pre_hook(self._step))

    def _grad(self, _: th.Tensor) -> None:
        self.arrived += 1
        if self.arrived == len(self.params):  # the last gradient of this backward: none clipped yet
            # one flat vector and one norm: on the CPU about half the time of get_total_norm
            # for these small networks (the norms are equal up to float rounding)
            self.norm = th.linalg.vector_norm(th.cat([p.grad.detach().reshape(-1) for p in self.params]))
            self.arrived = 0

    def _step(self, *_: Any) -> None:
        if self.norm is not None:
            self.logger.add(d.GRAD_NORM, self.norm.item())
        self.norm = None
        self.arrived = 0

    def remove(self) -> None:
        for h in self.handles:
            h.remove()
        self.handles.clear()


def tensorboard_format(folder: str | Path) -> KVWriter:
    """SB3's TensorBoard writer on ``folder``; a clear error when tensorboard is missing."""
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        raise RuntimeError(
            "--tensorboard needs the tensorboard package: pip install 'nutribench[tensorboard]'"
        ) from None
    from stable_baselines3.common.logger import TensorBoardOutputFormat

    Path(folder).mkdir(parents=True, exist_ok=True)
    return TensorBoardOutputFormat(str(folder))


def plugin_logger(model: Any, folder: str | Path | None) -> None:
    """Point a plug-in's own SB3 logger at ``folder`` (what ``--tensorboard`` asks for): an SB3
    algorithm writes its TensorBoard events where ``tensorboard_log`` says when ``learn`` starts.
    Without a folder (None) and without a logger of its own, an SB3 plug-in gets SB3's default
    logger (stdout when ``verbose`` > 0) minus the empty folder tempdir/SB3-<date> that SB3 makes for
    it at every ``learn``, one per job. A plug-in that is not an SB3 algorithm has no such logger:
    a ``folder`` then gets a warning saying so."""
    if folder is None:
        if (
            isinstance(model, BaseAlgorithm)
            and not getattr(model, "_custom_logger", False)
            and model.tensorboard_log is None
        ):
            formats = [HumanOutputFormat(sys.stdout)] if getattr(model, "verbose", 0) >= 1 else []
            model.set_logger(Logger(folder=None, output_formats=formats))
        return
    if isinstance(model, BaseAlgorithm):
        try:
            import tensorboard  # noqa: F401
        except ImportError:
            raise RuntimeError(
                "--tensorboard needs the tensorboard package: pip install 'nutribench[tensorboard]'"
            ) from None
        Path(folder).mkdir(parents=True, exist_ok=True)
        model.tensorboard_log = str(folder)
    else:
        import warnings

        warnings.warn(
            f"--tensorboard: a {type(model).__name__} is not an SB3 algorithm, so no TensorBoard events are written",
            stacklevel=2,
        )


class TrainingDiagnostics(BaseCallback):
    """Records one diagnostics row per update of ``model`` (see the module docstring) into
    :attr:`rows`; installs its logger on the model when training starts and takes its probes
    off when training ends. ``tensorboard``: a folder for this job's TensorBoard events."""

    def __init__(self, model: Any, tensorboard: str | Path | None = None):
        super().__init__()
        self.rows: list[dict[str, float]] = []
        self.off_policy = isinstance(model, OffPolicyAlgorithm)
        formats = [tensorboard_format(tensorboard)] if tensorboard is not None else []
        self.diag_logger = DiagnosticsLogger(DQN_KEYS if isinstance(model, DQN) else SB3_KEYS, formats)
        model.set_logger(self.diag_logger)
        self.probe: GradNormProbe | None = None
        if isinstance(model, OnPolicyAlgorithm) and not getattr(model, "records_grad_norm", False):
            policy = model.policy
            self.probe = GradNormProbe(list(policy.parameters()), policy.optimizer, self.diag_logger)

    def _on_step(self) -> bool:
        if self.off_policy and any(self.locals["dones"]):
            if self.diag_logger.updated:
                self._close_row()
            else:  # a day before learning starts: no update, no row
                self.diag_logger.take()
        return True

    def _on_rollout_start(self) -> None:
        if not self.off_policy and self.diag_logger.updated:
            self._close_row()

    def _on_training_end(self) -> None:
        if not self.off_policy and self.diag_logger.updated:
            self._close_row()
        if self.probe is not None:
            self.probe.remove()
        self.diag_logger.close()

    def _return_scale(self) -> float | None:
        venv = self.model.get_vec_normalize_env()
        if venv is None or not venv.norm_reward:
            return None
        return float(math.sqrt(float(venv.ret_rms.var) + venv.epsilon))

    def _close_row(self) -> None:
        row: dict[str, float] = {d.UPDATE: len(self.rows), d.TIMESTEP: int(self.model.num_timesteps)}
        row |= self.diag_logger.take()
        scale = self._return_scale()
        if scale is not None:
            row[d.RETURN_SCALE] = scale
        self.rows.append(row)
        if self.diag_logger.output_formats:
            for name in d.QUANTITIES:
                if name in row:
                    self.diag_logger.record(f"diagnostics/{name}", row[name])
        self.diag_logger.dump(step=row[d.TIMESTEP])  # to TensorBoard, if any; clears SB3's values
