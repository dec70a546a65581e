"""Equal knobs between search spaces (docs/tuning.md, "The protocol", version 2): a
hyperparameter two agents share is searched over the same range in both spaces, or each space
that does not search it says why in its ``[kept]`` table.

Which knobs are shared, by their name in each agent's config, is :data:`SHARED_KNOBS`. Two
knobs with one field name but another role are kept apart there and say why: PPO's minibatch
is a slice of a 500-step rollout reused every epoch, DDQN's and SAC's a fresh draw from a
replay of up to 1e5 transitions at every gradient step; PPO's, GRU-PPO's and MC's gradient clip
bounds an actor-critic loss's gradient, DDQN's a Huber TD loss's; SAC's temperature ``alpha``
weighs an entropy inside its soft values, not a bonus on a surrogate as ``ent_coef`` does.
"""

from __future__ import annotations

from dataclasses import dataclass

from nutribench.tuning.space import SearchSpace

#: knob -> the config fields that are it, per agent (an agent whose config lacks every field
#: named for it does not have the knob)
SHARED_KNOBS: dict[str, dict[str, tuple[str, ...]]] = {
    "learning rate": {
        "ppo": ("learning_rate",),
        "gru_ppo": ("learning_rate",),
        "mc": ("learning_rate",),
        "ddqn": ("learning_rate_start",),
        "sac": ("actor_learning_rate", "critic_learning_rate"),
    },
    "discount": {a: ("gamma",) for a in ("ppo", "gru_ppo", "mc", "ddqn", "sac")},
    "GAE lambda": {a: ("gae_lambda",) for a in ("ppo", "gru_ppo", "mc")},
    "clip range": {a: ("clip_range",) for a in ("ppo", "gru_ppo")},
    "epochs": {a: ("n_epochs",) for a in ("ppo", "gru_ppo")},
    "entropy coefficient": {a: ("ent_coef",) for a in ("ppo", "gru_ppo", "mc")},
    "value coefficient": {a: ("vf_coef",) for a in ("ppo", "gru_ppo", "mc")},
    "gradient clip (actor-critic)": {a: ("max_grad_norm",) for a in ("ppo", "gru_ppo", "mc")},
    "rollout length": {a: ("n_steps",) for a in ("ppo", "gru_ppo")},
    "minibatch (on-policy, transitions)": {a: ("batch_size",) for a in ("ppo", "gru_ppo")},
    "minibatch (replay, transitions)": {a: ("batch_size",) for a in ("ddqn", "sac")},
}


@dataclass(frozen=True)
class Breach:
    """One knob two spaces treat unequally, in words."""

    knob: str
    detail: str

    def __str__(self) -> str:
        return f"{self.knob}: {self.detail}"


def _range(space: SearchSpace, field: str) -> tuple | None:
    """A searched field's range without its ``why`` (None: not searched)."""
    p = space.params.get(field)
    if p is None:
        return None
    return (p.kind, p.low, p.high, p.log, tuple(map(str, p.choices)) if p.choices else None)


def parity_breaches(spaces: dict[str, SearchSpace]) -> list[Breach]:
    """Every shared knob (:data:`SHARED_KNOBS`) that the ``spaces`` (agent -> its space) search
    over unequal ranges, or that a space neither searches nor explains in ``[kept]``."""
    breaches = []
    for knob, fields_of in SHARED_KNOBS.items():
        ranges: dict[str, tuple] = {}
        for agent, fields in fields_of.items():
            space = spaces.get(agent)
            if space is None:
                continue
            for field in fields:
                r = _range(space, field)
                if r is not None:
                    ranges[f"{space.name}.{field}"] = r
                elif field not in space.kept:
                    breaches.append(Breach(knob, f"{space.name} neither searches {field} nor says why in [kept]"))
        if len(set(ranges.values())) > 1:
            shown = "; ".join(f"{where} {r}" for where, r in sorted(ranges.items()))
            breaches.append(Breach(knob, f"searched over unequal ranges: {shown}"))
    return breaches
