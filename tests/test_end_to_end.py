"""The README's main command for real: `nutribench run --preset smoke` trains every regime x
algorithm (seed 0, 20 days) into a fresh SQLite file, then `status`, pandas on the view,
`report --all` and a trajectory read what it wrote. About 1.5 minutes on 2 cores."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from nutribench.agents.api import TrainedAgent
from nutribench.agents.registry import paper_names
from nutribench.config import list_regimes

ALGOS = tuple(paper_names())

NUTRIBENCH = str(Path(sys.executable).parent / "nutribench")
EPISODES, EVAL, H = 20, 5, 50

pytestmark = pytest.mark.slow  # the smoke grid trains every regime x algorithm in a subprocess: minutes


def nutribench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([NUTRIBENCH, *args], cwd=cwd, capture_output=True, text=True, timeout=900)


@pytest.fixture(scope="module")
def smoke(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A working directory in which the smoke grid ran with the default database."""
    work = tmp_path_factory.mktemp("smoke")
    res = nutribench("run", "--preset", "smoke", cwd=work)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert (work / "nutribench.db").is_file()
    return work


def test_every_job_and_episode_is_in_the_view(smoke: Path):
    df = pd.read_sql("SELECT * FROM episode_metrics", f"sqlite:///{smoke / 'nutribench.db'}")
    jobs = len(list_regimes()) * len(ALGOS)
    assert len(df) == jobs * (EPISODES + EVAL)
    counts = df.groupby(["regime", "algo", "phase"]).size()
    assert set(counts.index.get_level_values("algo")) == set(ALGOS)
    assert (counts.xs("train", level="phase") == EPISODES).all()
    assert (counts.xs("eval", level="phase") == EVAL).all()
    assert df["return"].lt(0).all() and df["foods"].between(0, H).all()
    # paired evaluation: seed 0's five days are the same for every algorithm in a regime
    steps = pd.read_sql("SELECT job_id, episode, step, food FROM eval_steps", f"sqlite:///{smoke / 'nutribench.db'}")
    assert len(steps) == jobs * EVAL * H
    per_job = steps.sort_values(["episode", "step"]).groupby("job_id")["food"].apply(tuple)
    assert per_job.nunique() == 1


def test_jobs_carry_their_metadata_and_model(smoke: Path):
    jobs = pd.read_sql("SELECT * FROM jobs", f"sqlite:///{smoke / 'nutribench.db'}")
    assert (jobs["status"] == "done").all()
    for col in (
        "host",
        "python_version",
        "torch_version",
        "sb3_version",
        "nutribench_version",
        "started_at",
        "finished_at",
        "wall_seconds",
        "model_path",
    ):
        assert jobs[col].notna().all(), col
    path = (
        smoke / jobs["model_path"].iloc[0]
        if not Path(jobs["model_path"].iloc[0]).is_absolute()
        else Path(jobs["model_path"].iloc[0])
    )
    agent = TrainedAgent.load(path)
    assert agent.algo in ALGOS


def test_rerun_does_no_work_and_status_sees_everything_done(smoke: Path):
    res = nutribench("run", "--preset", "smoke", cwd=smoke)
    assert res.returncode == 0 and "0 done" in res.stderr and "35 already done" in res.stderr
    res = nutribench("status", "--json", cwd=smoke)
    assert res.returncode == 0
    data = json.loads(res.stdout)
    assert data["totals"]["done"] == 35 and data["totals"]["pending"] == 0


def test_report_all_and_a_trajectory_from_the_smoke_database(smoke: Path):
    res = nutribench("report", "--all", cwd=smoke)
    assert res.returncode == 0, res.stderr
    out = smoke / "reports"
    for stem in ("fig1_training_return", "fig2_training_foods", "fig3_eval_across_regimes", "fig4_ppo_vs_gru_ppo"):
        assert (out / f"{stem}.png").stat().st_size > 10_000 and (out / f"{stem}.pdf").is_file()
    assert (out / "table_results.csv").is_file() and (out / "table1_regimes.md").is_file()
    res = nutribench("report", "--trajectory", "--algo", "ppo", "--regime", "run5", "--seed", "0", cwd=smoke)
    assert res.returncode == 0, res.stderr
    assert (out / "trajectory_run5_ppo_seed0_ep0.png").is_file()
