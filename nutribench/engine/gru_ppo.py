"""GRU-PPO for K agents at once: :class:`~nutribench.agents.gru_ppo.GRUPPO`'s policy and
update with every agent's parameters stacked along a leading agent axis. It is PPO
(:mod:`nutribench.engine.ppo`: the loop, the loss, the gradient step) with another network,
a hidden state carried while acting, and minibatches of whole days.

Per agent, the policy is ``GRUActorCriticPolicy`` (``gru_ppo.toml``): a GRU over the
nutrient stream (the first 3 observation dims) and a GRU over the food stream (the rest),
their hidden states concatenated (256) into an actor head 256-128-2 and a critic head
256-128-1; orthogonal initialisation (each GRU gate block with gain 1, the heads with
SB3's gains), zero biases; the state is reset at each day's start and carried step to step.
Without memory (the agent file's ``memory = false``) the state is zeroed before every step,
in acting, in the update's replay of days and in the greedy evaluation alike: each step's
output depends on its observation alone, as the SB3 policy's ``memory=False``.
Training is PPO over whole days: each epoch shuffles the rollout's days and takes
minibatches of ``round(batch_size / 50)`` days, each replayed through the GRUs from the zero
state with the gradient through the whole day (backpropagation through time).

The two GRUs of the K agents are one stack of 2K recurrent cells (nutrient cells first, then
food cells; the nutrient cells' inputs are zero-padded to the food stream's width, and the
padded weights, receiving no gradient, stay zero), so each time step is one batched product.
The cell is ``torch.nn.GRU``'s: ``r = s(W_ir x + b_ir + W_hr h + b_hr)``, ``z = s(W_iz x +
b_iz + W_hz h + b_hz)``, ``n = tanh(W_in x + b_in + r (W_hn h + b_hn))``, ``h' = (1 - z) n + z h``.
"""

from __future__ import annotations

import math

import torch as th

from nutribench.engine.evaluate import Greedy, greedy_categorical
from nutribench.engine.on_policy import StackedActor, log_prob_entropy
from nutribench.engine.ppo import BatchedPPO
from nutribench.engine.stacked import SB3Weights, linear_pairs, orthogonal, with_zero_biases

N_NUTRIENTS = 3


class GRUSequence(th.autograd.Function):
    """The hidden states ``(M, S, T, H)`` of M stacked GRU cells run over S sequences of T
    steps from the zero state, given the input projections ``gi = W_ih x + b_ih`` ``(M, S, T,
    3H)``, ``W_hh (M, H, 3H)`` and ``b_hh (M, 1, 3H)``; with a hand-written backward pass
    through time: per step a few elementwise products and one batched product for the state's
    gradient, and ``W_hh``'s gradient as one batched product over all steps at the end
    (autograd's backward of the step-by-step loop took 3.4 times the forward pass)."""

    @staticmethod
    def forward(ctx, gi: th.Tensor, w_hh: th.Tensor, b_hh: th.Tensor) -> th.Tensor:
        m, s, t_max, h3 = gi.shape
        H = h3 // 3
        hs, rz, ns, ghn = (gi.new_empty(m, s, t_max, width) for width in (H, 2 * H, H, H))
        h = gi.new_zeros(m, s, H)
        for t in range(t_max):
            gh = th.baddbmm(b_hh, h, w_hh)
            g = gi[:, :, t]
            gates = th.sigmoid(g[..., : 2 * H] + gh[..., : 2 * H])
            n = th.tanh(g[..., 2 * H :] + gates[..., :H] * gh[..., 2 * H :])
            h = n + gates[..., H:] * (h - n)
            hs[:, :, t], rz[:, :, t], ns[:, :, t], ghn[:, :, t] = h, gates, n, gh[..., 2 * H :]
        ctx.save_for_backward(w_hh, hs, rz, ns, ghn)
        return hs

    @staticmethod
    def backward(ctx, d_hs: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        w_hh, hs, rz, ns, ghn = ctx.saved_tensors
        m, s, t_max, H = hs.shape
        d_gi, d_gh = hs.new_empty(m, s, t_max, 3 * H), hs.new_empty(m, s, t_max, 3 * H)
        w_t = w_hh.transpose(1, 2)
        zeros = hs.new_zeros(m, s, H)
        dh = zeros
        for t in reversed(range(t_max)):
            dh = dh + d_hs[:, :, t]
            h_prev = hs[:, :, t - 1] if t > 0 else zeros
            r, z, n = rz[:, :, t, :H], rz[:, :, t, H:], ns[:, :, t]
            da_n = dh * (1 - z) * (1 - n * n)
            d_rz = th.cat([da_n * ghn[:, :, t], dh * (h_prev - n)], dim=-1) * rz[:, :, t] * (1 - rz[:, :, t])
            d_gi[:, :, t, : 2 * H] = d_gh[:, :, t, : 2 * H] = d_rz
            d_gi[:, :, t, 2 * H :] = da_n
            d_gh[:, :, t, 2 * H :] = da_n * r
            dh = dh * z + th.bmm(d_gh[:, :, t], w_t)
        h_prev_all = th.cat([hs.new_zeros(m, s, 1, H), hs[:, :, :-1]], dim=2).reshape(m, s * t_max, H)
        d_gh_flat = d_gh.reshape(m, s * t_max, 3 * H)
        return d_gi, th.bmm(h_prev_all.transpose(1, 2), d_gh_flat), d_gh_flat.sum(dim=1, keepdim=True)


class StackedGRUActorCritic(SB3Weights):
    """K copies of ``GRUActorCriticPolicy``. Parameters, in order: the 2K cells' ``W_ih (2K,
    in, 3H)``, ``b_ih (2K, 1, 3H)``, ``W_hh (2K, H, 3H)``, ``b_hh (2K, 1, 3H)`` (gates r, z,
    n as nn.GRU), then the heads' first layers side by side ``(K, 2H, 2 x head)`` and bias,
    the actor's last layer ``(K, head, 2)`` and bias, the critic's ``(K, head, 1)`` and bias.
    ``memory=False``: every step from the zero state (:meth:`sequences`, :meth:`step`,
    :meth:`step_days`), the same network without memory."""

    def __init__(
        self,
        k: int,
        obs_dim: int,
        hidden: int = 128,
        head: int = 128,
        n_actions: int = 2,
        generators: list[th.Generator] | None = None,
        device: th.device | str | None = None,
        memory: bool = True,
    ):
        """Initialised on the CPU from ``generators`` (one per agent), then moved to ``device``."""
        self.k, self.hidden, self.head, self.n_actions = k, hidden, head, n_actions
        self.memory = memory
        self.n_foods = obs_dim - N_NUTRIENTS
        self.width = max(N_NUTRIENTS, self.n_foods)
        h3 = 3 * hidden
        w_ih, w_hh = th.zeros(2 * k, self.width, h3), th.zeros(2 * k, hidden, h3)
        for stream, n_in in ((0, N_NUTRIENTS), (1, self.n_foods)):  # as policy.py: nutrient GRU, then food GRU
            for gate in range(3):
                cols = slice(gate * hidden, (gate + 1) * hidden)
                w_ih[stream * k : (stream + 1) * k, :n_in, cols] = orthogonal(k, n_in, hidden, 1.0, generators)
                w_hh[stream * k : (stream + 1) * k, :, cols] = orthogonal(k, hidden, hidden, 1.0, generators)
        # the actor's first head layer, then the critic's, side by side
        first = th.cat([orthogonal(k, 2 * hidden, head, math.sqrt(2), generators) for _ in range(2)], dim=2)
        actor_out = orthogonal(k, head, n_actions, 0.01, generators)
        critic_out = orthogonal(k, head, 1, 1.0, generators)
        self.params = with_zero_biases([w_ih, w_hh, first, actor_out, critic_out], device)

    # ---- the recurrent core ----

    def _projections(self, obs: th.Tensor) -> th.Tensor:
        """``obs (K, N, d)`` -> the 2K cells' input projections ``W_ih x + b_ih`` ``(2K, N, 3H)``
        (their inputs ``x (2K, N, width)``: the nutrients, then the foods, each zero-padded)."""
        nut, food = obs[..., :N_NUTRIENTS], obs[..., N_NUTRIENTS:]
        pad = lambda x: th.nn.functional.pad(x, (0, self.width - x.shape[-1]))  # noqa: E731
        return th.baddbmm(self.params[1], th.cat([pad(nut), pad(food)]), self.params[0])

    def _cell(self, gi: th.Tensor, h: th.Tensor) -> th.Tensor:
        """One GRU step of the 2K cells: input projection ``gi (2K, B, 3H)``, state ``h (2K, B, H)``."""
        gh = th.baddbmm(self.params[3], h, self.params[2])
        H = self.hidden
        r = th.sigmoid(gi[..., :H] + gh[..., :H])
        z = th.sigmoid(gi[..., H : 2 * H] + gh[..., H : 2 * H])
        n = th.tanh(gi[..., 2 * H :] + r * gh[..., 2 * H :])
        return n + z * (h - n)  # (1 - z) n + z h

    def _heads(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``features (K, N, 2H)`` -> logits ``(K, N, n_actions)``, values ``(K, N)``."""
        p = self.params
        x = th.relu(th.baddbmm(p[5], features, p[4]))
        logits = th.baddbmm(p[7], x[..., : self.head], p[6])
        if self.k > 1:
            values = th.baddbmm(p[9], x[..., self.head :], p[8])
        else:  # torch rounds a batch of one matrix-vector product (a gemv) unlike a batch of two or more: pad to two
            values = th.baddbmm(p[9].repeat(2, 1, 1), x[..., self.head :].repeat(2, 1, 1), p[8].repeat(2, 1, 1))[:1]
        return logits, values[..., 0]

    def sequences(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """Whole days from the zero state: ``obs (K, S, T, d)`` -> logits ``(K, S, T, n_actions)``, values ``(K, S, T)``
        (without memory, every step its own sequence of one step)."""
        k, s, t_max, _ = obs.shape
        if not self.memory and t_max > 1:
            logits, values = self.sequences(obs.reshape(k, s * t_max, 1, -1))
            return logits.reshape(k, s, t_max, -1), values.reshape(k, s, t_max)
        gi = self._projections(obs.reshape(k, s * t_max, -1)).reshape(2 * k, s, t_max, -1)
        out = GRUSequence.apply(gi, self.params[2], self.params[3])  # (2K, S, T, H)
        features = th.cat([out[:k], out[k:]], dim=-1).reshape(k, s * t_max, 2 * self.hidden)
        logits, values = self._heads(features)
        return logits.reshape(k, s, t_max, -1), values.reshape(k, s, t_max)

    def evaluate_actions(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """``log pi(a|s)``, the policy's entropy and the values of whole days ``obs (K, S, T, d)``,
        ``actions (K, S, T)`` replayed from the zero state (:meth:`sequences`), each ``(K, S T)``."""
        logits, values = self.sequences(obs)
        log_prob, entropy = log_prob_entropy(logits.reshape(self.k, -1, self.n_actions), actions.reshape(self.k, -1))
        return log_prob, entropy, values.reshape(self.k, -1)

    def step(self, obs: th.Tensor, state: th.Tensor, starts: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """One acting step: ``obs (K, d)``, ``state (2K, 1, H)`` zeroed where ``starts (K,)``;
        logits ``(K, n_actions)``, values ``(K,)`` and the new state (without memory :meth:`step_days`
        zeroes it everywhere)."""
        keep = (1.0 - starts).reshape(1, self.k, 1, 1).expand(2, -1, -1, -1).reshape(2 * self.k, 1, 1)
        logits, values, h = self.step_days(obs.unsqueeze(1), state * keep)
        return logits[:, 0], values[:, 0], h

    def step_days(self, obs: th.Tensor, state: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """One step of ``B`` days side by side per agent: ``obs (K, B, d)``, ``state (2K, B, H)``;
        logits ``(K, B, n_actions)``, values ``(K, B)`` and the new state (no reset: days start
        from zeros; without memory every step does)."""
        if not self.memory:
            state = th.zeros_like(state)
        h = self._cell(self._projections(obs), state)
        logits, values = self._heads(th.cat([h[: self.k], h[self.k :]], dim=-1))
        return logits, values, h

    # ---- SB3's policy ----

    def sb3_pairs(self, j: int, policy) -> list[tuple[th.Tensor, th.Tensor]]:
        """Agent ``j``'s parameters and a ``GRUActorCriticPolicy``'s."""
        k, p = self.k, self.params
        pairs = []
        for stream, gru in enumerate((policy.nutrient_gru, policy.food_gru)):
            row = stream * k + j
            n_in = gru.weight_ih_l0.shape[1]
            pairs += [
                (p[0][row, :n_in], gru.weight_ih_l0.T),
                (p[1][row, 0], gru.bias_ih_l0),
                (p[2][row], gru.weight_hh_l0.T),
                (p[3][row, 0], gru.bias_hh_l0),
            ]
        pairs += [
            (p[4][j, :, : self.head], policy.actor_head[0].weight.T),
            (p[4][j, :, self.head :], policy.critic_head[0].weight.T),
            (p[5][j, 0, : self.head], policy.actor_head[0].bias),
            (p[5][j, 0, self.head :], policy.critic_head[0].bias),
            *linear_pairs(p[6:], j, [policy.actor_head[2], policy.critic_head[2]]),
        ]
        assert self.hidden == policy.hidden_size and self.n_actions == policy.action_space.n
        return pairs


class RecurrentActor(StackedActor):
    """Acting with the GRU actor-critic, its state carried from step to step from zeros (reset
    where a day starts; a checkpoint keeps it)."""

    def __init__(self, net: StackedGRUActorCritic):
        super().__init__(net, th.zeros(2 * net.k, 1, net.hidden, device=net.params[0].device))


class BatchedGRUPPO(BatchedPPO):
    """K GRU-PPO agents: PPO's loop, loss and step with the stacked GRU actor-critic, its
    state carried while acting, its update over whole days."""

    @classmethod
    def forward_flops(cls, cfg, obs_dim: int, n_actions: int) -> float:
        """Two GRU steps (input and recurrent products of 3 gates) and the two heads."""
        h, head = cfg.hidden_size, 128
        grus = sum(2 * n_in * 3 * h + 2 * h * 3 * h for n_in in (N_NUTRIENTS, obs_dim - N_NUTRIENTS))
        return grus + 2 * (2 * h) * head * 2 + 2 * head * (n_actions + 1)

    def make_network(self, generators: list[th.Generator]) -> StackedGRUActorCritic:
        memory = {c.memory for c in self.cfgs}
        if len(memory) > 1:
            raise ValueError("agents of one batch must agree on memory")
        kwargs = dict(generators=generators, device=self.device, memory=memory.pop())
        return StackedGRUActorCritic(self.k, self.envs.obs_dim, self.cfg.hidden_size, **kwargs)

    def make_actor(self, net: StackedGRUActorCritic) -> RecurrentActor:
        return RecurrentActor(net)

    def greedy(self) -> Greedy:
        state: list[th.Tensor] = []  # the GRU state of the days played, from zeros

        def play(obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
            if not state:
                state.append(th.zeros(2 * self.k, obs.shape[1], self.net.hidden, device=obs.device))
            logits, _, state[0] = self.net.step_days(obs, state[0])
            return greedy_categorical(logits)

        return play
