"""The two references above the planner (issue 73): lookahead and clairvoyant, the model they
plan on, the exact search against brute force, and ``nutribench baselines`` printing them."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from typer.testing import CliRunner

from nutribench.agents.days import eval_food_streams
from nutribench.baselines import play_simple_policy, play_strong_policy
from nutribench.cli import app
from nutribench.config import load_env_config
from nutribench.env import NutriRLVectorEnv
from nutribench.env.metrics import play
from nutribench.env.policies import DayModel, clairvoyant_actions, lookahead_actions


def _returns(regime, foods, actions):
    class Replay:
        def __call__(self, env):
            return actions[:, env.steps_taken]

    env = NutriRLVectorEnv(len(foods), regime=regime)
    return np.array([r["return"] for r in play(env, Replay(), episodes=len(foods), foods=foods)])


def _model_returns(model, foods, actions):
    """The returns of the days ``foods`` (n, H) played with ``actions`` (n, H) on the model."""
    nodes = model.start(len(foods))
    for t in range(model.horizon):
        nodes, _ = model.step(nodes, t, foods[:, t], actions[:, t].astype(bool))
    return nodes.ret


@pytest.mark.parametrize("regime", ["run0", "run3", "run6"])
def test_the_model_steps_as_the_env_does(regime):
    foods = eval_food_streams(regime, 0, 4)
    actions = np.random.default_rng(1).integers(0, 2, size=foods.shape)
    actions[0] = 0
    model = DayModel(regime)
    assert _model_returns(model, foods, actions) == pytest.approx(_returns(regime, foods, actions), abs=1e-9)
    # the model's planner is the env's planner, step for step
    nodes = model.start(len(foods))
    ate = np.zeros(foods.shape, dtype=np.int64)
    for t in range(model.horizon):
        a = model.planner(nodes, t, foods[:, t])
        ate[:, t] = a
        nodes, _ = model.step(nodes, t, foods[:, t], a)
    planner = [r["return"] for r in play_simple_policy("planner", regime, foods)]
    assert nodes.ret == pytest.approx(planner, abs=1e-9)
    assert _returns(regime, foods, ate) == pytest.approx(planner, abs=1e-9)


def _short(regime: str, horizon: int):
    cfg = load_env_config(regime)
    return dataclasses.replace(cfg, reward=cfg.reward.model_copy(update={"horizon": horizon}))


@pytest.mark.parametrize(("regime", "horizon", "kinds"), [("run0", 12, 3), ("run1", 12, 4), ("run3", 11, 10)])
def test_the_exact_search_equals_brute_force_on_a_short_day(regime, horizon, kinds):
    """Every one of the 2^H days of decisions played: the clairvoyant search, exact on each
    day, finds the best of them (also from a beam of one node, so the proof does the work)."""
    cfg = _short(regime, horizon)
    model = DayModel(cfg)
    every = np.array(list(itertools.product((0, 1), repeat=horizon)), dtype=np.int64)
    days = np.random.default_rng(horizon).integers(0, kinds, size=(4, horizon))
    for width in (1, 64):
        actions, how = clairvoyant_actions(model, days, width=width)
        assert how == ["exact"] * len(days)
        found = _returns(cfg, days, actions)
        for day, got in zip(days, found):
            brute = _model_returns(model, np.broadcast_to(day, every.shape), every)
            assert got == pytest.approx(brute.max(), abs=1e-9)


def test_a_day_the_proof_cannot_hold_is_the_beams_and_says_so():
    cfg = _short("run0", 12)
    days = np.random.default_rng(12).integers(0, 3, size=(4, 12))
    actions, how = clairvoyant_actions(cfg, days, width=4, max_nodes=1)
    assert "beam" in how
    exact, _ = clairvoyant_actions(cfg, days, width=4)
    assert np.all(_returns(cfg, days, actions) <= _returns(cfg, days, exact) + 1e-9)


def test_lookahead_is_seeded_and_a_day_does_not_depend_on_its_neighbours():
    foods = eval_food_streams("run3", 21, 3)
    model = DayModel("run3")
    a = lookahead_actions(model, foods, samples=16, seed=5)
    assert np.array_equal(a, lookahead_actions(model, foods, samples=16, seed=5))
    assert np.array_equal(a[1:2], lookahead_actions(model, foods[1:2], samples=16, seed=5))


def test_strong_policies_beat_the_planner_on_a_few_days():
    foods = eval_food_streams("run2", 9, 4)
    planner = np.mean([r["return"] for r in play_simple_policy("planner", "run2", foods)])
    look = play_strong_policy("lookahead", "run2", foods, samples=32)
    clair = play_strong_policy("clairvoyant", "run2", foods)
    assert {r["search"] for r in look} == {"sampled"}
    assert np.mean([r["return"] for r in clair]) >= np.mean([r["return"] for r in look]) > planner
    with pytest.raises(ValueError, match="known ones"):
        play_strong_policy("oracle", "run2", foods)


def test_baselines_cli_prints_lookahead_and_clairvoyant(tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "baselines",
            "--regimes",
            "run1",
            "--eval-episodes",
            "6",
            "--strong-days",
            "2",
            "--samples",
            "8",
            "--markdown",
        ],
    )
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 2 + 6
    assert lines[-2].startswith("| run1 | lookahead | 2 |") and "8 futures" in lines[-2]
    assert lines[-1].startswith("| run1 | clairvoyant | 2 |") and "exact" in lines[-1]
    assert "| 100.0 % |" in lines[5] and "| 0.0 % |" in lines[3]
    bad = CliRunner().invoke(app, ["baselines", "--out", str(tmp_path / "x.csv")])
    assert bad.exit_code == 2 and "--test-days" in bad.output
