"""The stacked primitives every batched algorithm is built of: K agents' parameters along a
leading agent axis, and what keeps each agent's update its own.

* :func:`orthogonal` and :class:`StackedMLP`: stacked layers ``(W (K, in, out), b (K, 1,
  out))`` initialised per agent from its own generator as SB3 (orthogonal) or
  ``torch.nn.Linear`` (Kaiming-uniform) initialise one agent's, applied with
  ``torch.baddbmm``;
* :func:`clip_grad_norm_per_agent`: ``clip_grad_norm_`` over each agent's own parameters;
* :class:`StackedAdam`: Adam over stacked parameters, each agent at its own
  rate: torch's Adam at rate 1 (fused where that is batch-invariant), each row's move scaled by
  its agent's rate, alone or stacked alike;
* :class:`RunningStats`: SB3's ``RunningMeanStd`` for K agents (``VecNormalize``'s statistics);
* :class:`AgentMeans`: per-agent means of a few ``(K,)`` quantities over an update's gradient
  steps, kept on the device and read back at once (the agents' diagnostics).

Stacking is exact: the loss is the sum of the K agents' losses over disjoint parameters, so
each agent's gradient is its own loss's gradient.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch as th

from nutribench.engine.device import leaves_on


def orthogonal(k: int, n_in: int, n_out: int, gain: float, generators: list[th.Generator] | None = None) -> th.Tensor:
    """``(k, n_in, n_out)``: each agent's ``(n_out, n_in)`` weight initialised orthogonally as
    SB3 (and ``GRUActorCriticPolicy``) do, from its own generator, then transposed."""
    w = th.empty(k, n_in, n_out)
    for j in range(k):
        block = th.empty(n_out, n_in)
        th.nn.init.orthogonal_(block, gain=gain, generator=None if generators is None else generators[j])
        w[j] = block.T
    return w


def linears(module: th.nn.Module) -> list[th.nn.Linear]:
    """The ``Linear`` layers of an ``nn.Sequential`` MLP, input to output."""
    return [m for m in module if isinstance(m, th.nn.Linear)]


def linear_pairs(params: list[th.Tensor], j: int, layers: list[th.nn.Linear]) -> list[tuple[th.Tensor, th.Tensor]]:
    """Agent ``j``'s first stacked layers ``(W, b)`` of ``params`` and ``layers`` (``nn.Linear``), as
    :meth:`SB3Weights.sb3_pairs` gives them."""
    pairs = []
    for i, lin in enumerate(layers):
        pairs += [(params[2 * i][j], lin.weight.T), (params[2 * i + 1][j, 0], lin.bias)]
    return pairs


def with_zero_biases(weights: list[th.Tensor], device: th.device | str | None) -> list[th.Tensor]:
    """Stacked layers ``(W, b)``: each weight ``(K, in, out)`` (made on the CPU) and a zero bias
    ``(K, 1, out)``, all leaves requiring grad, moved to ``device`` (:func:`leaves_on`)."""
    params = []
    for w in weights:
        params += [w.requires_grad_(), th.zeros(w.shape[0], 1, w.shape[2], requires_grad=True)]
    return leaves_on(params, device)


class SB3Weights:
    """A stacked network whose agent ``j`` is copied from and into the SB3 policy (or the
    ``nn.Linear`` layers) of one agent, parameter by parameter: :meth:`sb3_pairs`."""

    def sb3_pairs(self, j: int, policy: Any) -> list[tuple[th.Tensor, th.Tensor]]:
        """(our view, the SB3 tensor in our layout: a view of it) of each of agent ``j``'s parameters."""
        raise NotImplementedError

    def load_sb3(self, j: int, policy: Any) -> None:
        """Agent ``j``'s weights from ``policy``."""
        with th.no_grad():
            for ours, theirs in self.sb3_pairs(j, policy):
                ours.copy_(theirs)

    def store_sb3(self, j: int, policy: Any) -> None:
        """Agent ``j``'s weights into ``policy`` (of the same shapes)."""
        with th.no_grad():
            for ours, theirs in self.sb3_pairs(j, policy):
                theirs.copy_(ours)


class StackedMLP(SB3Weights):
    """K copies of an MLP ``obs -> net_arch -> n_out`` (ReLU): layers ``(W (K, in, out),
    b (K, 1, out))``, each agent initialised as ``torch.nn.Linear`` is, from its own generator
    (None: torch's global one), on the CPU, then moved to ``device``."""

    def __init__(
        self,
        k: int,
        sizes: list[int],
        generators: list[th.Generator] | None = None,
        device: th.device | str | None = None,
    ):
        self.params: list[th.Tensor] = []
        for n_in, n_out in zip(sizes[:-1], sizes[1:]):
            w, b = th.empty(k, n_in, n_out), th.empty(k, 1, n_out)
            bound = 1.0 / math.sqrt(n_in)
            for j in range(k):
                g = None if generators is None else generators[j]
                block = th.empty(n_out, n_in)
                th.nn.init.kaiming_uniform_(block, a=math.sqrt(5), generator=g)
                w[j] = block.T
                th.nn.init.uniform_(b[j], -bound, bound, generator=g)
            self.params += [w.requires_grad_(), b.requires_grad_()]
        self.params = leaves_on(self.params, device)

    def forward(self, x: th.Tensor) -> th.Tensor:
        """``x (K, B, in)`` -> ``(K, B, out)``."""
        p = self.params
        n = len(p) // 2
        for i in range(n):
            x = th.baddbmm(p[2 * i + 1], x, p[2 * i])
            if i < n - 1:
                x = th.relu(x)
        return x

    def sb3_pairs(self, j: int, policy: list[th.nn.Linear]) -> list[tuple[th.Tensor, th.Tensor]]:
        """Agent ``j``'s layers and a list of ``nn.Linear`` of the same shapes (e.g. an SB3 ``QNetwork``'s)."""
        return linear_pairs(self.params, j, policy)


class RunningStats:
    """SB3's ``RunningMeanStd`` for K agents at once: ``mean``/``var`` ``(K, *shape)``,
    ``count (K,)``, each agent updated with one sample ``(K, *shape)`` per call."""

    def __init__(self, k: int, shape: tuple[int, ...] = (), epsilon: float = 1e-4):
        self.mean = np.zeros((k, *shape))
        self.var = np.ones((k, *shape))
        self.count = np.full(k, epsilon)

    def update(self, x: np.ndarray) -> None:
        """One sample per agent (SB3's update with a batch of one: batch variance 0)."""
        c = self.count.reshape(-1, *([1] * (self.mean.ndim - 1)))
        delta = x - self.mean
        tot = c + 1.0
        self.mean = self.mean + delta / tot
        self.var = (self.var * c + np.square(delta) * c / tot) / tot
        self.count = self.count + 1.0

    def state_dict(self) -> dict[str, np.ndarray]:
        return {"mean": self.mean, "var": self.var, "count": self.count}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Take over ``state`` (:meth:`state_dict` of statistics of the same shape); ValueError if it does not fit."""
        arrays = {key: np.asarray(state[key], dtype=np.float64) for key in ("mean", "var", "count")}
        if any(arrays[key].shape != getattr(self, key).shape for key in arrays):
            raise ValueError("the checkpoint's running statistics do not fit this batch")
        self.mean, self.var, self.count = arrays["mean"], arrays["var"], arrays["count"]


def load_params(params: list[th.Tensor], saved: list[th.Tensor]) -> None:
    """Copy ``saved`` (a checkpoint's tensors, any device; or the online network's, into its
    target) into ``params`` in place, so that whatever holds ``params`` (an optimiser) goes on
    with them; ValueError if they do not fit."""
    if len(saved) != len(params) or any(tuple(s.shape) != tuple(p.shape) for s, p in zip(saved, params)):
        raise ValueError("the checkpoint's networks do not fit this batch")
    with th.no_grad():
        for p, s in zip(params, saved):
            p.copy_(s)


def clip_grad_norm_per_agent(params: list[th.Tensor], max_norm: float | np.ndarray, k: int | None = None) -> th.Tensor:
    """``torch.nn.utils.clip_grad_norm_`` applied to each agent's own parameters; the K norms
    before clipping. A parameter may stack several networks per agent along its first axis
    (``m * K`` rows: row ``i * K + j`` is agent ``j``'s ``i``-th); ``k`` is K (default: the
    first parameter's rows). ``max_norm``: one for all, or a ``(K,)`` array (inf: no clipping)."""
    k = params[0].shape[0] if k is None else k
    # each row's sum over its own contiguous elements, then over an agent's rows: the same
    # order of additions at every K (a sum over dims (0, 2) at once was blocked by K)
    sq = sum(p.grad.pow(2).reshape(p.shape[0] // k, k, -1).sum(dim=2).sum(dim=0) for p in params)
    norms = sq.sqrt()
    if isinstance(max_norm, np.ndarray):
        max_norm = per_agent(max_norm, norms)  # inf / x = inf -> 1: unclipped
    elif not math.isfinite(max_norm):
        return norms
    # max_norm * (1 / (norm + 1e-6)), as torch's clip_grad_norm_ rounds it (a float over a tensor is
    # a reciprocal times the float), for one max_norm and for a max_norm per agent alike
    coef = ((norms + 1e-6).reciprocal() * max_norm).clamp(max=1.0)
    for p in params:
        p.grad.mul_(coef.repeat(p.shape[0] // k).reshape(-1, *([1] * (p.ndim - 1))))
    return norms


def per_agent(value: float | np.ndarray, like: th.Tensor, ndim: int = 1) -> float | th.Tensor:
    """A setting as an operand of ``like``: a float as it is; a ``(K,)`` array (one value per
    agent) as a tensor of ``like``'s dtype and device, shaped ``(K, 1, ...)`` with ``ndim``
    dimensions to broadcast against ``(K, ...)`` tensors."""
    if not isinstance(value, np.ndarray):
        return value
    return th.as_tensor(value, dtype=like.dtype, device=like.device).reshape(-1, *([1] * (ndim - 1)))


#: the most floats one CPU vector register holds (AVX-512); see :class:`StackedAdam`
VECTOR_FLOATS = 16


class StackedAdam(th.optim.Adam):
    """Adam over stacked parameters, each agent at its own rate, batch-invariant: an agent's
    step is bit for bit the same at every K, in every place of the batch, and alone at one
    float rate or beside agents at other rates.

    Every step is torch's Adam at rate 1, then each row's move scaled by its agent's rate:
    ``p = p0 + rate * (p1 - p0)`` (Adam's move is its rate times a direction that does not
    depend on the rate, so this is a step at that rate up to float rounding; SB3's Adam, to
    which the engine is tested equal within a tolerance). Every agent takes this arithmetic,
    with one rate for all or a rate each: a step at rate 1e-3 taken directly rounds unlike
    one scaled afterwards, and when the batch scaled (a rate per agent, stacked tuning
    trials) while a batch of one stepped directly, the last-bit difference grew through
    Adam's normalised steps to 0.7 % of a weight within one GRU-PPO update on an AMD EPYC
    (docs/batched-engine.md, "Reproducibility").

    torch's fused CPU Adam steps a tensor in whole vectors (8 or 16 floats) and a scalar tail
    that round differently, so an agent's step would depend on where its block falls, that
    is on K: a parameter whose rows per agent are not a multiple of :data:`VECTOR_FLOATS`
    floats (the output biases: 1 to 3 per agent) takes torch's foreach Adam, which rounds
    every element alike; every other parameter fills whole vectors at every K and is fused
    (on this CPU 0.3 ms a step instead of 3.9 ms for K = 35).

    ``rate`` (:attr:`rate`, which a schedule may change between steps): one for all agents, or a
    ``(K,)`` array of per-agent rates (0: no move), the row ``i * K + j`` of a parameter being
    agent ``j``'s; :meth:`step` takes ``active``, a ``(K,)`` bool array (None: all): an inactive
    agent's rate is 0, its weights stay as they are. The state and its ``state_dict`` are torch
    Adam's (its own rate, 1, in the groups)."""

    def __init__(self, params: list[th.Tensor], rate: float | np.ndarray, eps: float):
        fused = [p for p in params if math.prod(p.shape[1:]) % VECTOR_FLOATS == 0]
        rest = [p for p in params if math.prod(p.shape[1:]) % VECTOR_FLOATS != 0]
        groups = [{"params": fused}, {"params": rest, "fused": False, "foreach": True}]
        try:
            super().__init__([g for g in groups if g["params"]], lr=1.0, eps=eps, fused=True)
        except RuntimeError:  # pragma: no cover - torch < 2.4 on CPU
            super().__init__(params, lr=1.0, eps=eps, foreach=True)
        self.rate = rate
        self._before = [th.empty_like(p) for p in params]
        self._params = list(params)

    @th.no_grad()
    def step(self, closure: None = None, active: np.ndarray | None = None) -> None:  # type: ignore[override]
        if closure is not None:
            raise ValueError("StackedAdam takes no closure")
        rates = np.atleast_1d(np.asarray(self.rate, dtype=np.float64))
        if active is not None:
            rates = np.where(active, rates, 0.0)
        for p, p0 in zip(self._params, self._before):
            if p.shape[0] % len(rates):
                raise ValueError(f"a parameter of {p.shape[0]} rows does not stack {len(rates)} agents")
            p0.copy_(p)
        super().step()
        for p, p0 in zip(self._params, self._before):
            p.sub_(p0).mul_(per_agent(np.tile(rates, p.shape[0] // len(rates)), p, p.ndim)).add_(p0)


class AgentMeans:
    """Means of named quantities over the gradient steps of one update (or one day): a
    ``(K,)`` tensor per step (each agent's value) or a float (one for all agents).
    :meth:`add` sums the tensors where they are (on the device, detached, no copy to the
    CPU); :meth:`means` reads every sum back in one transfer."""

    def __init__(self) -> None:
        self._sums: dict[str, th.Tensor | float] = {}
        self._counts: dict[str, int] = {}

    def __bool__(self) -> bool:
        """Whether anything was added since the last :meth:`means`."""
        return bool(self._sums)

    def add(self, **values: th.Tensor | float) -> None:
        for name, v in values.items():
            if isinstance(v, th.Tensor):
                v = v.detach()
                self._sums[name] = v.clone() if name not in self._sums else self._sums[name].add_(v)
            else:
                self._sums[name] = self._sums.get(name, 0.0) + float(v)
            self._counts[name] = self._counts.get(name, 0) + 1

    def means(self) -> dict[str, list[float] | float]:
        """Each quantity's mean since the last call (K floats for a tensor's, one float for a
        float's); the sums are then cleared."""
        stacked = [n for n, v in self._sums.items() if isinstance(v, th.Tensor)]
        out: dict[str, list[float] | float] = {}
        if stacked:
            # on one device (a plug-in's or a stacked setting's values may be CPU tensors
            # beside the network's CUDA ones), then one transfer
            device = self._sums[stacked[0]].device
            rows = th.stack([self._sums[n].to(device, th.float64) / self._counts[n] for n in stacked]).tolist()
            out.update(zip(stacked, rows))
        out.update({n: v / self._counts[n] for n, v in self._sums.items() if not isinstance(v, th.Tensor)})
        self._sums, self._counts = {}, {}
        return out
