"""GRU-PPO, the algorithm: PPO's update over whole sequences, acting with the state carried."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import FloatSchedule, explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv
from torch.nn import functional as F

from nutribench.agents.gru_ppo.buffer import RecurrentRolloutBuffer, RecurrentRolloutBufferSamples
from nutribench.agents.gru_ppo.policy import GRUActorCriticPolicy, GRUState


class GRUPPO(OnPolicyAlgorithm):
    """PPO (clip) with the two-stream GRU policy and full-episode backpropagation through time.

    :param env: the environment (SB3 ``VecEnv``, e.g. ``VecNormalize(NutriRLSB3VecEnv(...),
        norm_obs=True, norm_reward=False)``, or a Gymnasium env).
    :param learning_rate: Adam learning rate (float or SB3 schedule).
    :param n_steps: steps per env per rollout; a multiple of ``sequence_length``
        (buffer = ``n_steps * n_envs`` steps = ``n_steps / 50 * n_envs`` episodes).
    :param batch_size: env steps per minibatch, as in PPO, rounded to whole sequences:
        ``max(1, round(batch_size / sequence_length))`` sequences (64 -> one 50-step episode).
    :param n_epochs: passes over each rollout.
    :param gamma: discount factor.
    :param gae_lambda: GAE lambda.
    :param clip_range: PPO clip range (float or schedule).
    :param ent_coef: entropy bonus coefficient.
    :param vf_coef: value loss coefficient.
    :param max_grad_norm: L2 gradient-norm clip.
    :param hidden_size: hidden units of each GRU (128).
    :param sequence_length: steps per training sequence: the episode length (50 in NutriRL).
    :param memory: carry the GRU state from step to step (True, the paper's); False: zero it
        before every step (no memory: :class:`GRUActorCriticPolicy`'s ``memory``).
    :param normalize_advantage: normalise advantages per minibatch (SB3 PPO default).
    :param target_kl: stop an update early when the approximate KL exceeds 1.5x this (None: never).
    :param policy: ``"GRUPolicy"`` or a policy class (:class:`GRUActorCriticPolicy` or a subclass).
    :param policy_kwargs: extra policy keyword arguments (``hidden_size`` is set from ``hidden_size``).
    :param stats_window_size: episodes averaged in the rollout logs.
    :param tensorboard_log: tensorboard log folder (None: none).
    :param seed: seed of Python, NumPy, PyTorch, the action space and the env.
    :param device: torch device.
    :param verbose: 0 silent, 1 info, 2 debug.
    :param _init_setup_model: build the networks now (SB3's ``load`` passes False).

    Logged each update: SB3 PPO's ``train/*`` keys plus ``train/entropy`` (mean policy
    entropy over the rollout's minibatches, nats), ``train/grad_norm`` (mean gradient norm
    before clipping) and ``train/minibatch_sequences``.
    """

    #: the update logs ``train/grad_norm`` itself (no gradient probe needed)
    records_grad_norm: ClassVar[bool] = True

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "GRUPolicy": GRUActorCriticPolicy,
        "MlpPolicy": GRUActorCriticPolicy,
    }
    policy: GRUActorCriticPolicy
    rollout_buffer: RecurrentRolloutBuffer

    def __init__(
        self,
        env: GymEnv | str | None,
        learning_rate: float | Schedule = 1e-3,
        n_steps: int = 2000,
        batch_size: int = 64,
        n_epochs: int = 10,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        ent_coef: float = 0.0,
        vf_coef: float = 0.5,
        max_grad_norm: float = 0.5,
        hidden_size: int = 128,
        sequence_length: int = 50,
        memory: bool = True,
        normalize_advantage: bool = True,
        target_kl: float | None = None,
        policy: str | type[GRUActorCriticPolicy] = "GRUPolicy",
        policy_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        seed: int | None = None,
        device: th.device | str = "cpu",
        verbose: int = 0,
        _init_setup_model: bool = True,
    ):
        if batch_size < 1:  # (n_steps, a multiple of sequence_length: the buffer's check)
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        policy_kwargs = {"hidden_size": hidden_size, **({} if memory else {"memory": False}), **(policy_kwargs or {})}
        super().__init__(
            policy,
            env,  # type: ignore[arg-type]
            learning_rate=learning_rate,
            n_steps=n_steps,
            gamma=gamma,
            gae_lambda=gae_lambda,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=max_grad_norm,
            use_sde=False,
            sde_sample_freq=-1,
            rollout_buffer_class=RecurrentRolloutBuffer,
            rollout_buffer_kwargs={"hidden_size": policy_kwargs["hidden_size"], "sequence_length": sequence_length},
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            device=device,
            seed=seed,
            _init_setup_model=False,
            supported_action_spaces=(spaces.Discrete,),
        )
        self.batch_size, self.n_epochs, self.clip_range, self.target_kl = batch_size, n_epochs, clip_range, target_kl
        self.hidden_size, self.sequence_length = policy_kwargs["hidden_size"], sequence_length
        self.normalize_advantage = normalize_advantage
        self._last_gru_states: GRUState | None = None
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        super()._setup_model()
        self.clip_range = FloatSchedule(self.clip_range)
        self._last_gru_states = None

    @property
    def sequences_per_batch(self) -> int:
        """Whole sequences per minibatch: ``max(1, round(batch_size / sequence_length))``."""
        return max(1, round(self.batch_size / self.sequence_length))

    def _setup_learn(self, *args, **kwargs) -> tuple[int, BaseCallback]:  # type: ignore[override]
        out = super()._setup_learn(*args, **kwargs)
        n_envs = self.env.num_envs  # type: ignore[union-attr]
        if self._last_gru_states is None or self._last_gru_states[0].shape[1] != n_envs:
            # Content is irrelevant after an env reset (_last_episode_starts is all ones).
            self._last_gru_states = self.policy.initial_state(n_envs)
        return out

    # ---- acting: the hidden state is carried from step to step ----

    def collect_rollouts(
        self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer, n_rollout_steps: int
    ) -> bool:
        """SB3's ``OnPolicyAlgorithm.collect_rollouts`` with the GRU state carried between steps
        (and stored in the buffer, the state carried *into* each step)."""
        assert self._last_obs is not None, "No previous observation was provided"
        assert isinstance(rollout_buffer, RecurrentRolloutBuffer)
        assert self._last_gru_states is not None
        self.policy.set_training_mode(False)
        n_steps = 0
        rollout_buffer.reset()
        callback.on_rollout_start()
        states = self._last_gru_states

        while n_steps < n_rollout_steps:
            with th.no_grad():
                obs_tensor = obs_as_tensor(self._last_obs, self.device)  # type: ignore[arg-type]
                episode_starts = th.as_tensor(self._last_episode_starts, dtype=th.float32, device=self.device)
                actions, values, log_probs, new_states = self.policy(obs_tensor, states, episode_starts)
            actions = actions.cpu().numpy()
            new_obs, rewards, dones, infos = env.step(actions)
            self.num_timesteps += env.num_envs

            callback.update_locals(locals())
            if not callback.on_step():
                self._last_gru_states = new_states
                return False
            self._update_info_buffer(infos, dones)
            n_steps += 1

            self._bootstrap_truncated(rewards, dones, infos, new_states)
            rollout_buffer.add(
                self._last_obs,  # type: ignore[arg-type]
                actions.reshape(-1, 1),
                rewards,
                self._last_episode_starts,  # type: ignore[arg-type]
                values,
                log_probs,
                hidden_state=states,
            )
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones
            states = new_states

        self._last_gru_states = states
        with th.no_grad():
            last_values = self.policy.predict_values(
                obs_as_tensor(new_obs, self.device),  # type: ignore[arg-type]
                states,
                th.as_tensor(dones, dtype=th.float32, device=self.device),
            )
        rollout_buffer.compute_returns_and_advantage(last_values=last_values, dones=dones)
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def _bootstrap_truncated(self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict], states: GRUState) -> None:
        """Add ``gamma * V(terminal observation)`` to the reward of each env whose episode a time
        limit cut short (as SB3's on-policy loop does), the GRU state carried into it. NutriRL's
        day end is a true terminal (no ``TimeLimit.truncated``), so this never fires there."""
        for idx, done in enumerate(dones):
            info = infos[idx]
            if done and info.get("terminal_observation") is not None and info.get("TimeLimit.truncated", False):
                terminal_obs = self.policy.obs_to_tensor(info["terminal_observation"])[0]
                carried = (states[0][:, idx : idx + 1], states[1][:, idx : idx + 1])
                with th.no_grad():
                    terminal_value = self.policy.predict_values(terminal_obs, carried, th.zeros(1, device=self.device))
                rewards[idx] += self.gamma * terminal_value.item()

    # ---- training: PPO over whole sequences ----

    def ppo_loss(self, data: RecurrentRolloutBufferSamples, clip_range: float) -> tuple[th.Tensor, dict[str, float]]:
        """PPO's loss on a minibatch of sequences, re-running the GRUs over each whole sequence.

        ``loss = -E[min(r A, clip(r, 1 +- eps) A)] - ent_coef * E[H] + vf_coef * MSE(V, R)``,
        returned with logging statistics.
        """
        values, log_prob, entropy = self.policy.evaluate_actions(
            data.observations, data.actions, data.hidden_states, data.episode_starts
        )
        advantages = data.advantages
        if self.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        log_ratio = log_prob - data.old_log_prob
        ratio = th.exp(log_ratio)
        policy_loss = -th.min(advantages * ratio, advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)).mean()
        value_loss = F.mse_loss(data.returns, values)
        entropy_loss = -entropy.mean()
        loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
        with th.no_grad():
            stats = {
                "policy_gradient_loss": policy_loss.item(),
                "value_loss": value_loss.item(),
                "entropy_loss": entropy_loss.item(),
                "clip_fraction": th.mean((th.abs(ratio - 1) > clip_range).float()).item(),
                "approx_kl": th.mean((th.exp(log_ratio) - 1) - log_ratio).item(),
            }
        return loss, stats

    def train(self) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)  # type: ignore[operator]
        history: dict[str, list[float]] = {}
        loss = th.zeros(())
        continue_training = True
        for epoch in range(self.n_epochs):
            approx_kls = []
            for data in self.rollout_buffer.get(self.sequences_per_batch):
                loss, stats = self.ppo_loss(data, clip_range)
                for key, value in stats.items():
                    history.setdefault(key, []).append(value)
                approx_kls.append(stats["approx_kl"])
                if self.target_kl is not None and stats["approx_kl"] > 1.5 * self.target_kl:
                    continue_training = False
                    if self.verbose >= 1:
                        print(f"Early stopping at step {epoch} due to reaching max kl: {stats['approx_kl']:.2f}")
                    break
                self.policy.optimizer.zero_grad()
                loss.backward()
                grad_norm = th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
                history.setdefault("grad_norm", []).append(grad_norm.item())
                self.policy.optimizer.step()
            self._n_updates += 1
            if not continue_training:
                break

        explained_var = explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten())
        history["approx_kl"] = approx_kls  # as SB3's PPO logs it: the last epoch's
        for key, values in history.items():
            self.logger.record(f"train/{key}", float(np.mean(values)))
        if "entropy_loss" in history:
            self.logger.record("train/entropy", -float(np.mean(history["entropy_loss"])))
        self.logger.record("train/loss", loss.item())
        self.logger.record("train/explained_variance", explained_var)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)
        self.logger.record("train/minibatch_sequences", self.sequences_per_batch)

    # ---- inspection ----

    def day_entropy(self, obs: np.ndarray) -> float:
        """Mean entropy over one whole day's observations ``(T, obs_dim)``, the GRU state
        carried from a zero state at the day's first step (as when acting)."""
        pol = self.policy
        x = th.as_tensor(obs, dtype=th.float32).unsqueeze(0)
        starts = th.zeros(1, x.shape[1])
        starts[0, 0] = 1.0
        with th.no_grad():
            feats, _ = pol.unroll(x, pol.initial_state(1), starts)
            return float(pol.action_dist.proba_distribution(pol.actor_head(feats[0])).entropy().mean())

    # ---- SB3 plumbing ----

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_last_gru_states"]
