"""GRU-PPO: PPO with a recurrent policy whose memory is carried through the whole episode
(the paper's Table 6).

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

**Without memory** (``memory=False``; an agent file's ``memory = false``): the same network with
its state zeroed before every step, in acting, training and evaluation alike, so each step's
output depends on that step's observation alone (the form of the authors' published GRU
agent, which fed length-1 sequences with no carried state; ``reports/gru_memory/``). The
memory ablation; the paper's GRU-PPO carries its state.

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

from nutribench.agents.gru_ppo.algorithm import GRUPPO
from nutribench.agents.gru_ppo.buffer import RecurrentRolloutBuffer, RecurrentRolloutBufferSamples
from nutribench.agents.gru_ppo.policy import GRUActorCriticPolicy, GRUState

__all__ = ["GRUPPO", "GRUActorCriticPolicy", "RecurrentRolloutBuffer", "RecurrentRolloutBufferSamples", "GRUState"]
