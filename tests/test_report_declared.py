"""What a recorded agent declared, and what a comparison knows of its training (issue 75):
a recorded loop's config table lists only the settings it declared (not the plug-in runner's
defaults, ``entry_point None``, ``normalize_obs False``, ``gamma 0.99``); ``compare`` says an
agent with no recorded training days has its training not recorded, never "trained 0 days"."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

import nutribench
from nutribench.cli import app

runner = CliRunner()


def _record(db: Path, name: str, days: int, params: dict | None = None) -> None:
    for seed in (0, 1):
        with nutribench.Recorder(
            db=str(db), name=name, regime="run3", seed=seed, eval_episodes=2, params=params
        ) as rec:
            for _ in range(days):
                rec.env.reset()
                for t in range(50):
                    rec.env.step(int(t < 4))
            rec.evaluate(lambda obs: int(obs[:3].sum() < 1.0))


def test_a_recorded_loops_table_lists_only_what_it_declared(tmp_path: Path):
    from nutribench.report.build import build_table

    db = tmp_path / "lab.db"
    _record(db, "reinforce_loop", 1)
    _record(db, "tuned_loop", 1, params={"lr": 0.01})
    bare = build_table("reinforce_loop", db=db)
    assert list(bare.raw["hyperparameter"]) == ["algo", "name", "version", "description"]
    assert "recorded: trained by its own loop, so only what it declared" in bare.title
    md = bare.to_markdown()
    assert "entry_point" not in md and "normalize_obs" not in md and "gamma" not in md
    with_params = build_table("tuned_loop", db=db)
    assert list(with_params.raw["hyperparameter"]) == ["algo", "name", "version", "description", "params.lr"]
    # a plug-in that nutribench run trains keeps every setting: they apply
    from nutribench.agents.config import parse_agent_config
    from nutribench.report.tables import table_agent_config

    plugin = parse_agent_config(
        {
            "algo": "external",
            "name": "a2c_mine",
            "version": 1,
            "description": "x",
            "entry_point": "my_plugins:make_agent",
        },
        "test",
    )
    rows = list(table_agent_config(7, plugin).raw["hyperparameter"])
    assert {"entry_point", "normalize_obs", "normalize_reward", "gamma"} <= set(rows)


def test_compare_says_training_not_recorded_not_trained_0_days(tmp_path: Path):
    db = tmp_path / "lab.db"
    _record(db, "evaluated", 0)  # a saved model evaluated: no training day recorded with it
    _record(db, "trained", 3)
    res = runner.invoke(app, ["compare", "evaluated", "trained", "--db", str(db)])
    assert res.exit_code == 0, res.output
    assert "0 days" not in res.output, res.output
    assert "evaluated: budget unknown (training not recorded), seeds 0, 1; trained: budget 3 days" in res.output
    assert "budgets differ (evaluated: training not recorded, trained 3 days)" in res.output
