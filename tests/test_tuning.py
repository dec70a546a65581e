"""``nutribench tune`` training for real, at a tiny budget: the objective is the share of the
never -> planner gap on validation days (never the test days), the best trial becomes a new
agent file, plug-ins tune through their ``[params]``, and a study killed with -9 resumes
without losing or double-counting a trial."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import optuna
import pytest
from typer.testing import CliRunner

from nutribench.agents import config as agent_config
from nutribench.agents.api import evaluate
from nutribench.agents.config import load_agent_config
from nutribench.agents.days import validation_food_streams
from nutribench.baselines import play_simple_policy
from nutribench.cli import app
from nutribench.engine.train import train_batched
from nutribench.tuning.objective import ValidationObjective
from nutribench.tuning.space import load_search_space
from nutribench.tuning.stack import StackedTrials
from nutribench.tuning.study import TuneError, count_trials, make_pruner, make_sampler, open_study, stored_settings
from tests.conftest import one_error_line, wait_for
from tests.test_own_agent import plugin_folder  # noqa: F401 (a fixture)

runner = CliRunner()
TINY = ["--regimes", "run3", "--seeds", "101", "--days", "4", "--eval-every", "2", "--val-episodes", "2"]


def tune(db: Path, *args: str):
    return runner.invoke(app, ["tune", "--db", str(db), *args])


def mean_return(rows) -> float:
    return float(np.mean([r["return"] for r in rows]))


def test_a_trial_is_its_share_of_the_gap_on_validation_days(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    res = tune(db, "--algo", "ppo", "--study", "s", "--trials", "2", "--pruner", "none", *TINY)
    assert res.exit_code == 0, res.output
    assert "trial 0: day 2: IQM share of the gap" in res.output and "holds 2 finished trials" in res.output
    study = optuna.load_study(study_name="s", storage=f"sqlite:///{db}")
    trial = study.trials[1]
    assert sorted(trial.intermediate_values) == [2, 4]
    # the same config trained again, evaluated post hoc on the validation days: the same share
    cfg = load_search_space("ppo").config(dict(trial.params))
    (agent,) = train_batched([("run3", 101)], cfg, 4)
    days = validation_food_streams("run3", 101, 2)
    never, planner = (mean_return(play_simple_policy(p, "run3", days)) for p in ("never", "planner"))
    share = (mean_return(evaluate(agent, "run3", days, record_steps=False).episodes) - never) / (planner - never)
    assert trial.value == pytest.approx(share, abs=1e-9)
    assert trial.user_attrs["shares"] == {"run3/101": pytest.approx(share, abs=1e-9)}


def test_the_best_trial_becomes_a_new_agent_file(tmp_path: Path, monkeypatch) -> None:
    agents = tmp_path / "agents"
    agents.mkdir()
    for f in (agent_config.regimes_dir() / "agents").glob("*.toml"):
        (agents / f.name).write_text(f.read_text())
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(agents))
    db = tmp_path / "lab.db"
    assert tune(db, "--algo", "mc", "--study", "mc_s", "--trials", "2", *TINY).exit_code == 0
    res = runner.invoke(app, ["tune", "best", "--study", "mc_s", "--write", "--db", str(db)])
    assert res.exit_code == 0, res.output
    cfg = load_agent_config(agents / "mc_tuned.toml")
    best = optuna.load_study(study_name="mc_s", storage=f"sqlite:///{db}").best_trial
    assert (cfg.name, cfg.version) == ("mc_tuned", 1) and cfg.learning_rate == best.params["learning_rate"]
    assert f"study 'mc_s', trial {best.number}" in cfg.description and "search space mc v1" in cfg.description
    assert load_agent_config("mc").version == 3  # the paper's file untouched (v3 as shipped)
    again = runner.invoke(app, ["tune", "best", "--study", "mc_s", "--write", "--db", str(db)])
    assert "mc_tuned.toml exists" in one_error_line(again)
    paper = runner.invoke(app, ["tune", "best", "--study", "mc_s", "--write", "--name", "mc", "--db", str(db)])
    assert "is a paper agent's name" in one_error_line(paper)
    with pytest.raises(TuneError, match="no tuning study"):
        open_study(db, "absent", None)


def test_a_plugin_is_tuned_through_its_params(plugin_folder: Path, monkeypatch) -> None:  # noqa: F811
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(plugin_folder / "agents"))
    monkeypatch.syspath_prepend(str(plugin_folder))
    space = plugin_folder / "a2c_mine.toml"
    space.write_text(
        'name = "a2c_mine"\nversion = 1\nagent = "a2c_mine"\ndescription = "x"\n'
        '[params.learning_rate]\nkind = "float"\nlow = 1e-4\nhigh = 1e-3\nlog = true\nwhy = "test"\n'
    )
    db = plugin_folder / "lab.db"
    res = tune(db, "--algo", str(space), "--study", "p", "--trials", "1", *TINY)
    assert res.exit_code == 0, res.output
    (trial,) = optuna.load_study(study_name="p", storage=f"sqlite:///{db}").trials
    assert trial.state.name == "COMPLETE" and np.isfinite(trial.value) and 1e-4 <= trial.params["learning_rate"] <= 1e-3
    # scored once after its last day, never pruned: the study records that, not --eval-every 2 and the median rule
    settings = stored_settings(optuna.load_study(study_name="p", storage=f"sqlite:///{db}"))
    assert (settings.eval_every, settings.pruner, settings.days) == (4, "none", 4)
    assert "late-mean" in one_error_line(
        tune(db, "--algo", str(space), "--study", "p3", "--objective", "late-mean", *TINY)
    )
    # the written file says how a plug-in's trial was scored (once, at its end), and the
    # leaderboard labels it tuned, as a built-in agent's tuned file
    out = plugin_folder / "tuned"
    res = runner.invoke(app, ["tune", "best", "--study", "p", "--write", "--out", str(out), "--db", str(db)])
    assert res.exit_code == 0, res.output
    text = (out / "a2c_mine_tuned.toml").read_text()
    assert "each agent scored once, after its last day, on 2 validation days (a plug-in's own loop)" in text
    assert "evaluated every" not in text and "(last)" in text
    import pandas as pd

    from nutribench.config.loading import read_toml
    from nutribench.report.leaderboard import protocols

    body = read_toml(out / "a2c_mine_tuned.toml")
    rows = pd.DataFrame([{"name": "a2c_mine_tuned", "version": 1, "sha256": "x", "body": body}])
    assert protocols(rows) == {"a2c_mine_tuned": "tuned"}
    plain = rows.assign(name="a2c_mine", body=[{**body, "description": "mine"}])
    assert protocols(plain) == {"a2c_mine": "plug-in"}
    bad = space.read_text().replace("learning_rate", "gamma_typo")
    space.write_text(bad)
    line = one_error_line(tune(db, "--algo", str(space), "--study", "p2", *TINY))
    assert "not a hyperparameter of agent 'a2c_mine' (keys of its [params]: learning_rate, n_steps)" in line


@pytest.mark.slow
@pytest.mark.serial
def test_a_study_killed_with_minus_9_resumes_without_losing_or_repeating_a_trial(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    # a grace period longer than the rerun takes to start, so that it meets the killed trial fresh
    env = dict(os.environ, NUTRIBENCH_TUNE_HEARTBEAT="1", NUTRIBENCH_TUNE_GRACE="20")
    args = [sys.executable, "-m", "nutribench.cli", "tune", "--algo", "ppo", "--study", "k", "--db", str(db)]
    args += ["--trials", "2", "--regimes", "run0", "--seeds", "101", "--days", "60", "--eval-every", "10"]
    args += ["--val-episodes", "1", "--pruner", "none"]
    proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    storage = f"sqlite:///{db}"

    def mid_trial() -> bool:
        try:
            trials = optuna.load_study(study_name="k", storage=storage).trials
        except (KeyError, Exception):
            return False
        # killed in the study's last missing trial: the rerun finds no trial to add, only the
        # killed one running (the case a rerun left "1 running" for good)
        complete = sum(t.state.name == "COMPLETE" for t in trials)
        return complete == 1 and any(t.state.name == "RUNNING" and t.intermediate_values for t in trials)

    wait_for(mid_trial, timeout=300)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    (killed,) = [t for t in optuna.load_study(study_name="k", storage=storage).trials if t.state.name == "RUNNING"]
    # rerun at once, the killed trial's heartbeat still fresh (the documented rerun; a rerun
    # after the grace period fails the trial at its start and never met the bug of issue 51:
    # a rerun that ran the missing trials and left the killed one running for good)
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    assert "1 of 2 finished, 1 running: waiting for them" in done.stdout  # the killed trial, not yet stale
    study = optuna.load_study(study_name="k", storage=storage)
    counts = count_trials(study)
    assert (counts.complete, counts.pruned, counts.running) == (2, 0, 0)
    states = {t.number: t.state.name for t in study.trials}
    assert states[killed.number] == "FAIL"  # not counted
    (retry,) = [t for t in study.trials if t.system_attrs.get("failed_trial") == killed.number]
    assert retry.state.name == "COMPLETE" and retry.params == killed.params  # not lost


def test_the_guide_s_first_commands_run(tmp_path: Path, monkeypatch) -> None:
    """docs/tuning.md's "Try it in a minute" and ``--stack`` blocks, command by command, in an
    empty folder (the page's last command, a real study, takes hours and is not run)."""
    import re
    import shlex

    page = (Path(__file__).resolve().parents[1] / "docs" / "tuning.md").read_text()
    block = re.search(r"## Try it in a minute\s+```bash\n(.*?)```", page, re.S).group(1)
    stacked = re.search(r"## Many trials in one process: `--stack N`\s+```bash\n(.*?)```", page, re.S).group(1)
    lines = (block + stacked).splitlines()
    commands = [shlex.split(line)[1:] for line in lines if line.startswith("nutribench ")]
    assert len(commands) == 5
    monkeypatch.chdir(tmp_path)
    for args in commands:
        res = runner.invoke(app, args)
        assert res.exit_code == 0, (args, res.output)
    assert load_agent_config(tmp_path / "tuned_agents" / "ppo_tuned.toml").name == "ppo_tuned"


@pytest.mark.slow
@pytest.mark.serial
def test_two_drivers_start_one_new_study_on_sqlite_together(tmp_path: Path) -> None:
    """Both create Optuna's tables and the study at the same moment: neither fails, and they
    stop together at the count."""
    db = tmp_path / "two.db"
    args = [sys.executable, "-m", "nutribench.cli", "tune", "--algo", "mc", "--study", "two", "--db", str(db)]
    args += ["--regimes", "run0", "--seeds", "101", "--days", "4", "--eval-every", "2", "--val-episodes", "1"]
    args += ["--trials", "8"]
    procs = [subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    errors = [p.communicate(timeout=600)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errors
    study = optuna.load_study(study_name="two", storage=f"sqlite:///{db}")
    counts = count_trials(study)
    assert (counts.finished, counts.running, counts.failed) == (8, 0, 0)  # the count exactly (issue 51)
    params = [tuple(sorted(t.params.items())) for t in study.trials]
    assert len(set(params)) == len(params)  # the two drivers drew different trials (one seed each)


def test_stacked_trials_share_one_batch_and_score_as_single_trials(tmp_path: Path) -> None:
    """``--stack 3``: three trials asked at once, sharing the first's structure, train in one
    batch; each trial's value is what its config scores trained alone."""
    db = tmp_path / "lab.db"
    args = ["--regimes", "run3", "--seeds", "101", "--days", "2", "--eval-every", "1", "--val-episodes", "2"]
    res = tune(db, "--algo", "mc", "--study", "st", "--trials", "3", "--stack", "3", "--pruner", "none", *args)
    assert res.exit_code == 0, res.output
    study = optuna.load_study(study_name="st", storage=f"sqlite:///{db}")
    assert [t.state.name for t in study.trials] == ["COMPLETE"] * 3
    assert sorted(study.trials[0].user_attrs["stacked_with"]) == [1, 2]
    space = load_search_space("mc")
    days = validation_food_streams("run3", 101, 2)
    never, planner = (mean_return(play_simple_policy(p, "run3", days)) for p in ("never", "planner"))
    for trial in study.trials:
        (alone,) = train_batched([("run3", 101)], space.config(dict(trial.params)), 2)
        share = (mean_return(evaluate(alone, "run3", days, record_steps=False).episodes) - never) / (planner - never)
        assert trial.value == pytest.approx(share, abs=1e-6)
    assert len({t.params["learning_rate"] for t in study.trials}) == 3  # three settings in the one batch


def test_a_stack_of_8_draws_every_knob_as_8_lone_trials_do(tmp_path: Path) -> None:
    """Issue 73: ``--stack 8`` draws each trial's structural knobs (epochs, minibatch) as 8
    trials asked one at a time do (a stack used to share its first trial's structure, so 24
    stacked trials searched minibatch and epochs 6 times); the stack still trains trials of one
    structure as one batch."""
    args = ["--regimes", "run3", "--seeds", "101", "--days", "1", "--eval-every", "1", "--val-episodes", "1"]
    args += ["--trials", "8", "--startup-trials", "8", "--sampler-seed", "3", "--pruner", "none"]
    drawn = {}
    for stack in ("1", "8"):
        db = tmp_path / f"stack{stack}.db"
        res = tune(db, "--space", "ppo_v2", "--study", "s", "--stack", stack, *args)
        assert res.exit_code == 0, res.output
        study = optuna.load_study(study_name="s", storage=f"sqlite:///{db}")
        assert [t.state.name for t in study.trials] == ["COMPLETE"] * 8
        drawn[stack] = [dict(t.params) for t in study.trials]
    assert drawn["8"] == drawn["1"]  # every knob, the structural ones included, trial by trial
    structures = [(p["n_epochs"], p["batch_size"]) for p in drawn["8"]]
    assert len(set(structures)) > 1  # not one structure for the whole stack
    trials = optuna.load_study(study_name="s", storage=f"sqlite:///{tmp_path / 'stack8.db'}").trials
    for trial, structure in zip(trials, structures):  # stacked exactly with its structure's trials
        same = [t.number for t, s in zip(trials, structures) if s == structure and t.number != trial.number]
        assert sorted(trial.user_attrs["stacked_with"]) == same
    assert any(trial.user_attrs["stacked_with"] for trial in trials)  # (seed 3: two pairs share a structure)


def test_a_pruned_stacked_trial_is_told_pruned(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    args = ["--regimes", "run3", "--seeds", "101", "--days", "4", "--eval-every", "1", "--val-episodes", "1"]
    assert tune(db, "--algo", "mc", "--study", "pr", "--trials", "6", "--stack", "1", *args).exit_code == 0
    # resumed with the creator's seed (a joining driver draws its own), so that the trials are known
    storage = f"sqlite:///{db}"
    settings = stored_settings(optuna.load_study(study_name="pr", storage=storage))
    sampler, pruner = make_sampler(settings), make_pruner(settings)
    resumed = optuna.load_study(study_name="pr", storage=storage, sampler=sampler, pruner=pruner)
    StackedTrials(ValidationObjective(load_search_space("mc"), settings), 3).run(resumed, 12)
    counts = count_trials(optuna.load_study(study_name="pr", storage=storage))
    assert counts.finished == 12 and counts.running == 0 and counts.failed == 0
    study = optuna.load_study(study_name="pr", storage=f"sqlite:///{db}")
    pruned = [t for t in study.trials if t.state.name == "PRUNED" and t.user_attrs.get("stacked_with")]
    assert pruned and all(max(t.intermediate_values) < 4 for t in pruned)  # stopped before the last day


def test_a_late_mean_objective_is_the_mean_of_the_values_after_half_the_days(tmp_path: Path) -> None:
    """``--objective late-mean``: the trial's value is the mean of its IQMs at the evaluations
    after half its days (days 3 and 4 of 4), not its last one; a study made before the setting
    existed (no ``objective`` in its settings) resumes as ``last``."""
    db = tmp_path / "lab.db"
    args = ["--regimes", "run3", "--seeds", "101", "--days", "4", "--eval-every", "1", "--val-episodes", "1"]
    res = tune(
        db, "--algo", "ppo", "--study", "late", "--trials", "1", "--pruner", "none", "--objective", "late-mean", *args
    )
    assert res.exit_code == 0, res.output
    (trial,) = optuna.load_study(study_name="late", storage=f"sqlite:///{db}").trials
    values = trial.intermediate_values
    assert sorted(values) == [1, 2, 3, 4]
    assert trial.value == pytest.approx((values[3] + values[4]) / 2, abs=1e-12)
    study = optuna.load_study(study_name="late", storage=f"sqlite:///{db}")
    assert stored_settings(study).objective == "late-mean"
    attr = dict(study.user_attrs["nutribench"])
    del attr["objective"]
    study.set_user_attr("nutribench", attr)
    assert stored_settings(study).objective == "last"
    bad = tune(db, "--algo", "ppo", "--study", "x", "--objective", "best", *args)
    assert "--objective" in one_error_line(bad)


def test_a_new_study_draws_with_the_constant_liar_and_an_old_one_resumes_without(tmp_path: Path) -> None:
    """A study made by ``nutribench tune`` stores ``constant_liar`` and its drivers' TPE uses it
    (a stack's trials, asked at once, see each other running); a study made before the setting
    existed (no ``constant_liar`` in its settings) resumes without it, by the same command."""
    db = tmp_path / "lab.db"
    args = ["--regimes", "run3", "--seeds", "101", "--days", "2", "--eval-every", "1", "--val-episodes", "1"]
    assert tune(db, "--algo", "mc", "--study", "new", "--trials", "1", *args).exit_code == 0
    study = optuna.load_study(study_name="new", storage=f"sqlite:///{db}")
    assert stored_settings(study).constant_liar is True
    assert make_sampler(stored_settings(study))._constant_liar is True  # optuna 5's TPESampler attribute
    attr = dict(study.user_attrs["nutribench"])
    del attr["constant_liar"]  # as the studies made before it
    study.set_user_attr("nutribench", attr)
    assert stored_settings(study).constant_liar is False
    assert make_sampler(stored_settings(study))._constant_liar is False
    res = tune(db, "--algo", "mc", "--study", "new", "--trials", "2", *args)
    assert res.exit_code == 0, res.output  # resumed: no "created with other settings"
    study = optuna.load_study(study_name="new", storage=f"sqlite:///{db}")
    assert "constant_liar" not in study.user_attrs["nutribench"] and len(study.trials) == 2


def test_a_plugin_study_recorded_before_it_said_scored_once_resumes(tmp_path: Path) -> None:
    from dataclasses import replace

    from nutribench.tuning.study import StudySettings, scored_once

    old = StudySettings("s", 1, "0" * 64, ("run3",), (101,), 12, 6, 2, 0, "median")  # what such studies hold
    db = tmp_path / "lab.db"
    open_study(db, "p", old)
    now = scored_once(old)
    assert (now.eval_every, now.pruner) == (12, "none")
    with pytest.raises(TuneError, match="created with other settings"):
        open_study(db, "p", now)  # any other study's settings must match
    assert stored_settings(open_study(db, "p", now, once=True)) == replace(old, constant_liar=False)
    with pytest.raises(TuneError, match="created with other settings: days 12"):
        open_study(db, "p", replace(now, days=24, eval_every=24), once=True)  # what applies must still match
