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
their own; every other on-policy algorithm (SB3's own PPO and A2C, as MC and PPO train, and
any plug-in) gets :class:`GradNormProbe`, which takes the same norm, as ``clip_grad_norm_``
computes it, when backward has accumulated every gradient; nothing here changes torch or SB3
for the rest of the process. SAC does not clip and its gradient norm is
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
from stable_baselines3.common.logger import HumanOutputFormat, KVWriter, Logger, TensorBoardOutputFormat
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
        #: called first by :meth:`take` (a probe adds what it kept since the last row)
        self.before_take: list[Any] = []
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
        for flush in list(self.before_take):
            flush()
        out = {k: self.sums[k] / self.counts[k] for k in d.QUANTITIES if k in self.sums}
        self.sums.clear()
        self.counts.clear()
        self.updated = False
        return out


class GradNormProbe:
    """The global gradient norm of ``params`` before clipping, read through hooks on any model
    (its update need not log it, nor clip with ``clip_grad_norm_``).

    Backward accumulates each parameter's gradient in turn; when the last of them has arrived
    (a hook counts them), the norm of all of them is taken at once, before the update clips
    anything, computed as ``clip_grad_norm_`` computes the norm it returns
    (``torch.nn.utils.get_total_norm``: the same value, bit for bit), and kept when
    ``optimizer`` steps (one norm per gradient step). At each row (:meth:`DiagnosticsLogger.take`)
    ``logger`` gets the mean of the finite norms kept since the last, a float32 mean as SB3's
    logged losses are. A step whose backward left some parameter without a gradient keeps
    nothing (its norm could no longer be read before clipping).
    """

    def __init__(self, params: list[th.nn.Parameter], optimizer: th.optim.Optimizer, logger: DiagnosticsLogger):
        self.logger = logger
        self.params = [p for p in params if p.requires_grad]
        self.arrived = 0
        self.norm: th.Tensor | None = None
        self.norms: list[th.Tensor] = []
        self.handles = [p.register_post_accumulate_grad_hook(self._grad) for p in self.params]
        self.handles.append(optimizer.register_step_pre_hook(self._step))
        logger.before_take.append(self.flush)

    def _grad(self, _: th.Tensor) -> None:
        self.arrived += 1
        if self.arrived == len(self.params):  # the last gradient of this backward: none clipped yet
            self.norm = th.nn.utils.get_total_norm([p.grad for p in self.params])
            self.arrived = 0

    def _step(self, *_: Any) -> None:
        if self.norm is not None:
            self.norms.append(self.norm)
        self.norm = None
        self.arrived = 0

    def flush(self) -> None:
        """Hand ``logger`` the mean of the finite norms kept since the last row (none: nothing)."""
        if not self.norms:
            return
        kept = th.stack(self.norms)
        self.norms.clear()
        finite = kept[th.isfinite(kept)]
        if finite.numel():  # a step whose norm is not finite is left out, as the logger leaves it out
            self.logger.add(d.GRAD_NORM, float(finite.mean()))

    def remove(self) -> None:
        """Take the hooks off, and the probe off ``logger`` (norms kept since its last row are dropped)."""
        for h in self.handles:
            h.remove()
        self.handles.clear()
        if self.flush in self.logger.before_take:
            self.logger.before_take.remove(self.flush)


def tensorboard_folder(folder: str | Path) -> str:
    """``folder``, made, for TensorBoard events; a clear error when tensorboard is missing."""
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        raise RuntimeError(
            "--tensorboard needs the tensorboard package: pip install 'nutribench[tensorboard]'"
        ) from None
    Path(folder).mkdir(parents=True, exist_ok=True)
    return str(folder)


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
        model.tensorboard_log = tensorboard_folder(folder)
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
        formats = [] if tensorboard is None else [TensorBoardOutputFormat(tensorboard_folder(tensorboard))]
        self.diag_logger = DiagnosticsLogger(DQN_KEYS if isinstance(model, DQN) else SB3_KEYS, formats)
        model.set_logger(self.diag_logger)
        self.probe: GradNormProbe | None = None
        if isinstance(model, OnPolicyAlgorithm) and not getattr(model, "records_grad_norm", False):
            # every on-policy model but those whose update logs it (GRU-PPO): SB3's PPO and A2C too
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
        self._on_rollout_start()  # the last on-policy update's row
        if self.probe is not None:
            self.probe.remove()
        self.diag_logger.close()

    def _close_row(self) -> None:
        row: dict[str, float] = {d.UPDATE: len(self.rows), d.TIMESTEP: int(self.model.num_timesteps)}
        row |= self.diag_logger.take()
        venv = self.model.get_vec_normalize_env()
        if venv is not None and venv.norm_reward:  # VecNormalize's return scale
            row[d.RETURN_SCALE] = float(math.sqrt(float(venv.ret_rms.var) + venv.epsilon))
        self.rows.append(row)
        if self.diag_logger.output_formats:
            for name in d.QUANTITIES:
                if name in row:
                    self.diag_logger.record(f"diagnostics/{name}", row[name])
        self.diag_logger.dump(step=row[d.TIMESTEP])  # to TensorBoard, if any; clears SB3's values
