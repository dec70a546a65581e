"""Protocol v2's parity of shared knobs (docs/tuning.md): the v2 search spaces search every
knob two agents share over one range, or say why not; version 1's PPO/GRU-PPO pair did not
(PPO searched the minibatch, GRU-PPO kept it at 250 without a word).

The rule, checked here: a hyperparameter two agents share is searched over the same range in
both spaces, or each space that does not search it says why in its ``[kept]`` table. Which
knobs are shared, by their field names in each agent's config, is data:
``regimes/shared_knobs.toml`` (:func:`shared_knobs`), which also says why two knobs with one
field name but another role (an on-policy and a replay minibatch) are kept apart."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from nutribench.config.loading import ConfigError, read_toml, regimes_dir
from nutribench.tuning.space import SearchSpace, check_space, load_search_space

AGENTS = ("ppo", "gru_ppo", "mc", "ddqn", "sac")


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


def spaces(suffix: str) -> dict[str, SearchSpace]:
    return {a: load_search_space(a + suffix) for a in AGENTS}


def test_the_v2_spaces_search_every_shared_knob_alike() -> None:
    assert parity_breaches(spaces("_v2")) == []


def test_the_v1_pair_ppo_gru_ppo_breaks_the_rule() -> None:
    v1 = {a: load_search_space(a) for a in ("ppo", "gru_ppo")}
    assert [str(b) for b in parity_breaches(v1)] == [
        "rollout length: ppo neither searches n_steps nor says why in [kept]",
        "rollout length: gru_ppo neither searches n_steps nor says why in [kept]",
        "minibatch (on-policy, transitions): gru_ppo neither searches batch_size nor says why in [kept]",
    ]


def test_a_range_that_differs_is_a_breach() -> None:
    v2 = spaces("_v2")
    lr = v2["ppo"].params["learning_rate"].model_copy(update={"high": 2e-3})
    v2["ppo"] = v2["ppo"].model_copy(update={"params": {**v2["ppo"].params, "learning_rate": lr}})
    (breach,) = parity_breaches(v2)
    assert breach.knob == "learning rate" and "ppo_v2.learning_rate" in breach.detail


def test_every_shared_field_is_a_field_of_its_agent() -> None:
    """The table names real config fields (a typo would make a knob silently unshared)."""
    from nutribench.agents.config import load_agent_config

    for knob, fields_of in shared_knobs().items():
        for agent, fields in fields_of.items():
            model = type(load_agent_config(agent))
            assert set(fields) <= set(model.model_fields), (knob, agent, fields)


def test_kept_must_name_an_unsearched_hyperparameter() -> None:
    space = load_search_space("ppo_v2")
    with pytest.raises(ConfigError, match="kept.hidden_size: not a hyperparameter"):
        check_space(space.model_copy(update={"kept": {"hidden_size": "x"}}), "ppo_v2.toml")
    with pytest.raises(ConfigError, match="it is searched in"):
        check_space(space.model_copy(update={"kept": {"gamma": "x"}}), "ppo_v2.toml")
