"""Soft Actor-Critic for discrete actions (the paper's Table 5), on Stable-Baselines3's
off-policy machinery.

The discrete form of SAC (Christodoulou 2019; CleanRL's ``sac_atari``), written so that each
part of the update can be read (and tested) on its own:

* **actor**: a categorical policy ``pi(a|s) = softmax(logits(s))``, MLP ``obs -> 256 -> 128 -> |A|``.
* **critics**: twin Q-networks, each an MLP ``obs -> 256 -> 128 -> |A|`` (one Q-head per action),
  and two target copies updated by Polyak averaging (``tau = 0.005``) after every gradient step.
* **soft value** as an *expectation* under the policy (no sampled next action)::

      V(s') = sum_a pi(a|s') * ( min(Q1_targ, Q2_targ)(s', a) - alpha * log pi(a|s') )

  -> :func:`soft_value`.
* **1-step soft Bellman target**: ``y = r + gamma * (1 - done) * V(s')`` -> :func:`soft_bellman_target`.
* **critic loss**: ``MSE(Q1(s, a), y) + MSE(Q2(s, a), y)`` (CleanRL's sum of the two).
* **actor loss**: ``E_s sum_a pi(a|s) * (alpha * log pi(a|s) - min(Q1, Q2)(s, a))`` with the critics
  detached (an exact expectation again, so no reparameterisation trick is needed).
* **temperature**: ``alpha = 0.2``, fixed (no automatic entropy tuning).
* separate Adam optimisers: actor lr 1e-4, critic lr 1e-3; no gradient clipping.

Everything else (replay buffer of 100k transitions, uniform random actions until
``learning_starts`` = batch size, ``train_freq``/``gradient_steps``, VecNormalize handling,
logging, ``save``/``load``) is Stable-Baselines3's :class:`OffPolicyAlgorithm`. Its replay
buffer stores the *unnormalised* observations and normalises them when sampling, so
wrapping the env in ``VecNormalize`` works unchanged. An episode end without
``TimeLimit.truncated`` (NutriRL's day end) is a true terminal: no bootstrap past it.

With ``n_envs`` environments, one collection step is ``n_envs`` env steps and is followed by
``gradient_steps`` gradient steps (SB3 semantics); ``gradient_steps=-1`` does one gradient
step per env step.
"""

from nutribench.agents.sac.algorithm import DiscreteSAC, soft_bellman_target, soft_value
from nutribench.agents.sac.policy import DiscreteSACPolicy, TwinQNetwork

__all__ = ["DiscreteSAC", "DiscreteSACPolicy", "TwinQNetwork", "soft_value", "soft_bellman_target"]
