"""Equal knobs between search spaces (docs/tuning.md, "Protocol v2"): a hyperparameter two
agents share is searched over the same range in both spaces, or each space that does not
search it says why in its ``[kept]`` table.

Which knobs are shared, by their field names in each agent's config, is data:
``regimes/shared_knobs.toml`` (:func:`shared_knobs`), which also says why two knobs with one
field name but another role (an on-policy and a replay minibatch) are kept apart.
"""

from __future__ import annotations

from dataclasses import dataclass

from nutribench.config.loading import read_toml, regimes_dir
from nutribench.tuning.space import SearchSpace


def shared_knobs() -> dict[str, dict[str, tuple[str, ...]]]:
    """knob -> agent -> the config fields that are that knob (``regimes/shared_knobs.toml``)."""
    data = read_toml(regimes_dir() / "shared_knobs.toml")
    return {knob: {agent: tuple(fields) for agent, fields in of.items()} for knob, of in data["knobs"].items()}


@dataclass(frozen=True)
class Breach:
    """One knob two spaces treat unequally, in words."""

    knob: str
    detail: str

    def __str__(self) -> str:
        return f"{self.knob}: {self.detail}"


def parity_breaches(spaces: dict[str, SearchSpace]) -> list[Breach]:
    """Every shared knob (:func:`shared_knobs`) that the ``spaces`` (agent -> its space) search
    over unequal ranges, or that a space neither searches nor explains in ``[kept]``."""
    breaches = []
    for knob, fields_of in shared_knobs().items():
        ranges: dict[str, tuple] = {}
        for agent, fields in fields_of.items():
            space = spaces.get(agent)
            if space is None:
                continue
            for field in fields:
                p = space.params.get(field)
                if p is not None:  # its range without its ``why``
                    choices = p.choices and tuple(map(str, p.choices))
                    ranges[f"{space.name}.{field}"] = (p.kind, p.low, p.high, p.log, choices)
                elif field not in space.kept:
                    breaches.append(Breach(knob, f"{space.name} neither searches {field} nor says why in [kept]"))
        if len(set(ranges.values())) > 1:
            shown = "; ".join(f"{where} {r}" for where, r in sorted(ranges.items()))
            breaches.append(Breach(knob, f"searched over unequal ranges: {shown}"))
    return breaches
