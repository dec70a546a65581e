"""A model trained elsewhere and brought in with ``nutribench evaluate``: its budget is the
training days its sidecar records (what ``TrainedAgent.save`` writes beside the model), so
``compare`` and the leaderboard show how long it was trained; "training not recorded" only
where no sidecar says, never "trained 0 days"."""

from __future__ import annotations

import csv
import io
import json
import shutil
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from nutribench.store import read_episode_metrics, read_jobs

runner = CliRunner()

LOADERS = """\
from stable_baselines3 import DQN

from nutribench.agents.api import TrainedAgent


def sidecar(path):
    agent = TrainedAgent.load(path)
    return lambda obs: int(agent.act(obs[None])[0][0])


def plain(path):
    return DQN.load(path, device="cpu")
"""


@pytest.fixture
def loaders(tmp_path: Path):
    (tmp_path / "budget_loaders.py").write_text(LOADERS)
    sys.path.insert(0, str(tmp_path))
    yield
    sys.path.remove(str(tmp_path))
    sys.modules.pop("budget_loaders", None)


def _evaluate(model: Path, loader: str, name: str, db: Path):
    return runner.invoke(
        app,
        [
            "evaluate",
            "--model",
            str(model),
            "--entry-point",
            f"budget_loaders:{loader}",
            "--name",
            name,
            "--db",
            str(db),
        ],
    )


def test_an_evaluated_model_has_its_sidecars_training_days_as_budget(tmp_path: Path, loaders):
    model = tmp_path / "m.zip"
    res = runner.invoke(
        app,
        ["train", "--algo", "ddqn", "--regime", "run0", "--days", "2", "--eval-episodes", "1", "--save", str(model)],
    )
    assert res.exit_code == 0, res.output
    assert json.loads(model.with_suffix(".json").read_text())["provenance"]["episodes"] == 2
    bare = tmp_path / "bare" / "m.zip"  # the same model without its sidecar: nothing says how long it trained
    bare.parent.mkdir()
    shutil.copyfile(model, bare)

    db = tmp_path / "fresh.db"
    res = _evaluate(model, "sidecar", "mine", db)
    assert res.exit_code == 0, res.output
    assert "trained 2 days (its sidecar)" in " ".join(res.output.split())
    res = _evaluate(bare, "plain", "bare", db)
    assert res.exit_code == 0, res.output
    assert "training not recorded" in " ".join(res.output.split())

    jobs = read_jobs(db).set_index("algo")
    assert jobs.loc["mine", "episodes"] == 2 and jobs.loc["bare", "episodes"] == 0
    assert (read_episode_metrics(db)["phase"] == "eval").all()  # no training rows: the days were played elsewhere

    res = runner.invoke(app, ["compare", "mine", "bare", "--db", str(db)])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "mine: budget 2 days" in text and "bare: budget unknown (training not recorded)" in text
    assert "budgets differ (mine trained 2 days, bare: training not recorded)" in text
    assert "trained 0 days" not in text

    res = runner.invoke(app, ["leaderboard", "--db", str(db), "--format", "csv"])
    assert res.exit_code == 0, res.output
    rows = {r["algo"]: r for r in csv.DictReader(io.StringIO(res.stdout))}
    assert rows["mine"]["budget"] == "2" and rows["bare"]["budget"] == "0"
    assert rows["mine"]["flags"].startswith("budget 2 days (reference 5000)")
    assert rows["bare"]["flags"].startswith("training not recorded (reference 5000 days)")

    # the budget travels through an archive: export checks it, import keeps it
    archive = tmp_path / "lab.npz"
    assert runner.invoke(app, ["db", "export", str(archive), "--db", str(db)]).exit_code == 0
    again = tmp_path / "again.db"
    res = runner.invoke(app, ["db", "import", str(archive), "--db", str(again)])
    assert res.exit_code == 0, res.output
    assert read_jobs(again).set_index("algo").loc["mine", "episodes"] == 2

    # a sidecar whose training days are no number of days: one line, nothing written
    side = json.loads(model.with_suffix(".json").read_text())
    side["provenance"]["episodes"] = "many"
    model.with_suffix(".json").write_text(json.dumps(side))
    other = tmp_path / "other.db"
    res = _evaluate(model, "sidecar", "forged", other)
    assert res.exit_code == 2 and "provenance episodes 'many' is not a number of training days" in res.output
    assert len(res.output.strip().splitlines()) == 1 and not other.exists()


def test_the_recorder_takes_trained_days_or_played_days_not_both(tmp_path: Path):
    db = tmp_path / "lab.db"
    with pytest.raises(nutribench.errors.UserError, match="trained_days=3 and 1 training days played"):
        with nutribench.Recorder(db=db, name="both", regime="run0", trained_days=3, eval_episodes=1) as rec:
            rec.env.reset()
            for _ in range(50):
                rec.env.step(0)
            rec.evaluate(lambda obs: 0)
    assert not db.exists()
    for bad in (-1, True, 2.5):
        with pytest.raises(nutribench.errors.UserError, match="trained_days"):
            nutribench.Recorder(db=db, name="bad", trained_days=bad)
    with nutribench.Recorder(db=db, name="elsewhere", regime="run0", trained_days=3, eval_episodes=1) as rec:
        rec.evaluate(lambda obs: 0)
    assert read_jobs(db).loc[0, "episodes"] == 3
