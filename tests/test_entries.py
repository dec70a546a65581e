"""A leaderboard row, and a side of ``compare``, is an entry: an agent config's name, version and
training budget. The published baselines (the paper archives' older versions of the shipped
files, 5000 days) stay beside a user's short run of a shipped agent: neither hides the other,
and the README's pandas line does not average them together."""

from __future__ import annotations

import io
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from tests.conftest import one_error_line
from tests.test_report_builders import _day_refs, synthetic

REPO = Path(__file__).resolve().parents[1]
PAPER_SEEDS = (0, 21, 9, 2003, 1997)
runner = CliRunner()


def _two_ppos():
    """PPO v1 on the reference grid (5000 days, the paper's seeds), and a short run of PPO v2
    (150 days, seed 0) that scores higher: the old rule kept only v2."""
    regs = ("run0", "run3")
    v1 = synthetic(regimes=regs, algos=("ppo",), seeds=PAPER_SEEDS, train_eps=1).assign(budget=5000, algo_version=1)
    v2 = synthetic(regimes=regs, algos=("ppo",), seeds=(0,), train_eps=1, seed=1).assign(budget=150, algo_version=2)
    v2["return"] += 40
    df = pd.concat([v1, v2], ignore_index=True).assign(regime_version=1)
    df["job_id"] = df.groupby(["regime", "algo", "algo_version", "budget", "seed"]).ngroup()
    jobs = pd.DataFrame(
        {
            "id": sorted(df["job_id"].unique()),
            "engine": "sb3",
            "nutribench_version": "0.1.0",
            "git_commit": "",
            "git_dirty": False,
        }
    )
    return df, jobs


def test_two_versions_and_budgets_of_one_agent_are_two_rows_each_scored_on_its_own_runs():
    from nutribench.report.aggregate import run_scores
    from nutribench.report.data import prepare, prepare_entries
    from nutribench.report.leaderboard import leaderboard_rows, leaderboard_table

    df, jobs = _two_ppos()
    assert set(prepare(df).eval["algo_version"]) == {2}  # the figures' choice: the newest version only
    ev = prepare_entries(df).eval
    refs = _day_refs(df, never=-150.0, planner=-50.0)
    rows = leaderboard_rows(ev, refs, jobs, {("ppo", 1): "paper config", ("ppo", 2): "paper config"}, reps=300)
    assert list(zip(rows["algo"], rows["version"], rows["budget"])) == [("ppo", 2, "150"), ("ppo", 1, "5000")]
    v1 = rows[rows["version"] == 1].iloc[0]
    assert v1["flags"] == "" and v1["seeds"] == "0 9 21 1997 2003" and v1["runs"] == 10
    mine = run_scores(ev[ev.algo_version == 1], refs)
    assert v1["share_run3"] == pytest.approx(mine[mine.regime == "run3"]["score"].mean())
    v2 = rows[rows["version"] == 2].iloc[0]
    assert "budget 150 days (reference 5000)" in v2["flags"] and v2["runs"] == 2
    md = leaderboard_table(rows).to_markdown()
    assert "| v1 | 5000 |" in md and "| v2 | 150 |" in md


def _recorded(db: Path, version: int, days: int, seeds=(0, 21)) -> None:
    for seed in seeds:
        with nutribench.Recorder(db=db, name="loop", regime="run0", seed=seed, version=version, eval_episodes=1) as rec:
            for _ in range(days):
                rec.env.reset()
                for t in range(50):
                    rec.env.step(int(version == 2 and t < 3))
            rec.evaluate(lambda obs, v=version: int(v == 2 and obs[:3].sum() < 1.0))


def test_compare_picks_one_entry_by_default_names_it_and_picks_another_when_asked(tmp_path: Path):
    db = tmp_path / "lab.db"
    _recorded(db, version=1, days=2)
    _recorded(db, version=2, days=1, seeds=(0,))
    with nutribench.Recorder(db=db, name="never", regime="run0", seed=0, eval_episodes=1) as rec:
        rec.env.reset()
        for _ in range(50):
            rec.env.step(0)
        rec.evaluate(lambda obs: 0)
    res = runner.invoke(app, ["compare", "never", "loop", "--db", str(db), "--reps", "200", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    # by default the largest budget (v1's 2 days), not the newest version (v2's 1 day)
    assert any(
        n.startswith("loop: compared loop v1, 2 days (by default") and "loop v2, 1 day (loop@v2@1)" in n
        for n in out["notes"]
    ), out["notes"]
    ev = pd.read_sql("select * from episode_metrics where phase = 'eval'", f"sqlite:///{db}")
    v1 = ev[(ev.algo == "loop") & (ev.algo_version == 1) & (ev.seed == 0)]["return"].mean()
    assert out["rows"][0]["b_mean"] == pytest.approx(v1)
    picked = runner.invoke(app, ["compare", "never", "loop@v2", "--db", str(db), "--reps", "200", "--json"])
    assert picked.exit_code == 0, picked.output
    v2 = ev[(ev.algo == "loop") & (ev.algo_version == 2)]["return"].mean()
    assert json.loads(picked.output)["rows"][0]["b_mean"] == pytest.approx(v2)
    both = runner.invoke(app, ["compare", "loop@v2", "loop@2", "--db", str(db), "--reps", "200", "--json"])
    assert both.exit_code == 0, both.output
    assert json.loads(both.output)["a"] == "loop@v2@1" and json.loads(both.output)["b"] == "loop@v1@2"
    line = one_error_line(runner.invoke(app, ["compare", "never", "loop@v3", "--db", str(db)]))
    assert "loop@v3: no such entry" in line and "loop v1, 2 days (loop@v1@2)" in line
    line = one_error_line(runner.invoke(app, ["compare", "never", "loop@x", "--db", str(db)]))
    assert "give an agent as NAME, NAME@vVERSION" in line
    line = one_error_line(runner.invoke(app, ["compare", "loop@v1", "loop@2", "--db", str(db)]))
    assert "both name loop@v1@2" in line


def readme_pandas_line() -> str:
    """The README's one-line pandas query, as printed there."""
    (line,) = [ln for ln in (REPO / "README.md").read_text().splitlines() if ln.startswith('python -c "import pandas')]
    return line


@pytest.mark.slow  # the smallest paper archive imported (about 50 s on the loaded 2-core machine) and two 2-day jobs
def test_own_short_runs_of_shipped_agents_beside_the_imported_paper_archive(tmp_path: Path):
    """The newcomer's scenario: ``nutribench run`` of shipped agents at a tiny budget, then
    ``nutribench db import`` of a paper archive holding an older version of one of them. The
    published rows stay on the leaderboard, ``compare`` finds them, the README's pandas line
    keeps the budgets apart. (The smallest archive, SAC on run4-run6, 3.6 MB; every archive
    is of the same shape.)"""
    archive = REPO / "reports" / "paper" / "data" / "sac-run4-run6.npz"
    db = tmp_path / "nutribench.db"
    cmd = [sys.executable, "-m", "nutribench.cli"]
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}
    run = [*cmd, "run", "--regimes", "run4", "--algos", "sac,mc", "--seeds", "0", "--episodes", "2"]
    run += ["--eval-episodes", "1", "--workers", "1", "--db", str(db)]
    for args in (run, [*cmd, "db", "import", str(archive), "--db", str(db)]):
        res = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stdout + res.stderr
    board = runner.invoke(app, ["leaderboard", "--db", str(db), "--format", "csv", "--reps", "200"])
    assert board.exit_code == 0, board.output
    rows = pd.read_csv(io.StringIO(board.output))
    sac = rows[rows.algo == "sac"].set_index("version")
    assert set(sac.index) == {1, 2}  # the published v1 and the shipped v2 of one's own run
    assert sac.loc[1, "budget"] == 5000 and sac.loc[1, "regimes"] == 3 and pd.isna(sac.loc[1, "flags"])
    assert sac.loc[1, "protocol"] == "paper config" and sac.loc[1, "seeds"] == "0 9 21 1997 2003"
    assert sac.loc[2, "budget"] == 2 and "budget 2 days (reference 5000)" in sac.loc[2, "flags"]
    assert np.isfinite(sac.loc[1, "rank"]) and np.isfinite(sac.loc[2, "rank"])
    md = runner.invoke(app, ["leaderboard", "--db", str(db), "--reps", "200"]).output
    assert "older algo versions left out" not in md
    # compare: by default the published 5000 days, named; the short run when asked
    cmp = runner.invoke(app, ["compare", "mc", "sac", "--db", str(db), "--reps", "200"])
    assert cmp.exit_code == 0, cmp.output
    assert "sac: compared sac v1, 5000 days" in cmp.output and "sac v2, 2 days (sac@v2@2)" in cmp.output
    ev = pd.read_sql("select * from episode_metrics where phase = 'eval'", f"sqlite:///{db}")
    published = ev[(ev.algo == "sac") & (ev.algo_version == 1) & (ev.regime == "run4") & (ev.seed == 0)]
    assert f"{published[published.episode == 0]['return'].mean():.2f}" in cmp.output  # paired on day 0
    own = runner.invoke(app, ["compare", "sac@v2", "sac@v1", "--db", str(db), "--reps", "200"])
    assert own.exit_code == 0 and "sac@v2@2 - sac@v1@5000" in " ".join(own.output.split()), own.output
    # the README's pandas line, run as printed on this database (its print caught): one row per
    # version and budget, the published 5000 days never averaged with one's own 2 days
    code = shlex.split(readme_pandas_line())[2].replace("sqlite:///nutribench.db", f"sqlite:///{db}")
    shown = []
    exec(code, {"print": shown.append})
    (table,) = shown
    assert table.index.names == ["algo", "algo_version", "budget"]
    v1_run4 = ev[(ev.algo == "sac") & (ev.algo_version == 1) & (ev.regime == "run4")]["return"].mean()
    assert table.loc[("sac", 1, 5000), "run4"] == pytest.approx(v1_run4, abs=0.05)
    assert table.loc[("sac", 2, 2), ["run5", "run6"]].isna().all()  # the short run has none: never a blend
    assert sorted(table.loc["sac"].index) == [(1, 5000), (2, 2)]
