"""GRU-PPO: PPO with a recurrent policy whose memory is carried through the whole episode (SPEC 3).

Everything PPO is unchanged (clipped surrogate with ``clip_range`` 0.2, GAE gamma 0.99 and
lambda 0.95, Adam lr 1e-3, value coefficient 0.5, L2 gradient clip 0.5, advantage
normalisation per minibatch, ``n_epochs`` passes over each rollout). What changes is the
policy and, because of it, how data is collected and replayed:

**Policy** (:class:`GRUActorCriticPolicy`, Table 6). The flat observation is split by index:
``obs[..., :3]`` (absorbed C, F, P) feeds a 1-layer GRU ``3 -> 128`` and ``obs[..., 3:]`` (the
one-hot of the offered food, N dims) feeds a second 1-layer GRU ``N -> 128``. Their hidden
states after the current step are concatenated (256) and read by an actor head
``Linear(256,128)-ReLU-Linear(128,|A|)`` (categorical logits) and a critic head
``Linear(256,128)-ReLU-Linear(128,1)``. Orthogonal initialisation (each GRU gate block with
gain 1; head layers with SB3's PPO gains: sqrt(2) hidden, 0.01 policy output, 1 value
output) and zero biases everywhere.

**Hidden state, always carried.** The state ``(h_nutrient, h_food)``, each ``(1, n_envs, 128)``,
is set to zero where ``episode_start`` is true and otherwise carried from one step to the next:

* *acting* (:meth:`GRUPPO.collect_rollouts`): one GRU step per env step; the state carried
  *into* each step is stored in the rollout buffer next to the observation and the
  ``episode_start`` flag; it survives across rollouts (``self._last_gru_states``);
* *training* (:meth:`GRUPPO.train`): the buffer (:class:`RecurrentRolloutBuffer`) cuts each
  env's time line into sequences of ``sequence_length`` = 50 steps, shaped
  ``(n_seq, 50, obs_dim)``; the policy re-runs the GRUs over each whole sequence from the
  stored state at its first step (masked by its ``episode_start``), so gradients flow
  back through all earlier steps of the episode (full backpropagation through time). On
  NutriRL every episode has exactly 50 steps, all envs start and end together and each
  rollout starts at an episode boundary, so a sequence *is* one episode and starts from a
  zero state; episode starts inside a sequence (other envs / horizons) are still handled by
  resetting the state at those steps, so the computation matches acting in every case;
* *evaluation* (:meth:`GRUActorCriticPolicy.predict`, the same as sb3-contrib's RecurrentPPO)::

      state, episode_start = None, np.ones(n_envs, dtype=bool)
      obs = venv.reset()
      while ...:
          action, state = model.predict(obs, state=state, episode_start=episode_start, deterministic=True)
          obs, reward, done, info = venv.step(action)
          episode_start = done

**Minibatches.** PPO's minibatch of 64 *transitions* cannot be made of whole 50-step
episodes. ``batch_size`` keeps PPO's unit (env steps per minibatch) and is rounded to a whole
number of sequences, ``max(1, round(batch_size / sequence_length))``: the default 64 gives
minibatches of one 50-step episode, so the number of gradient steps per epoch stays about
that of PPO (``n_steps * n_envs / 50`` instead of ``/ 64``). Pass e.g.
``batch_size=64 * 50`` for minibatches of 64 episodes. Sequences are shuffled each epoch.

**Observation normalisation.** Wrap the env in ``VecNormalize(norm_obs=True,
norm_reward=False)``; the observations then reach the policy already normalised (rollouts
store them as seen), and ``predict`` expects normalised observations as well
(``VecNormalize(training=False)`` at evaluation).
"""

from __future__ import annotations

import math
from collections.abc import Generator
from typing import Any, ClassVar, NamedTuple, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from torch import nn
from torch.nn import functional as F

from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.distributions import CategoricalDistribution
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, PyTorchObs, Schedule
from stable_baselines3.common.utils import FloatSchedule, explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv

__all__ = ["GRUPPO", "GRUActorCriticPolicy", "RecurrentRolloutBuffer", "RecurrentRolloutBufferSamples", "GRUState"]

SelfGRUPPO = TypeVar("SelfGRUPPO", bound="GRUPPO")

GRUState = tuple[th.Tensor, th.Tensor]
"""``(h_nutrient, h_food)``, each ``(1, batch, hidden_size)`` (nn.GRU's layout)."""


# ---------------------------------------------------------------------------------------------
# Policy
# ---------------------------------------------------------------------------------------------


def _orthogonal_gru_init_(gru: nn.GRU, gain: float = 1.0) -> None:
    """Orthogonal init of each gate block (reset, update, new) of a GRU's weights; zero biases."""
    hidden = gru.hidden_size
    for name, param in gru.named_parameters():
        if name.startswith("weight"):
            for k in range(3):
                nn.init.orthogonal_(param.data[k * hidden : (k + 1) * hidden], gain=gain)
        else:
            nn.init.zeros_(param)


class GRUActorCriticPolicy(BasePolicy):
    """Two-stream GRU actor-critic (SPEC 3, Table 6); see the module docstring.

    :param observation_space: flat ``Box`` of ``n_nutrients + N`` dims (nutrients first).
    :param action_space: ``Discrete`` action space.
    :param lr_schedule: learning-rate schedule (its value at progress 1 builds the optimiser).
    :param hidden_size: hidden units of each GRU.
    :param head_size: hidden units of the actor and critic heads.
    :param n_nutrients: how many leading observation dims form the nutrient stream.
    :param ortho_init: orthogonal initialisation with zero biases.
    :param use_sde: must be False (accepted because SB3's on-policy set-up passes it).
    :param optimizer_class: optimiser class (Adam).
    :param optimizer_kwargs: optimiser keyword arguments; default ``eps=1e-5`` for Adam, as SB3's PPO.
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        hidden_size: int = 128,
        head_size: int = 128,
        n_nutrients: int = 3,
        ortho_init: bool = True,
        use_sde: bool = False,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
    ):
        if optimizer_kwargs is None:
            optimizer_kwargs = {"eps": 1e-5} if optimizer_class == th.optim.Adam else {}
        super().__init__(observation_space, action_space, optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs)
        if use_sde:
            raise ValueError("GRUActorCriticPolicy does not support gSDE")
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"GRUActorCriticPolicy needs a Discrete action space, got {action_space}")
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(f"GRUActorCriticPolicy needs a flat Box observation space, got {observation_space}")
        obs_dim = int(observation_space.shape[0])
        if not 0 < n_nutrients < obs_dim:
            raise ValueError(f"n_nutrients must be in 1..{obs_dim - 1}, got {n_nutrients}")
        self.hidden_size = int(hidden_size)
        self.head_size = int(head_size)
        self.n_nutrients = int(n_nutrients)
        self.n_foods = obs_dim - self.n_nutrients
        self.ortho_init = ortho_init
        n_actions = int(action_space.n)

        self.nutrient_gru = nn.GRU(self.n_nutrients, self.hidden_size, num_layers=1, batch_first=True)
        self.food_gru = nn.GRU(self.n_foods, self.hidden_size, num_layers=1, batch_first=True)
        features = 2 * self.hidden_size
        self.actor_head = nn.Sequential(nn.Linear(features, self.head_size), nn.ReLU(), nn.Linear(self.head_size, n_actions))
        self.critic_head = nn.Sequential(nn.Linear(features, self.head_size), nn.ReLU(), nn.Linear(self.head_size, 1))
        self.action_dist = CategoricalDistribution(n_actions)

        if ortho_init:
            _orthogonal_gru_init_(self.nutrient_gru)
            _orthogonal_gru_init_(self.food_gru)
            for module, gain in (
                (self.actor_head[0], math.sqrt(2)),
                (self.actor_head[2], 0.01),
                (self.critic_head[0], math.sqrt(2)),
                (self.critic_head[2], 1.0),
            ):
                self.init_weights(module, gain=gain)  # orthogonal weight, zero bias

        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            dict(
                lr_schedule=self._dummy_schedule,  # not needed to load the policy alone
                hidden_size=self.hidden_size,
                head_size=self.head_size,
                n_nutrients=self.n_nutrients,
                ortho_init=self.ortho_init,
                optimizer_class=self.optimizer_class,
                optimizer_kwargs=self.optimizer_kwargs,
            )
        )
        return data

    # ---- recurrent core ----

    def initial_state(self, n_envs: int) -> GRUState:
        """Zero hidden state for ``n_envs`` envs."""
        zeros = th.zeros(1, n_envs, self.hidden_size, device=self.device)
        return zeros, zeros.clone()

    def unroll(self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor) -> tuple[th.Tensor, GRUState]:
        """Run both GRUs over sequences, resetting the state where an episode starts.

        :param obs: ``(batch, T, obs_dim)`` observations (as the policy sees them).
        :param state: hidden state carried into the first step, each ``(1, batch, hidden)``.
        :param episode_starts: ``(batch, T)``, 1 where the step is the first of an episode
            (the carried state is zeroed before that step).
        :return: features ``(batch, T, 2 * hidden)`` (both GRUs' hidden states after each step)
            and the state after the last step.
        """
        obs = preprocess_obs(obs, self.observation_space).float()  # type: ignore[assignment]
        batch, steps = obs.shape[0], obs.shape[1]
        nutrients, foods = obs[..., : self.n_nutrients], obs[..., self.n_nutrients :]
        keep = 1.0 - episode_starts.float().reshape(batch, steps)
        h_nut, h_food = state
        if steps == 1 or bool((keep[:, 1:] == 1.0).all()):
            # Fast path: the state is reset at most before the first step -> one GRU call.
            mask = keep[:, 0].reshape(1, batch, 1)
            out_nut, h_nut = self.nutrient_gru(nutrients, h_nut * mask)
            out_food, h_food = self.food_gru(foods, h_food * mask)
        else:
            # An episode starts inside a sequence: step by step, zeroing the state there.
            outs_nut, outs_food = [], []
            for t in range(steps):
                mask = keep[:, t].reshape(1, batch, 1)
                o_nut, h_nut = self.nutrient_gru(nutrients[:, t : t + 1], h_nut * mask)
                o_food, h_food = self.food_gru(foods[:, t : t + 1], h_food * mask)
                outs_nut.append(o_nut)
                outs_food.append(o_food)
            out_nut, out_food = th.cat(outs_nut, dim=1), th.cat(outs_food, dim=1)
        return th.cat([out_nut, out_food], dim=-1), (h_nut, h_food)

    def _step(self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor) -> tuple[th.Tensor, GRUState]:
        """One step for a batch of envs: ``obs (n, obs_dim)``, ``episode_starts (n,)`` -> features ``(n, 2H)``."""
        features, new_state = self.unroll(obs.unsqueeze(1), state, episode_starts.reshape(-1, 1))
        return features[:, 0], new_state

    # ---- acting ----

    def forward(
        self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor, deterministic: bool = False
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor, GRUState]:
        """One acting step: ``(actions, values, log_probs, new_state)``."""
        features, new_state = self._step(obs, state, episode_starts)
        dist = self.action_dist.proba_distribution(self.actor_head(features))
        actions = dist.get_actions(deterministic=deterministic)
        return actions, self.critic_head(features), dist.log_prob(actions), new_state

    def get_distribution(
        self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor
    ) -> tuple[CategoricalDistribution, GRUState]:
        """Action distribution after one step from ``state`` (and the new state)."""
        features, new_state = self._step(obs, state, episode_starts)
        return self.action_dist.proba_distribution(self.actor_head(features)), new_state

    def predict_values(self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor) -> th.Tensor:
        """``(n, 1)`` values after one step from ``state``."""
        features, _ = self._step(obs, state, episode_starts)
        return self.critic_head(features)

    # ---- training ----

    def evaluate_actions(
        self, obs: th.Tensor, actions: th.Tensor, state: GRUState, episode_starts: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Values, log-probabilities of ``actions`` and entropies over whole sequences.

        :param obs: ``(batch, T, obs_dim)``; :param actions: ``(batch, T)``;
        :param state: state carried into the first step; :param episode_starts: ``(batch, T)``.
        :return: three ``(batch * T,)`` tensors, in (sequence, step) order. Each step's outputs
            depend on every earlier step of its episode through the recurrent state.
        """
        features, _ = self.unroll(obs, state, episode_starts)
        features = features.reshape(-1, features.shape[-1])
        dist = self.action_dist.proba_distribution(self.actor_head(features))
        return self.critic_head(features).flatten(), dist.log_prob(actions.reshape(-1).long()), dist.entropy()

    # ---- SB3 predict API (sb3-contrib RecurrentPPO semantics) ----

    def _predict(  # type: ignore[override]
        self, observation: PyTorchObs, state: GRUState | None = None, episode_starts: th.Tensor | None = None, deterministic: bool = False
    ) -> tuple[th.Tensor, GRUState]:
        obs = observation  # type: ignore[assignment]
        n = obs.shape[0]  # type: ignore[union-attr]
        if state is None:
            state = self.initial_state(n)
        if episode_starts is None:
            episode_starts = th.zeros(n, device=self.device)
        actions, _, _, new_state = self.forward(obs, state, episode_starts, deterministic)  # type: ignore[arg-type]
        return actions, new_state

    def predict(  # type: ignore[override]
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """Action(s) and the next hidden state, carried like sb3-contrib's ``RecurrentPPO``.

        :param observation: ``(n_envs, obs_dim)`` or one ``(obs_dim,)`` observation.
        :param state: the state returned by the previous call (None: zero state).
        :param episode_start: ``(n_envs,)`` bools, True where ``observation`` is the first of an
            episode (the state is reset there); None means False everywhere.
        :param deterministic: argmax action instead of a sample.
        :return: ``(actions, (h_nutrient, h_food))``, states as ``(1, n_envs, hidden)`` arrays.
        """
        self.set_training_mode(False)
        obs_tensor, vectorized = self.obs_to_tensor(observation)
        n = obs_tensor.shape[0]  # type: ignore[union-attr]
        state_t = None if state is None else tuple(th.as_tensor(s, dtype=th.float32, device=self.device) for s in state)
        starts = None if episode_start is None else th.as_tensor(np.asarray(episode_start, dtype=np.float32).reshape(n), device=self.device)
        with th.no_grad():
            actions, new_state = self._predict(obs_tensor, state_t, starts, deterministic)  # type: ignore[arg-type]
        actions_np = actions.cpu().numpy().reshape((-1, *self.action_space.shape))  # type: ignore[misc]
        if not vectorized:
            actions_np = actions_np.squeeze(axis=0)
        return actions_np, tuple(h.cpu().numpy() for h in new_state)


# ---------------------------------------------------------------------------------------------
# Rollout buffer
# ---------------------------------------------------------------------------------------------


class RecurrentRolloutBufferSamples(NamedTuple):
    """A minibatch of whole sequences (B sequences of T steps)."""

    observations: th.Tensor  # (B, T, obs_dim)
    actions: th.Tensor  # (B, T)
    old_values: th.Tensor  # (B * T,)
    old_log_prob: th.Tensor  # (B * T,)
    advantages: th.Tensor  # (B * T,)
    returns: th.Tensor  # (B * T,)
    episode_starts: th.Tensor  # (B, T)
    hidden_states: GRUState  # state carried into each sequence's first step, each (1, B, H)


class RecurrentRolloutBuffer(RolloutBuffer):
    """SB3's ``RolloutBuffer`` plus, per step, the GRU state carried into that step; serves
    minibatches of whole sequences of ``sequence_length`` consecutive steps of one env.

    GAE and returns are SB3's (``compute_returns_and_advantage`` is inherited, and already
    uses ``episode_starts``). ``get(n_sequences)`` yields :class:`RecurrentRolloutBufferSamples`.

    :param buffer_size: steps per env (``n_steps``), a multiple of ``sequence_length``.
    :param hidden_size: GRU hidden size.
    :param sequence_length: steps per training sequence (NutriRL's episode length, 50).
    """

    hidden_states: np.ndarray

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        gae_lambda: float = 1,
        gamma: float = 0.99,
        n_envs: int = 1,
        hidden_size: int = 128,
        sequence_length: int = 50,
    ):
        if sequence_length < 1 or buffer_size % sequence_length != 0:
            raise ValueError(
                f"the rollout length n_steps={buffer_size} must be a multiple of sequence_length={sequence_length} "
                "(the episode length: training replays whole episodes through the GRU)"
            )
        self.hidden_size = hidden_size
        self.sequence_length = sequence_length
        super().__init__(buffer_size, observation_space, action_space, device, gae_lambda, gamma, n_envs)

    @property
    def n_sequences(self) -> int:
        return (self.buffer_size // self.sequence_length) * self.n_envs

    def reset(self) -> None:
        super().reset()
        # (step, env, stream, hidden); stream 0 = nutrient GRU, 1 = food GRU
        self.hidden_states = np.zeros((self.buffer_size, self.n_envs, 2, self.hidden_size), dtype=np.float32)

    def add(self, *args, hidden_state: GRUState, **kwargs) -> None:  # type: ignore[override]
        """SB3's ``add(obs, action, reward, episode_start, value, log_prob)`` plus the state
        carried into this step (before the ``episode_start`` reset)."""
        h_nut, h_food = hidden_state
        self.hidden_states[self.pos, :, 0] = h_nut[0].cpu().numpy()
        self.hidden_states[self.pos, :, 1] = h_food[0].cpu().numpy()
        super().add(*args, **kwargs)

    def to_sequences(self, arr: np.ndarray) -> np.ndarray:
        """``(n_steps, n_envs, *rest)`` -> ``(n_sequences, T, *rest)``: each env's time line cut
        into consecutive chunks of T steps (sequence index = chunk * n_envs + env)."""
        T = self.sequence_length
        rest = arr.shape[2:]
        chunks = arr.reshape(self.buffer_size // T, T, self.n_envs, *rest)
        return chunks.swapaxes(1, 2).reshape(self.n_sequences, T, *rest)

    def get(self, batch_size: int | None = None) -> Generator[RecurrentRolloutBufferSamples, None, None]:  # type: ignore[override]
        """Shuffled minibatches of ``batch_size`` whole sequences (None: all in one)."""
        assert self.full, "the rollout buffer is not full"
        if not self.generator_ready:  # reshape once per rollout (reset() clears the flag)
            self._sequences = {
                name: self.to_sequences(getattr(self, name))
                for name in ("observations", "actions", "values", "log_probs", "advantages", "returns", "episode_starts")
            }
            # state carried into each sequence's first step: (n_seq, 2, H)
            self._sequences["hidden_states"] = self.to_sequences(self.hidden_states)[:, 0]
            self.generator_ready = True
        seq = self._sequences
        n_seq = self.n_sequences
        if batch_size is None:
            batch_size = n_seq
        indices = np.random.permutation(n_seq)
        for start in range(0, n_seq, batch_size):
            yield self._get_sequence_samples(seq, indices[start : start + batch_size])

    def _get_sequence_samples(self, seq: dict[str, np.ndarray], idx: np.ndarray) -> RecurrentRolloutBufferSamples:
        hidden = self.to_torch(seq["hidden_states"][idx])  # (B, 2, H)
        return RecurrentRolloutBufferSamples(
            observations=self.to_torch(seq["observations"][idx]),
            actions=self.to_torch(seq["actions"][idx].reshape(len(idx), self.sequence_length)),
            old_values=self.to_torch(seq["values"][idx].reshape(-1)),
            old_log_prob=self.to_torch(seq["log_probs"][idx].reshape(-1)),
            advantages=self.to_torch(seq["advantages"][idx].reshape(-1)),
            returns=self.to_torch(seq["returns"][idx].reshape(-1)),
            episode_starts=self.to_torch(seq["episode_starts"][idx]),
            hidden_states=(hidden[:, 0].unsqueeze(0).contiguous(), hidden[:, 1].unsqueeze(0).contiguous()),
        )


# ---------------------------------------------------------------------------------------------
# Algorithm
# ---------------------------------------------------------------------------------------------


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
    entropy over the rollout's minibatches, nats) and ``train/minibatch_sequences``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"GRUPolicy": GRUActorCriticPolicy, "MlpPolicy": GRUActorCriticPolicy}
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
        if sequence_length < 1 or n_steps % sequence_length != 0:
            raise ValueError(
                f"GRUPPO needs n_steps to be a multiple of sequence_length={sequence_length} (the episode "
                f"length), so that training replays whole episodes through the GRU; got n_steps={n_steps}"
            )
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        policy_kwargs = dict(policy_kwargs or {})
        policy_kwargs.setdefault("hidden_size", hidden_size)
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
        self.batch_size = batch_size
        self.n_epochs = n_epochs
        self.clip_range = clip_range
        self.hidden_size = policy_kwargs["hidden_size"]
        self.sequence_length = sequence_length
        self.normalize_advantage = normalize_advantage
        self.target_kl = target_kl
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
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
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

            # Bootstrap on time-limit truncation (SB3 issue #633). NutriRL's day end is a true
            # terminal (no "TimeLimit.truncated"), so this never fires there.
            for idx, done in enumerate(dones):
                if done and infos[idx].get("terminal_observation") is not None and infos[idx].get("TimeLimit.truncated", False):
                    terminal_obs = self.policy.obs_to_tensor(infos[idx]["terminal_observation"])[0]
                    carried = (new_states[0][:, idx : idx + 1], new_states[1][:, idx : idx + 1])
                    with th.no_grad():
                        terminal_value = self.policy.predict_values(terminal_obs, carried, th.zeros(1, device=self.device))
                    rewards[idx] += self.gamma * terminal_value.item()

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
        ratio = th.exp(log_prob - data.old_log_prob)
        policy_loss = -th.min(advantages * ratio, advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)).mean()
        value_loss = F.mse_loss(data.returns, values)
        entropy_loss = -entropy.mean()
        loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
        with th.no_grad():
            log_ratio = log_prob - data.old_log_prob
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
                th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
                self.policy.optimizer.step()
            self._n_updates += 1
            if not continue_training:
                break

        explained_var = explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten())
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

    def action_probabilities(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """``pi(.|history)`` after one more step, and the new state (same conventions as ``predict``)."""
        self.policy.set_training_mode(False)
        obs, vectorized = self.policy.obs_to_tensor(observation)
        n = obs.shape[0]  # type: ignore[union-attr]
        state_t = self.policy.initial_state(n) if state is None else tuple(th.as_tensor(s, dtype=th.float32) for s in state)
        starts = th.zeros(n) if episode_start is None else th.as_tensor(np.asarray(episode_start, dtype=np.float32).reshape(n))
        with th.no_grad():
            dist, new_state = self.policy.get_distribution(obs, state_t, starts)  # type: ignore[arg-type]
            probs = dist.distribution.probs.cpu().numpy()
        return (probs if vectorized else probs[0]), tuple(h.cpu().numpy() for h in new_state)

    def action_entropy(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """Entropy (nats) of ``pi(.|history)`` after one more step, and the new state."""
        probs, new_state = self.action_probabilities(observation, state, episode_start)
        logs = np.log(np.clip(probs, 1e-30, None))
        return -(probs * logs).sum(axis=-1), new_state

    # ---- SB3 plumbing ----

    def learn(
        self: SelfGRUPPO,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "GRUPPO",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfGRUPPO:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_last_gru_states"]
