"""What a newcomer hit bringing an agent of their own beside the paper's (issue 40): plug-in
params that SB3 mutates, a plug-in that cannot import, TensorBoard for plug-ins, the
recorder's checks on entry, budgets in the tables and ``compare``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from tests.conftest import one_error_line

REPO = Path(__file__).resolve().parents[1]

QRDQN_PLUGIN = '''
"""sb3-contrib's QRDQN as a plug-in agent."""
from sb3_contrib import QRDQN


def make_agent(params, env, seed):
    return QRDQN("MlpPolicy", env, seed=seed, device="cpu", **params)


def load(path):
    return QRDQN.load(path, device="cpu")
'''

QRDQN_TOML = """
algo = "external"
name = "qrdqn_mine"
version = 1
description = "sb3-contrib QRDQN, plugged in"
entry_point = "{module}:make_agent"

[params]
learning_starts = 10
buffer_size = 1000
batch_size = 8

[params.policy_kwargs]
net_arch = [16]
n_quantiles = 5
"""


@pytest.fixture
def qrdqn_folder(tmp_path: Path, monkeypatch) -> Path:
    """A user's folder: the QRDQN plug-in (a module of its own name) and its agent file."""
    pytest.importorskip("sb3_contrib")
    module = f"qrdqn_plugin_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{module}.py").write_text(QRDQN_PLUGIN)
    agents = tmp_path / "agents"
    agents.mkdir()
    (agents / "qrdqn_mine.toml").write_text(QRDQN_TOML.format(module=module))
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def test_plugin_params_are_deep_copied_so_a_mutating_sb3_class_leaves_the_config_whole(qrdqn_folder: Path):
    """QRDQN writes th.optim.Adam into the policy_kwargs it is given: the config the job stores
    must not see it (it failed to serialise, after training, in every job)."""
    from nutribench.agents.api import make_train_env
    from nutribench.agents.config import agent_config_content, load_agent_config
    from nutribench.agents.registry import make_model
    from nutribench.config import load_env_config

    cfg = load_agent_config(qrdqn_folder / "agents" / "qrdqn_mine.toml")
    before = json.dumps(agent_config_content(cfg), sort_keys=True)
    _, env = make_train_env(load_env_config("run0"), cfg)
    model = make_model(cfg, env, seed=0, horizon=50)
    assert "optimizer_class" in model.policy_kwargs  # the class did write into its kwargs...
    assert "optimizer_class" not in cfg.params["policy_kwargs"]  # ...a copy of them
    assert json.dumps(agent_config_content(cfg), sort_keys=True) == before
    cfg.model_dump_json()  # what the job stores still serialises


def test_plugin_trains_and_writes_tensorboard_events(qrdqn_folder: Path, tmp_path: Path):
    pytest.importorskip("tensorboard")
    from nutribench.agents.api import train
    from nutribench.agents.config import load_agent_config

    cfg = load_agent_config(qrdqn_folder / "agents" / "qrdqn_mine.toml")
    agent = train("run0", cfg, seed=0, episodes=2, tensorboard=tmp_path / "tb")
    assert len(agent.train_episodes) == 2
    assert list((tmp_path / "tb").rglob("events.out.tfevents.*")), sorted((tmp_path / "tb").rglob("*"))


def test_plugin_that_cannot_import_is_refused_before_the_run(qrdqn_folder: Path, monkeypatch):
    toml = qrdqn_folder / "agents" / "qrdqn_mine.toml"
    toml.write_text(toml.read_text().replace("qrdqn_plugin_", "no_such_module_"))
    monkeypatch.chdir(qrdqn_folder)
    db = qrdqn_folder / "lab.db"
    res = CliRunner().invoke(
        app,
        ["run", "--regimes", "run0", "--algos", "qrdqn_mine", "--seeds", "0", "--episodes", "1", "--db", str(db)],
        env={"NUTRIBENCH_AGENTS": str(qrdqn_folder / "agents"), "NUTRIBENCH_JOB": ""},
    )
    line = one_error_line(res)
    assert "cannot import no_such_module_" in line
    assert not db.exists()  # refused before the database was made, no job failed


# ------------------------------------------------------------------ the recorder, on entry
def test_recorder_refuses_a_conflict_or_a_duplicate_on_entry_before_the_loop(tmp_path: Path):
    db = tmp_path / "lab.db"
    with nutribench.Recorder(db=db, name="loop", regime="run3", seed=0, params={"lr": 0.1}, eval_episodes=1) as rec:
        rec.evaluate(lambda obs: 0)
    ran = []
    cases = [
        ({"params": {"lr": 0.2}, "seed": 0}, "bump the version"),  # other params, same version
        ({"params": {"lr": 0.2}, "seed": 5}, "bump the version"),  # whatever the seed
        ({"params": {"lr": 0.1}, "seed": 0}, "already recorded"),  # the same job again
    ]
    for kwargs, expected in cases:
        with pytest.raises(nutribench.errors.UserError, match=expected) as err:
            with nutribench.Recorder(db=db, name="loop", regime="run3", eval_episodes=1, **kwargs) as rec:
                ran.append(kwargs)  # the training loop: never reached
        message = str(err.value)
        assert "\n" not in message and "loop v1" in message and "run3" in message
        assert f"seed {kwargs['seed']}" in message
    assert ran == []
    # another seed of the same agent, or a bumped version, is recorded
    for kwargs in ({"seed": 1, "params": {"lr": 0.1}}, {"seed": 0, "params": {"lr": 0.2}, "version": 2}):
        with nutribench.Recorder(db=db, name="loop", regime="run3", eval_episodes=1, **kwargs) as rec:
            rec.evaluate(lambda obs: 0)
    from nutribench.store import read_jobs

    assert len(read_jobs(db)) == 3


# ------------------------------------------------------------------ budgets in the tables
def _mixed_budgets():
    """PPO trained 5000 days, a user's agent 50: the newcomer's database."""
    from tests.test_report_builders import synthetic

    df = synthetic(regimes=("run0", "run3"), algos=("ppo", "mine"), seeds=(0, 21, 9), train_eps=4)
    df["budget"] = np.where(df["algo"] == "ppo", 5000, 50)
    df["job_id"] = df.groupby(["regime", "algo", "seed"]).ngroup()
    return df


def test_results_and_aggregate_tables_state_each_budget_and_warn_when_they_differ():
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_table
    from nutribench.report.tables import table_results
    from tests.test_report_builders import _day_refs

    df = _mixed_budgets()
    ev = df[df.phase == "eval"]
    res = table_results(df, references=_day_refs(df))
    budgets = dict(zip(res.formatted["algorithm"], res.formatted["budget (days)"]))
    assert budgets == {"PPO": "5000", "mine": "50"}
    assert "budgets differ" in res.title and "5000 days" in res.title and "50 days" in res.title
    agg = aggregate_table(aggregate_from_eval(ev, _day_refs(df), reps=200), ev)
    assert dict(zip(agg.formatted["algorithm"], agg.formatted["budget (days)"])) == budgets
    assert "budgets differ" in agg.title and "budget (days)" in agg.to_markdown()
    same = df[df.algo == "ppo"]
    assert "budgets differ" not in table_results(same).title


def test_compare_warns_when_the_two_budgets_differ():
    from nutribench.report.compare import compare_agents

    df = _mixed_budgets()
    res = compare_agents(df[df.phase == "eval"], "ppo", "mine", reps=200)
    assert res.notes[0].startswith("warning: budgets differ (PPO trained 5000 days, mine 50 days)"), res.notes[0]
    for shown in (res.to_text(), res.to_markdown()):  # one "warning:", never "note: warning:"
        assert "warning: budgets differ" in shown and "note: warning" not in shown
        assert any(line.lstrip("*_ ").startswith("warning: budgets differ") for line in shown.splitlines()), shown
    even = df.assign(budget=5000)
    assert not any(
        "budgets differ" in n for n in compare_agents(even[even.phase == "eval"], "ppo", "mine", reps=200).notes
    )


def test_index_page_names_the_database_file_not_its_folder_and_states_budgets(tmp_path: Path):
    from nutribench.report.build import _page_subtitle
    from nutribench.report.data import ReportData

    data = ReportData(_mixed_budgets())
    text = _page_subtitle(str(tmp_path / "tmpabc" / "paper.db"), data)
    assert text.startswith("from paper.db;") and str(tmp_path) not in text
    assert "budgets differ" in text and "5000 days" in text
    assert _page_subtitle("postgresql://u:secret@host/lab", None) == "from lab"


# ------------------------------------------------------------------ colours of users' agents
#: Machado et al. (2009) colour-vision-deficiency matrices (severity 1), on linear RGB.
CVD = {
    "protan": [[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216], [-0.003882, -0.048116, 1.051998]],
    "deutan": [[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413], [-0.011820, 0.042940, 0.968881]],
    "tritan": [[1.255528, -0.076749, -0.178779], [-0.078411, 0.930809, 0.147602], [0.004733, 0.691367, 0.303900]],
}


def _as_seen(color: str, kind: str) -> str:
    from matplotlib.colors import to_hex, to_rgb

    rgb = np.asarray(to_rgb(color))
    lin = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    out = np.clip(np.array(CVD[kind]) @ lin, 0, 1)
    return to_hex(np.clip(np.where(out <= 0.0031308, 12.92 * out, 1.055 * out ** (1 / 2.4) - 0.055), 0, 1))


def test_users_agents_get_colour_blind_safe_colours_apart_from_the_five_and_readable_on_white():
    from nutribench.report.palette import (
        BUILTIN_COLORS,
        BUILTIN_ORDER,
        MAX_LIGHTNESS,
        MIN_DISTANCE,
        USER_COLORS,
        colors,
        distance,
        lab,
    )

    for i, a in enumerate(USER_COLORS):
        assert lab(a)[0] <= MAX_LIGHTNESS, a  # no pale yellow
        assert min(distance(a, b) for b in BUILTIN_COLORS.values()) >= MIN_DISTANCE, a
        for b in USER_COLORS[i + 1 :]:
            assert distance(a, b) >= MIN_DISTANCE, (a, b)
            assert all(distance(_as_seen(a, k), _as_seen(b, k)) >= 15 for k in CVD), (a, b)
    # the newcomer's three agents beside the five: the palette's colours, every pair apart
    c = colors([*BUILTIN_ORDER, "qrdqn_mine", "reinforce_loop", "mine"])
    users = [c[n] for n in ("qrdqn_mine", "reinforce_loop", "mine")]
    assert set(users) <= set(USER_COLORS) and len(set(users)) == 3
    values = list(c.values())
    assert min(distance(a, b) for i, a in enumerate(values) for b in values[i + 1 :]) >= MIN_DISTANCE
    # past the palette: derived colours, never pale either
    many = colors(f"agent{k}" for k in range(30))
    assert all(lab(v)[0] <= MAX_LIGHTNESS for v in many.values())


# ------------------------------------------------------------------ figures
def test_figure_3_draws_no_line_across_a_regime_without_data():
    from nutribench.report.figures import eval_across_regimes
    from tests.test_report_builders import synthetic

    df = synthetic(regimes=("run0", "run1", "run2"), algos=("ppo",), seeds=(0, 21), train_eps=1)
    mine = synthetic(regimes=("run0", "run2"), algos=("mine",), seeds=(0, 21), train_eps=1, seed=1)
    lone = synthetic(regimes=("run1",), algos=("lone",), seeds=(0, 21), train_eps=1, seed=2)
    res = eval_across_regimes(pd.concat([df, mine, lone]), bootstrap=200)
    ax = res.figure.axes[0]
    line = {ln.get_label(): ln for ln in ax.get_lines()}
    y = np.asarray(line["mine"].get_ydata(), dtype=float)
    assert np.isfinite(y[[0, 2]]).all() and np.isnan(y[1])  # broken at run1: no line from run0 to run2
    assert np.isfinite(np.asarray(line["PPO"].get_ydata(), dtype=float)).all()
    # the drawn numbers keep only what was evaluated
    assert sorted(res.data.loc[(res.data.panel == "return") & (res.data.algo == "mine"), "regime"]) == ["run0", "run2"]
    # a point with no neighbour carries its interval as an error bar
    from matplotlib.collections import LineCollection

    bars = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert bars, "the lone agent's interval is drawn"


def test_figure_1_gives_each_budget_axes_of_its_own():
    from nutribench.report.figures import training_curves
    from tests.test_report_builders import synthetic

    long = synthetic(regimes=("run0", "run3"), algos=("ppo",), seeds=(0, 21), train_eps=400, eval_eps=1).assign(
        budget=400
    )
    short = synthetic(regimes=("run3",), algos=("mine",), seeds=(0,), train_eps=8, eval_eps=1, seed=1).assign(budget=8)
    res = training_curves(pd.concat([long, short]))
    titles = [ax.get_title() for ax in res.figure.axes if ax.get_visible()]
    assert titles == ["run3, budget 8 days", "run0, budget 400 days", "run3, budget 400 days"]
    short_ax = next(ax for ax in res.figure.axes if ax.get_title() == "run3, budget 8 days")
    assert short_ax.get_xlim()[1] < 20  # the 8-day run fills its own axis
    labels = {ln.get_label() for ln in short_ax.get_lines()}  # an agent's budget and seeds in its legend entry
    assert "mine (8 days, 1 seed)" in labels and not any(lab.startswith("PPO") for lab in labels)
    # one budget: one panel per regime, as before
    one = training_curves(long)
    assert [ax.get_title() for ax in one.figure.axes if ax.get_visible()] == ["run0", "run3"]


def test_figure_5_with_one_seed_says_why_it_has_no_bars():
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_figure
    from tests.test_report_builders import _day_refs, synthetic

    df = pd.concat(
        [
            synthetic(regimes=("run0", "run3"), algos=("ppo",), seeds=(0, 21, 9), train_eps=1),
            synthetic(regimes=("run0", "run3"), algos=("mine",), seeds=(0,), train_eps=1, seed=3),
        ]
    )
    ev = df[df.phase == "eval"]
    res = aggregate_figure(aggregate_from_eval(ev, _day_refs(df), reps=200), ev=ev)
    why = [n for n in res.notes if "one seed per regime" in n]
    assert len(why) == 1 and why[0].startswith("mine:") and "PPO" not in why[0]
    assert "one seed per regime" in res.figure.get_suptitle()


# ------------------------------------------------------------------ smaller items
def test_progress_lines_stay_whole_without_a_terminal():
    import io
    from types import SimpleNamespace

    from rich.console import Console

    from nutribench.scheduler.progress import LiveView

    out = io.StringIO()
    view = LiveView(35, "2 workers", None, console=Console(file=out, width=60))
    run = SimpleNamespace(
        summary=SimpleNamespace(done=1, failed=0, total=35),
        live={},
        resumed={},
        planned=35,
        attempted=[],
        grid=SimpleNamespace(episodes=20),
    )
    view.start(run)
    view.stop(run)
    head = [ln for ln in out.getvalue().splitlines() if ln.startswith("jobs:")]
    assert (
        head
        and "ETA" in head[-1]
        and not any(ln.strip().startswith(("ETA", "0s", "s")) for ln in out.getvalue().splitlines())
    )


@pytest.mark.slow  # a real DDQN job through the process pool: about 17 s
def test_diagnostics_of_a_ddqn_too_short_to_learn_say_why(tmp_path: Path):
    from nutribench.report.build import ReportError
    from nutribench.report.diagnostics import build_diagnostics

    db = tmp_path / "lab.db"
    grid = ["run", "--regimes", "run0", "--algos", "ddqn", "--seeds", "0", "--episodes", "2", "--eval-episodes", "1"]
    res = CliRunner().invoke(app, [*grid, "--db", str(db), "--workers", "1"], env={"NUTRIBENCH_JOB": ""})
    assert res.exit_code == 0, res.output
    with pytest.raises(
        ReportError,
        match=r"trained 2 days, and ddqn makes its first update only after learning_starts = 10000 steps \(day 200\)",
    ):
        build_diagnostics(db, "ddqn", "run0", out=tmp_path / "out")


def test_report_says_where_it_is_as_each_item_starts(tmp_path: Path):
    from nutribench.report.build import build_report

    db = tmp_path / "lab.db"
    for name in ("never_eat", "eat_some"):
        with nutribench.Recorder(db=db, name=name, regime="run0", seed=0, eval_episodes=1) as rec:
            rec.env.reset()
            for t in range(50):
                rec.env.step(int(name == "eat_some" and t < 3))
            rec.evaluate(lambda obs: 0)
    said: list[str] = []
    paths = build_report(db, tmp_path / "out", figs=[1], tables=["1", "training"], progress=said.append)
    assert said == ["[1/3] figure 1", "[2/3] table 1", "[3/3] table training"] and paths


def test_seeds_paper_names_the_papers_seeds():
    from nutribench.scheduler.grid import GridError, parse_seeds, resolve_grid

    assert parse_seeds("paper") == (0, 21, 9, 2003, 1997)
    grid = resolve_grid(preset="smoke", regimes=["run0"], algos=["ppo"], seeds="paper", episodes=3)
    assert grid.seeds == (0, 21, 9, 2003, 1997) and grid.episodes == 3
    with pytest.raises(GridError, match="named set"):
        parse_seeds("papers")


def test_status_points_to_a_failed_jobs_whole_error_and_the_docs_snippet_reads_it(tmp_path: Path, monkeypatch):
    import re
    import sqlite3

    db = tmp_path / "nutribench.db"
    with nutribench.Recorder(db=db, name="loop", regime="run0", seed=0, eval_episodes=1) as rec:
        rec.evaluate(lambda obs: 0)
    error = "Traceback (most recent call last):\n  File 'x.py', line 1\nValueError: boom"
    with sqlite3.connect(db) as con:
        con.execute("UPDATE jobs SET status = 'failed', failures = 1, error = ?", (error,))
    res = CliRunner().invoke(app, ["status", "--db", str(db)])
    assert "ValueError: boom" in res.output and "jobs table's error column" in res.output
    # docs/failures.md shows how to read the whole text: its snippet prints the traceback
    doc = (REPO / "docs" / "failures.md").read_text()
    (snippet,) = [b for b in re.findall(r"```python\n(.*?)```", doc, re.S) if "read_jobs" in b]
    monkeypatch.chdir(tmp_path)
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(snippet, {})
    assert "Traceback (most recent call last):" in out.getvalue() and "ValueError: boom" in out.getvalue()


def test_the_smaller_docs_items():
    assert "/site/" in (REPO / ".gitignore").read_text().splitlines()  # mkdocs build's output stays untracked
    recorder_doc = nutribench.recorder.__doc__
    assert not any(line.strip() == "::" for line in recorder_doc.splitlines())  # rendered as a stray '::'
    for page in (REPO / "README.md", REPO / "docs" / "getting-started.md"):
        text = page.read_text()
        assert "so that pip takes the CPU build" not in text and "download.pytorch.org/whl/cpu" in text, page
    assert "the whole suite, the learning tests included" not in (REPO / "docs" / "getting-started.md").read_text()


def test_an_agent_with_fewer_seeds_says_so_in_its_table_cells():
    """The results table's cell for an agent on one seed reads 1 (PPO's 3), and the aggregate
    table counts each agent's own runs (2 against PPO's 6) and marks a single seed's interval."""
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_table
    from nutribench.report.tables import table_results
    from tests.test_report_builders import _day_refs

    df = _mixed_budgets()
    df = df[~((df.algo == "mine") & (df.seed != 0))]  # the user's agent on seed 0 only
    res = table_results(df, references=_day_refs(df))
    cells = {(r.regime, r.algorithm): str(r.seeds) for r in res.formatted.itertuples()}
    assert cells == {("run0", "PPO"): "3", ("run0", "mine"): "1", ("run3", "PPO"): "3", ("run3", "mine"): "1"}
    ev = df[df.phase == "eval"]
    agg = aggregate_table(aggregate_from_eval(ev, _day_refs(df), reps=200), ev).formatted
    first = agg[agg["regimes"].str.startswith("all regimes")]
    assert dict(zip(first["algorithm"], first["runs"].astype(str))) == {"PPO": "6", "mine": "2"}
    assert first.loc[first["algorithm"] == "mine", "IQM (%)"].iloc[0].endswith("[single seed]")
