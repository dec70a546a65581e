"""Bring your own agent: plug-in agent files through the scheduler, the RecurrentPPO example,
the Recorder (any training loop), ``nutribench evaluate``, and dry runs kept apart."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from nutribench.store import read_episode_metrics, read_jobs

REPO = Path(__file__).resolve().parents[1]

A2C_PLUGIN = '''
"""SB3's A2C under another name: a plug-in agent."""
from stable_baselines3 import A2C


def make_agent(params, env, seed):
    return A2C("MlpPolicy", env, seed=seed, device="cpu", **params)


def load(path):
    return A2C.load(path, device="cpu")
'''

A2C_TOML = """
algo = "external"
name = "a2c_mine"
version = 1
description = "SB3 A2C, plugged in"
entry_point = "my_plugins:make_agent"

[params]
n_steps = 25
learning_rate = 7e-4
"""


def cli(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``nutribench ARGS`` in a fresh process started in ``cwd``, as a user types it."""
    full = dict(os.environ, **(env or {}))
    full.pop("NUTRIBENCH_JOB", None)
    return subprocess.run(
        [sys.executable, "-m", "nutribench.cli", *args], cwd=cwd, env=full, capture_output=True, text=True, timeout=900
    )


@pytest.fixture
def plugin_folder(tmp_path: Path) -> Path:
    """A user's folder: a plug-in module and its agent file beside copies of the shipped agents."""
    (tmp_path / "my_plugins.py").write_text(A2C_PLUGIN)
    agents = tmp_path / "agents"
    agents.mkdir()
    for f in (REPO / "regimes" / "agents").glob("*.toml"):
        (agents / f.name).write_text(f.read_text())
    (agents / "a2c_mine.toml").write_text(A2C_TOML)
    return tmp_path


@pytest.mark.slow
def test_plugin_runs_through_nutribench_run_and_reaches_the_report(plugin_folder: Path, monkeypatch):
    env = {"NUTRIBENCH_AGENTS": str(plugin_folder / "agents")}
    db = plugin_folder / "lab.db"
    res = cli(
        "run",
        "--regimes",
        "run0,run3",
        "--algos",
        "a2c_mine",
        "--seeds",
        "0",
        "--episodes",
        "3",
        "--eval-episodes",
        "2",
        "--db",
        str(db),
        "--workers",
        "2",
        cwd=plugin_folder,
        env=env,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    jobs = read_jobs(db)
    assert sorted(jobs["regime"]) == ["run0", "run3"] and set(jobs["status"]) == {"done"}
    assert set(jobs["engine"]) == {"external"} and set(jobs["source"]) == {"my_plugins:make_agent"}
    assert all(len(h) == 64 for h in jobs["source_sha256"])
    df = read_episode_metrics(db)
    assert df.groupby(["regime", "phase"]).size().to_dict() == {
        ("run0", "eval"): 2,
        ("run0", "train"): 3,
        ("run3", "eval"): 2,
        ("run3", "train"): 3,
    }
    assert df["entropy"].notna().all()  # A2C's policy has a distribution
    monkeypatch.syspath_prepend(str(plugin_folder))
    for path in jobs["model_path"]:  # saved, and loadable by the plug-in's own load()
        from nutribench.agents.api import TrainedAgent

        agent = TrainedAgent.load(path, load_with="my_plugins:load")  # the loader named, never by the sidecar
        assert agent.algo == "external" and agent.config.entry_point == "my_plugins:make_agent"
    out = plugin_folder / "report"
    res = cli(
        "report", "--all", "--db", str(db), "--out", str(out), "--reference-episodes", "5", cwd=plugin_folder, env=env
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert "a2c_mine" in "".join(p.read_text() for p in out.rglob("*.md"))
    assert list(out.rglob("*fig3*.png")), sorted(p.name for p in out.rglob("*"))


def test_plugin_refused_in_one_line_when_its_module_is_missing(plugin_folder: Path, monkeypatch):
    from nutribench.agents.config import load_agent_config
    from nutribench.agents.registry import make_model
    from nutribench.config.loading import ConfigError

    toml = plugin_folder / "agents" / "a2c_mine.toml"
    toml.write_text(toml.read_text().replace("my_plugins:make_agent", "no_such_plugin_xyz:make_agent"))
    cfg = load_agent_config(toml)
    with pytest.raises(
        ConfigError, match=r"entry point 'no_such_plugin_xyz:make_agent': cannot import no_such_plugin_xyz"
    ):
        make_model(cfg, None, 0, 50)
    monkeypatch.syspath_prepend(str(plugin_folder))
    toml.write_text(toml.read_text().replace("no_such_plugin_xyz:make_agent", "my_plugins:no_function"))
    with pytest.raises(ConfigError, match=r"module my_plugins has no attribute 'no_function'"):
        make_model(load_agent_config(toml), None, 0, 50)


def test_external_config_needs_few_keys_and_states_its_defaults():
    from nutribench.agents.config import parse_agent_config
    from nutribench.config.loading import ConfigError

    cfg = parse_agent_config(
        {"algo": "external", "name": "x", "version": 1, "description": "d", "entry_point": "a.b:c"}
    )
    assert (cfg.params, cfg.normalize_obs, cfg.normalize_reward, cfg.gamma) == ({}, False, False, 0.99)
    with pytest.raises(ConfigError, match="entry_point"):
        parse_agent_config(
            {"algo": "external", "name": "x", "version": 1, "description": "d", "entry_point": "no colon"}
        )
    with pytest.raises(ConfigError, match='algo = \\"external\\"'):
        parse_agent_config({"algo": "recurrent_ppo", "name": "x", "version": 1, "description": "d"})


# ------------------------------------------------------------------ the RecurrentPPO example
def test_recurrent_ppo_example_trains_and_evaluation_carries_its_lstm_state(monkeypatch, tmp_path: Path):
    pytest.importorskip("sb3_contrib", reason="the example's optional extra (pip install -e '.[contrib]')")
    import tempfile

    from nutribench.agents.api import eval_food_streams, evaluate, train
    from nutribench.agents.config import load_agent_config, parse_agent_config

    data = load_agent_config(REPO / "examples" / "agents" / "recurrent_ppo.toml").model_dump()
    data["params"] = {**data["params"], "n_steps": 50, "batch_size": 50, "n_epochs": 1}  # a tiny budget
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where SB3's default logger makes its folder
    agent = train("run3", parse_agent_config(data), seed=0, episodes=2)
    assert len(agent.train_episodes) == 2 and all(r["entropy"] is not None for r in agent.train_episodes)
    assert not list(tmp_path.glob("SB3-*"))  # a plug-in's job leaves no empty SB3-<date> folder behind

    calls = []
    predict = agent.model.predict

    def spy(obs, state=None, episode_start=None, deterministic=False):
        actions, new_state = predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        calls.append((state, np.array(episode_start), new_state))
        return actions, new_state

    monkeypatch.setattr(agent.model, "predict", spy)
    streams = eval_food_streams("run3", 0, 3)
    result = evaluate(agent, "run3", streams)
    assert len(calls) == 50 and len(result.episodes) == 3
    assert calls[0][1].all() and not any(c[1].any() for c in calls[1:])  # day start only at step 1
    for (_, _, returned), (given, _, _) in zip(calls, calls[1:]):  # each step gets the state the last one returned
        assert given is not None and all(np.array_equal(a, b) for a, b in zip(returned, given))
    assert all(r["entropy"] is not None for r in result.episodes)


# ------------------------------------------------------------------ the Recorder
def test_recorder_with_a_hand_written_loop(tmp_path: Path):
    db = tmp_path / "lab.db"
    with nutribench.Recorder(db=f"sqlite:///{db}", name="eat_early", regime="run3", seed=7, params={"k": 4}) as rec:
        env = rec.env
        for _ in range(3):
            env.reset()
            for t in range(50):
                env.step(int(t < 4))
        env.reset()
        env.step(1)  # a day cut short by the end of the loop is not a row
        rows = rec.evaluate(lambda obs: int(obs[:3].sum() < 1.5))
    assert len(rows) == 5
    jobs = read_jobs(db)
    assert len(jobs) == 1 and jobs.loc[0, "engine"] == "external" and jobs.loc[0, "status"] == "done"
    assert jobs.loc[0, "source"] == str(Path(__file__).resolve()) and len(jobs.loc[0, "source_sha256"]) == 64
    df = read_episode_metrics(db)
    assert (df["phase"] == "train").sum() == 3 and list(df.loc[df.phase == "train", "foods"]) == [4, 4, 4]
    evals = df[df.phase == "eval"]
    assert list(evals["return"]) == pytest.approx([r["return"] for r in rows])
    # the evaluation days are the seed's fixed days: a second agent of the same seed plays the same foods
    with nutribench.Recorder(db=db, name="never", regime="run3", seed=7) as rec:
        rec.evaluate(lambda obs: 0)
    traj = nutribench.store.read_eval_trajectories(db)
    a, b = (traj[traj.algo == n].sort_values(["episode", "step"])["food"].to_numpy() for n in ("eat_early", "never"))
    assert np.array_equal(a, b)


def test_recorder_with_an_sb3_model_and_its_refusals(tmp_path: Path):
    from stable_baselines3 import PPO

    db = tmp_path / "lab.db"
    with nutribench.Recorder(db=db, name="sb3_ppo", regime="run0", seed=1, eval_episodes=2) as rec:
        model = PPO("MlpPolicy", rec.env, n_steps=50, batch_size=50, n_epochs=1, seed=1, device="cpu")
        model.learn(100)
        rows = rec.evaluate(model)
    df = read_episode_metrics(db)
    assert (df.phase == "train").sum() == 2 and len(rows) == 2
    assert df.loc[df.phase == "eval", "entropy"].notna().all()  # predict-objects with a distribution: entropy
    # the same job again: refused in one line, nothing written
    with pytest.raises(nutribench.errors.UserError, match="already recorded"):
        with nutribench.Recorder(db=db, name="sb3_ppo", regime="run0", seed=1, eval_episodes=2) as rec:
            for _ in range(2):
                rec.env.reset()
                for _ in range(50):
                    rec.env.step(0)
            rec.evaluate(model)
    # no evaluate: nothing written, one line
    with pytest.raises(nutribench.errors.UserError, match="call rec.evaluate"):
        with nutribench.Recorder(db=db, name="lazy", regime="run0", seed=1):
            pass
    # an exception in the loop writes nothing
    with pytest.raises(ZeroDivisionError):
        with nutribench.Recorder(db=db, name="broken", regime="run0", seed=1) as rec:
            rec.evaluate(lambda o: 0)
            raise ZeroDivisionError
    assert set(read_jobs(db)["algo"]) == {"sb3_ppo"}


def test_nutribench_evaluate_stores_a_saved_model(tmp_path: Path):
    from stable_baselines3 import PPO

    from nutribench.env.sb3 import NutriRLSB3VecEnv

    model = PPO(
        "MlpPolicy", NutriRLSB3VecEnv(num_envs=1, regime="run0"), n_steps=50, batch_size=50, seed=0, device="cpu"
    )
    model.save(tmp_path / "m.zip")
    db = tmp_path / "lab.db"
    args = [
        "evaluate",
        "--model",
        str(tmp_path / "m.zip"),
        "--entry-point",
        "stable_baselines3:PPO.load",
        "--regime",
        "run3",
        "--seed",
        "0",
        "--name",
        "my_agent",
        "--db",
        str(db),
    ]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2 and "has no attribute 'PPO.load'" in res.output  # one line: module:function
    (tmp_path / "loaders.py").write_text(
        "from stable_baselines3 import PPO\n\ndef load(path):\n    return PPO.load(path, device='cpu')\n"
    )
    sys.path.insert(0, str(tmp_path))
    try:
        args[4] = "loaders:load"
        res = CliRunner().invoke(app, args)
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("loaders", None)  # another test file in this process may write its own loaders.py
    assert res.exit_code == 0, res.output
    jobs = read_jobs(db)
    assert list(jobs["algo"]) == ["my_agent"] and jobs.loc[0, "episodes"] == 0 and jobs.loc[0, "engine"] == "external"
    assert jobs.loc[0, "source"].startswith("loaders:load ") and len(jobs.loc[0, "source_sha256"]) == 64
    assert len(read_episode_metrics(db, phase="eval")) == 5
    res = CliRunner().invoke(app, [*args[:2], str(tmp_path / "nope.zip"), *args[3:]])
    assert res.exit_code == 2 and "no such file" in res.output


# ------------------------------------------------------------------ dry runs
def test_fake_jobs_are_marked_never_drawn_and_never_mixed_with_real_ones(tmp_path: Path):
    db = tmp_path / "dry.db"
    grid = ["run", "--regimes", "run0", "--algos", "ppo", "--seeds", "0", "--episodes", "3", "--eval-episodes", "1"]
    res = CliRunner().invoke(app, [*grid, "--db", str(db)], env={"NUTRIBENCH_JOB": "fake"})
    assert res.exit_code == 0, res.output
    con = sqlite3.connect(db)
    assert con.execute("SELECT status, fake FROM jobs").fetchall() == [("done", 1)]
    assert con.execute("SELECT count(*) FROM episodes").fetchone()[0] == 4  # stored, for the dry run's checks
    assert len(read_episode_metrics(db)) == 0  # but never a result: the views leave them out
    # a real run on the dry run's database: refused in one line, nothing changed
    res = CliRunner().invoke(app, [*grid, "--db", str(db)], env={"NUTRIBENCH_JOB": ""})
    lines = res.output.strip().splitlines()  # the line saying what run starts, then the error
    assert res.exit_code == 2 and len(lines) == 2 and lines[0].startswith("nutribench run: 1 job"), res.output
    assert lines[1].startswith("error:") and "dry-run jobs" in lines[1]
    assert con.execute("SELECT count(*) FROM jobs").fetchone()[0] == 1
    with pytest.raises(nutribench.errors.UserError, match="dry-run jobs"):
        with nutribench.Recorder(db=db, name="x", regime="run0") as rec:
            rec.evaluate(lambda o: 0)
    # and a dry run on a real database
    real = tmp_path / "real.db"
    with nutribench.Recorder(db=real, name="never", regime="run0", eval_episodes=1) as rec:
        rec.evaluate(lambda o: 0)
    res = CliRunner().invoke(app, [*grid, "--db", str(real)], env={"NUTRIBENCH_JOB": "fake"})
    assert res.exit_code == 2 and "real jobs" in res.output
    assert sqlite3.connect(real).execute("SELECT count(*) FROM jobs").fetchone()[0] == 1


@pytest.mark.slow
def test_guide_code_blocks_run(tmp_path: Path):
    """Every Python and shell block of docs/own-agent.md, in order, in a scratch folder."""
    guide = REPO / "docs" / "own-agent.md"
    text = guide.read_text()
    blocks = _blocks(text)
    assert [lang for lang, _ in blocks].count("python") >= 2 and [lang for lang, _ in blocks].count("bash") >= 2
    env = dict(os.environ, NUTRIBENCH_GUIDE_TINY="1", PYTHONPATH=str(REPO))
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])  # the blocks' `python`
    env.pop("NUTRIBENCH_JOB", None)
    for k, (lang, code) in enumerate(blocks):
        if lang == "python":
            path = tmp_path / f"block{k}.py"
            path.write_text(code)
            cmd = [sys.executable, str(path)]
        else:
            cmd = [
                "bash",
                "-euo",
                "pipefail",
                "-c",
                code.replace("nutribench ", f"{sys.executable} -m nutribench.cli "),
            ]
        res = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        assert res.returncode == 0, f"block {k} ({lang}):\n{code}\n{res.stdout}\n{res.stderr}"


def _blocks(text: str) -> list[tuple[str, str]]:
    out, lang, lines = [], None, []
    for line in text.splitlines():
        if lang is None and line.startswith("```") and line[3:].strip() in ("python", "bash", "toml"):
            lang, lines = line[3:].strip(), []
        elif lang is not None and line.startswith("```"):
            if lang != "toml":
                out.append((lang, textwrap.dedent("\n".join(lines))))
            lang = None
        elif lang is not None:
            lines.append(line)
    return out
