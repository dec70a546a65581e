"""The recorder and ``nutribench evaluate`` at their edges (issue 39): actions that are not 0 or
1 refused, not coerced; seeds that are not integers refused, not truncated; the recorder used
outside its with block; and a failed recording leaves no database file behind."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from nutribench.errors import UserError
from tests.conftest import one_error_line

POLICIES = """
import numpy as np

class Predictor:
    def __init__(self, action):
        self.action = action

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.full(len(obs), self.action), None

def two(path):
    return lambda obs: 2

def most(path):
    return lambda obs: 0.9

def text(path):
    return lambda obs: "1"

def raises(path):
    def policy(obs):
        raise RuntimeError("boom")
    return policy

def predicts_1_9(path):
    return Predictor(1.9)

def predicts_1_0(path):
    return Predictor(1.0)
"""


@pytest.fixture
def policies(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "edge_policies.py").write_text(POLICIES)
    (tmp_path / "model.bin").write_bytes(b"")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    yield tmp_path
    sys.modules.pop("edge_policies", None)


def evaluate(loader: str, db: str = "lab.db"):
    args = ["evaluate", "--model", "model.bin", "--entry-point", f"edge_policies:{loader}", "--name", "a"]
    return CliRunner().invoke(app, [*args, "--eval-episodes", "1", "--db", db])


@pytest.mark.parametrize(
    ("loader", "shown"),
    [("two", "returned 2:"), ("most", "returned 0.9:"), ("text", "returned '1':"), ("predicts_1_9", "returned 1.9:")],
)
def test_evaluate_refuses_an_action_that_is_not_0_or_1_and_leaves_no_database(policies, loader, shown):
    """A policy returning 2 was a ValueError traceback; 0.9 and "1" were stored as 0 and 1. Each
    left a database file behind (the recorder created it before playing)."""
    line = one_error_line(evaluate(loader))
    assert f"at step 1 the policy {shown} an action is 0 (skip) or 1 (eat), an integer" in line, line
    assert not (policies / "lab.db").exists()


def test_evaluate_of_a_policy_that_raises_is_one_line_and_leaves_no_database(policies):
    line = one_error_line(evaluate("raises"))
    assert "the policy raised at step 1: RuntimeError: boom" in line, line
    assert not (policies / "lab.db").exists()


def test_evaluate_takes_a_float_action_that_is_an_integer(policies):
    """1.0 is an action, as the environment takes it: the check refuses values, not types."""
    res = evaluate("predicts_1_0")
    assert res.exit_code == 0, res.output
    assert "50.0 foods a day" in res.output


def test_evaluate_refuses_an_in_memory_database(policies):
    line = one_error_line(evaluate("predicts_1_0", db="sqlite://"))
    assert "in-memory SQLite database is lost" in line, line


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seed": 1.7}, "Recorder(seed=1.7): seed is an integer"),
        ({"seed": "1"}, "Recorder(seed='1'): seed is an integer"),
        ({"seed": True}, "Recorder(seed=True): seed is an integer"),
        ({"seed": -1}, "Recorder(seed=-1): seed goes from 0 to 2147483647"),
        ({"seed": 2**31}, "seed goes from 0 to 2147483647"),
        ({"eval_episodes": 2.0}, "eval_episodes is an integer"),
        ({"eval_episodes": 0}, "eval_episodes goes from 1"),
        ({"db": "sqlite://"}, "in-memory SQLite database is lost"),
    ],
)
def test_recorder_refuses_what_it_would_store_otherwise(tmp_path, kwargs, message):
    """``Recorder(seed=1.7)`` was stored as seed 1."""
    with pytest.raises(UserError) as info:
        with nutribench.Recorder(**{"db": tmp_path / "lab.db", **kwargs}, name="a", regime="run0") as rec:
            rec.evaluate(lambda obs: 0)
    assert message in str(info.value)
    assert not (tmp_path / "lab.db").exists()


def test_recorder_takes_a_numpy_integer_seed(tmp_path):
    with nutribench.Recorder(tmp_path / "lab.db", name="a", regime="run0", seed=np.int64(3), eval_episodes=1) as rec:
        rec.evaluate(lambda obs: 0)
    assert rec.seed == 3 and (tmp_path / "lab.db").is_file()


@pytest.mark.parametrize("action", [0.9, 1.9, "1", 2, None])
def test_recorder_evaluate_refuses_non_integer_actions(tmp_path, action):
    with pytest.raises(UserError, match="an action is 0 \\(skip\\) or 1 \\(eat\\)"):
        with nutribench.Recorder(tmp_path / "lab.db", name="a", regime="run0", eval_episodes=1) as rec:
            rec.evaluate(lambda obs: action)
    assert not (tmp_path / "lab.db").exists()


@pytest.mark.parametrize("use", ["env", "evaluate", "save"])
def test_recorder_without_with_is_a_clear_error(tmp_path, use):
    """``rec.save()`` outside the with block was an AttributeError (``_started``)."""
    rec = nutribench.Recorder(tmp_path / "lab.db", name="a", regime="run0")
    call = {"env": lambda: rec.env, "evaluate": lambda: rec.evaluate(lambda o: 0), "save": rec.save}[use]
    with pytest.raises(UserError, match=rf"Recorder\.{use}: use the recorder in a with block"):
        call()
    assert not (tmp_path / "lab.db").exists()


def test_a_failed_recording_on_an_existing_database_changes_nothing(tmp_path):
    db = tmp_path / "lab.db"
    with nutribench.Recorder(db, name="a", regime="run0", eval_episodes=1) as rec:
        rec.evaluate(lambda obs: 0)
    before = db.read_bytes()
    with pytest.raises(UserError):
        with nutribench.Recorder(db, name="b", regime="run0", eval_episodes=1) as rec:
            rec.evaluate(lambda obs: 2)
    assert db.read_bytes() == before


@pytest.mark.parametrize("action", [0.9, 1.9, "1", 2, 0.5])
def test_the_recorder_s_env_refuses_non_integer_actions_and_records_no_day(tmp_path, action):
    """The training env of the recorder is the NutriRL env: a bad action raises its ValueError
    (the Gymnasium contract) before the step counts, so the day is played on; 1.0 is an action."""
    with nutribench.Recorder(tmp_path / "lab.db", name="a", regime="run0", eval_episodes=1) as rec:
        rec.env.reset()
        with pytest.raises(ValueError, match="action must be 0 \\(skip\\) or 1 \\(eat\\)"):
            rec.env.step(action)
        for _ in range(50):
            rec.env.step(1.0)
        rec.evaluate(lambda obs: 0)
    assert [day["foods"] for day in rec.env.days] == [50]  # the refused step ate nothing, took no step
    assert nutribench.store.read_jobs(tmp_path / "lab.db").loc[0, "episodes"] == 1


def test_policies_returning_numpy_or_torch_scalars_are_still_taken():
    """The check refuses values, not containers: what ``int(policy(obs))`` took before (a numpy
    scalar, a 0-d or one-element array or tensor) is still an action."""
    import torch

    from nutribench.recorder import PolicyAgent, RecorderError

    agent = PolicyAgent(lambda obs: 0)
    for actions in (
        [np.array(1), np.array(0)],
        [np.array([1]), np.int64(0)],
        [torch.tensor(1), torch.tensor([0.0])],
        [True, 0.0],
        np.array([[1], [0]]),
    ):
        assert agent.check_actions(actions, 2).tolist() == [1, 0]
    for actions in ([np.array([1, 0]), 0], [torch.tensor(1.9), 0], [float("nan"), 1], [1]):
        with pytest.raises(RecorderError):
            agent.check_actions(actions, 2)
