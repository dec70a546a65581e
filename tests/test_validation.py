"""Validation days and the greedy evaluation during training, in both engines."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from nutribench.agents import days
from nutribench.agents.api import eval_food_streams, evaluate, train, validation_food_streams
from nutribench.agents.config import load_agent_config
from nutribench.engine.train import train_batched

REGIMES = [f"run{i}" for i in range(7)]
PAPER_SEEDS = [0, 21, 9, 2003, 1997]


def test_validation_days_are_never_test_days() -> None:
    """Over the shipped regimes and many seeds: no validation day is one of the seed's test
    days (the first 1000, of which a job plays 5), none twice, each a day of food indices."""
    for regime in REGIMES:
        for seed in [*PAPER_SEEDS, *range(40)]:
            val = validation_food_streams(regime, seed, 8)
            test = {d.tobytes() for d in eval_food_streams(regime, seed, days.TEST_DAYS_KEPT_APART).astype(np.int64)}
            assert val.shape == (8, 50) and val.min() >= 0 and val.max() < 10
            assert not test & {d.tobytes() for d in val}
            assert len({d.tobytes() for d in val}) == 8


def test_validation_days_are_drawn_again_where_they_meet_a_test_day(monkeypatch) -> None:
    """By construction, not by luck: with the test days' own salt the stream would give the
    test days themselves; every one is drawn again, and a prefix of n days is the n days."""
    monkeypatch.setattr(days, "VALIDATION_STREAM_SALT", days.EVAL_STREAM_SALT)
    val = validation_food_streams("run3", 7, 6, test_days=5)
    test = eval_food_streams("run3", 7, 5)
    assert not {d.tobytes() for d in test} & {d.tobytes() for d in val}
    assert (val[0] == eval_food_streams("run3", 7, 6)[5]).all()  # the first day not a test day
    assert (validation_food_streams("run3", 7, 2, test_days=5) == val[:2]).all()


def test_validation_days_are_per_seed_and_fixed() -> None:
    a, b = validation_food_streams("run1", 0, 5), validation_food_streams("run1", 1, 5)
    assert not (a == b).all() and (a == validation_food_streams("run1", 0, 5)).all()


def _ddqn():
    """DDQN that updates from its second day on (the shipped one waits 200 days)."""
    return load_agent_config("ddqn").model_copy(update=dict(learning_starts=60, target_update_interval=40))


def _weights(agent) -> dict[str, th.Tensor]:
    return agent.model.policy.state_dict()


def _same_training(a, b) -> None:
    assert a.train_episodes == b.train_episodes
    wa, wb = _weights(a), _weights(b)
    assert wa.keys() == wb.keys() and all(th.equal(wa[k], wb[k]) for k in wa)
    if a.obs_mean is not None:
        assert np.array_equal(a.obs_mean, b.obs_mean) and np.array_equal(a.obs_var, b.obs_var)


def _post_hoc(agent, regime: str, seed: int, n: int) -> list[dict]:
    return evaluate(agent, regime, validation_food_streams(regime, seed, n), record_steps=False).episodes


def _close(during: list[dict], post: list[dict]) -> None:
    assert [r["episode"] for r in during] == [r["episode"] for r in post]
    for d, p in zip(during, post):
        assert d["foods"] == p["foods"]
        assert d["return"] == pytest.approx(p["return"], abs=1e-5)
        assert (d["entropy"] is None) == (p["entropy"] is None)
        if d["entropy"] is not None:
            assert d["entropy"] == pytest.approx(p["entropy"], abs=1e-5)


@pytest.mark.parametrize("algo", ["mc", "ddqn", "gru_ppo", "sac"])
def test_sb3_evaluation_during_training_leaves_training_unchanged(algo: str) -> None:
    """Same training days, weights and statistics with and without the evaluation; the
    evaluation after the last day is a post-hoc evaluation of the returned agent (MC: after
    the update that day's end leads to), and the callback gets every evaluation."""
    cfg = _ddqn() if algo == "ddqn" else algo
    plain = train("run3", cfg, seed=4, episodes=3, diagnostics=False)
    calls = []
    evald = train(
        "run3",
        cfg,
        seed=4,
        episodes=3,
        diagnostics=False,
        eval_every=1,
        val_episodes=2,
        on_validation=lambda j, d, rows: calls.append((j, d, rows)),
    )
    _same_training(plain, evald)
    assert [(j, d) for j, d, _ in calls] == [(0, 1), (0, 2), (0, 3)]
    assert [r["train_day"] for r in evald.validation] == [1, 1, 2, 2, 3, 3]
    last = [{k: v for k, v in r.items() if k != "train_day"} for r in evald.validation if r["train_day"] == 3]
    assert calls[-1][2] == last
    _close(last, _post_hoc(evald, "run3", 4, 2))


@pytest.mark.parametrize("algo", ["mc", "ddqn", "gru_ppo"])
def test_batched_evaluation_during_training_leaves_training_unchanged(algo: str) -> None:
    """All K agents evaluated at once: training unchanged, and the evaluation after the last
    day equals a post-hoc evaluation of each returned agent on its validation days."""
    cfg = _ddqn() if algo == "ddqn" else algo
    jobs = [("run3", 1), ("run0", 2), ("run3", 5)]
    plain = train_batched(jobs, cfg, 3)
    calls = []
    evald = train_batched(jobs, cfg, 3, eval_every=3, val_episodes=2, on_validation=lambda *a: calls.append(a))
    for a, b in zip(plain, evald):
        _same_training(a, b)
    assert sorted((j, d) for j, d, _ in calls) == [(0, 3), (1, 3), (2, 3)]
    for (regime, seed), agent in zip(jobs, evald):
        assert [r["train_day"] for r in agent.validation] == [3, 3]
        _close(agent.validation, _post_hoc(agent, regime, seed, 2))


def test_batched_evaluation_during_training_equals_the_weights_saved_at_that_day() -> None:
    """The evaluation after day 2 of a 4-day run is the post-hoc evaluation of the agent a
    2-day run returns (its weights and statistics at that day: MC's first days do not depend
    on the budget)."""
    jobs = [("run2", 3), ("run5", 8)]
    short = train_batched(jobs, "mc", 2)
    long = train_batched(jobs, "mc", 4, eval_every=2, val_episodes=3)
    for (regime, seed), s, lg in zip(jobs, short, long):
        at_two = [{k: v for k, v in r.items() if k != "train_day"} for r in lg.validation if r["train_day"] == 2]
        _close(at_two, _post_hoc(s, regime, seed, 3))
        assert [r["train_day"] for r in lg.validation] == [2, 2, 2, 4, 4, 4]


class Pruned(Exception):
    pass


def _prune(j: int, day: int, rows: list[dict]) -> None:
    raise Pruned(f"agent {j} at day {day}")


def test_an_exception_in_the_callback_stops_training_in_both_engines() -> None:
    with pytest.raises(Pruned, match="agent 0 at day 1"):
        train("run0", "mc", seed=0, episodes=3, eval_every=1, on_validation=_prune)
    with pytest.raises(Pruned, match="agent 0 at day 2"):
        train_batched([("run0", 0), ("run0", 1)], "mc", 3, eval_every=2, on_validation=_prune)


def test_bad_periods_are_refused() -> None:
    with pytest.raises(ValueError, match="eval_every"):
        train("run0", "mc", seed=0, episodes=1, eval_every=-1)
    with pytest.raises(ValueError, match="val_episodes"):
        train_batched([("run0", 0)], "mc", 1, eval_every=1, val_episodes=0)


def test_a_batch_resumed_from_its_checkpoint_keeps_its_evaluations(tmp_path) -> None:
    """Stopped in day 3 (MC: a checkpoint at each day boundary, the last one holding the
    evaluation of day 1), resumed: the evaluations are those of a run never stopped, each once."""
    from nutribench.engine.checkpoint import Checkpoint

    jobs = [("run3", 1), ("run0", 2)]
    whole = train_batched(jobs, "mc", 4, eval_every=1, val_episodes=2)

    def stop(j: int, row: dict) -> None:
        if row["episode"] == 2 and j == 1:
            raise Pruned("stopped")

    path = tmp_path / "c.pt"
    every = dict(eval_every=1, val_episodes=2)
    with pytest.raises(Pruned):
        train_batched(jobs, "mc", 4, on_episode=stop, checkpoint=Checkpoint(path, every_seconds=0), **every)
    calls = []
    resumed = train_batched(
        jobs, "mc", 4, checkpoint=Checkpoint(path, every_seconds=0), on_validation=lambda *a: calls.append(a), **every
    )
    assert sorted({d for _, d, _ in calls}) == [2, 3, 4]  # day 1's came back from the checkpoint
    for a, b in zip(whole, resumed):
        assert [r["train_day"] for r in b.validation] == [1, 1, 2, 2, 3, 3, 4, 4]
        assert a.validation == b.validation
