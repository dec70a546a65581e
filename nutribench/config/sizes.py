"""How large a config's sizes may be: bounds derived from what each size makes the program hold.

A size that passes validation must be one the program could hold; one it never could (a
horizon of 10^12 steps, a network of three layers of 10^6 units, a rollout of 10^12 steps)
is refused when its file is read, in one line naming the file and the field, rather than
after minutes as a ``MemoryError`` of a job. Each bound is derived, not guessed, one of two ways:

* from a column the size is stored in: a step number (an evaluation step's ``step``, an
  episode's ``first_overshoot_step``, an update's ``timestep``, which a rollout of ``n_steps``
  steps reaches at its first update) is an INTEGER column everywhere (PostgreSQL's:
  ``2**31 - 1``), :data:`MAX_STEPS`;
* from memory arithmetic: the bytes that a size makes the program allocate *at least*
  (bytes per element x elements, counted from the arrays the code allocates, each a lower
  bound: the real use is larger) against :data:`MEMORY_CEILING`, 1 TiB, more memory than any one
  machine nutribench runs on (the largest it is run on has 128 GiB, and a GPU of 141 GB). A size over its
  bound could never be held anywhere; one under it may still not fit a smaller machine, where
  it fails at its allocation, as any program's does.

The arithmetic, per config field (float32 = 4 bytes, float64 and int64 = 8):

* the regime's dynamics (:class:`nutribench.env.nutri_env.RegimeDynamics`, built by every
  environment), for N foods and a horizon of H steps: the absorption schedule and its
  arrivals by horizon, ``N x H x 3`` float64 each (48 N H bytes), and one observation template
  row per food offered and one for none, ``(N + 1) x width`` float32, where the observation's
  width is ``3 + N`` at level 1, plus 1, 3 and ``3 (H - 1) + 3`` for the rungs above
  (:func:`dynamics_bytes`). With H = 1 it bounds the catalog alone: :data:`MAX_FOODS` foods;
* a feed-forward network of hidden widths ``w_1 .. w_L`` (``net_arch``): its weights and
  biases from an input of at least 4 floats (3 nutrients and one food) through the hidden
  layers to a head of at least 2 outputs, float32, four copies while it trains (the weights,
  their gradients and Adam's two moments: 16 bytes a parameter); every layer's two tensors
  in their four copies are eight allocations of at least 64 bytes (the allocators' alignment),
  so a network's depth counts as well as its widths (:func:`network_bytes`);
* the recurrent policy's two GRUs of ``hidden_size`` h: three gates of at least ``h x h``
  weights each, ``6 h^2`` parameters, 16 bytes each (:data:`MAX_HIDDEN`);
* a rollout of ``n_steps`` (SB3's ``RolloutBuffer``): per step an observation of at least 4
  float32 and the action, reward, return, episode start, value, log-probability and advantage,
  44 bytes, and the recurrent buffer's two hidden states, ``8 h`` bytes (:func:`rollout_bytes`);
* a replay buffer of ``buffer_size`` transitions (SB3's ``ReplayBuffer``): per transition an
  observation and the next, at least 4 float32 each, an int64 action and float32 reward, done
  and time-out: 52 bytes (:data:`REPLAY_BYTES`); a sampled batch of ``batch_size`` copies as
  much, and DDQN's n-step returns gather ``batch_size x n_step`` int64 indices and float32
  rewards, dones, time-outs and discounted rewards, 24 bytes each (:func:`n_step_bytes`).
"""

from __future__ import annotations

from collections.abc import Sequence
from math import isqrt

from pydantic import AfterValidator

#: The memory no machine nutribench runs on has: a size needing more can never run (1 TiB).
MEMORY_CEILING = 1 << 40

#: The largest step number: a step is stored in an INTEGER column (PostgreSQL's, the narrowest).
MAX_STEPS = 2**31 - 1

#: Bytes a replay buffer holds per transition, at least (see the module's docstring).
REPLAY_BYTES = 2 * 4 * 4 + 8 + 3 * 4


def dynamics_bytes(n_foods: int, horizon: int, level: int = 1) -> int:
    """Bytes a regime's dynamics hold at least: ``N x H x 3`` float64 twice and ``N + 1``
    observation rows of float32, each as wide as the observation at ``level`` of the ladder
    (the env's layout)."""
    rungs = (1, 3, 3 * (horizon - 1) + 3)  # the floats levels 2, 3 and 4 add to level 1's 3 + N
    width = 3 + n_foods + sum(rungs[: max(level - 1, 0)])
    return 48 * n_foods * horizon + 4 * (n_foods + 1) * width


#: The most foods a catalog may have: their dynamics alone, with a horizon of one step, within
#: the ceiling (``4 N^2 + 64 N + 12 = (2 N + 16)^2 - 244`` bytes: 524,280 foods).
MAX_FOODS = (isqrt(MEMORY_CEILING + 244) - 16) // 2


def _tensor_bytes(numel: int) -> int:
    """Bytes of one float32 tensor of ``numel`` elements: at least 64 (the allocation's alignment)."""
    return max(64, -(-4 * numel // 64) * 64)


def network_bytes(widths: Sequence[int]) -> int:
    """Bytes training a feed-forward network of hidden ``widths`` holds at least: each layer's
    weights and biases (from 4 inputs to 2 outputs) in four copies (see the module's docstring)."""
    dims = [4, *widths, 2]
    return sum(4 * (_tensor_bytes(a * b) + _tensor_bytes(b)) for a, b in zip(dims, dims[1:]))


def rollout_bytes(n_steps: int, hidden_size: int = 0) -> int:
    """Bytes a rollout of ``n_steps`` holds at least: 44 per step, and ``8 h`` more for a GRU's states."""
    return n_steps * (44 + 8 * hidden_size)


def n_step_bytes(batch_size: int, n_step: int) -> int:
    """Bytes DDQN's n-step returns of a batch gather at least: 24 per sample and step."""
    return 24 * batch_size * n_step


#: The most hidden units of the recurrent policy's GRUs: their ``6 h^2`` parameters, 16 bytes each
#: (``96 h^2`` bytes), within the ceiling.
MAX_HIDDEN = isqrt(MEMORY_CEILING // 96)
#: The most transitions a replay buffer (or a sampled batch) may hold within the ceiling.
MAX_REPLAY = MEMORY_CEILING // REPLAY_BYTES


def size(n: float) -> str:
    """``n`` bytes in words: ``47.3 TiB``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024


def too_large(what: str, need: int) -> str | None:
    """A refusal's words when ``need`` bytes exceed :data:`MEMORY_CEILING`, else None."""
    if need <= MEMORY_CEILING:
        return None
    return (
        f"{what} would need at least {size(need)} of memory, more than any machine has "
        f"(the bound: {size(MEMORY_CEILING)}, nutribench.config.sizes): give a smaller size"
    )


def at_most(bound: int, why: str) -> AfterValidator:
    """A field's validator: a value above ``bound`` is refused with ``why`` (what the bound is)."""

    def check(value: int) -> int:
        if value > bound:
            raise ValueError(f"{value:,} is more than {bound:,}, {why}: give a smaller one")
        return value

    return AfterValidator(check)


#: ``horizon``, ``n_steps``: a step number is stored in an INTEGER column
STEPS_BOUND = at_most(MAX_STEPS, "the largest step number the database's INTEGER columns hold")
#: ``buffer_size``, ``batch_size``: transitions held at once
TRANSITIONS_BOUND = at_most(
    MAX_REPLAY,
    f"the most transitions {REPLAY_BYTES} bytes each fit in {size(MEMORY_CEILING)} (nutribench.config.sizes)",
)
#: ``hidden_size``: two GRUs' weights
HIDDEN_BOUND = at_most(
    MAX_HIDDEN, f"the most hidden units whose two GRUs train in {size(MEMORY_CEILING)} (nutribench.config.sizes)"
)
