"""``nutribench report`` end to end on small synthetic databases built through the ORM."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.report.build import FIGURES, TABLES, build_report, load_report_data, simple_policy_references
from nutribench.store import AgentConfig, Episode, EvalStep, Job, RegimeConfig, open_store, session_scope, utcnow
from nutribench.store.models import ValidationEpisode
from tests.conftest import one_error_line

H = 50  # horizon of the shipped reward config
REF_EPISODES = ["--reference-episodes", "4"]  # the simple-policy references, kept cheap
runner = CliRunner()


def make_db(
    path: Path,
    regimes=("run0", "run3"),
    algos=("ppo", "gru_ppo"),
    seeds=(0, 1),
    budgets=(30,),
    eval_eps: int = 5,
    steps: bool = True,
    rng_seed: int = 0,
    eval_every: int = 10,
) -> Path:
    """A results database with one done job per regime x algo x seed x budget: ``budget``
    training episodes, ``eval_eps`` evaluation episodes (and their steps), and an evaluation
    during training on 3 validation days every ``eval_every`` days (0: none)."""
    rng = np.random.default_rng(rng_seed)
    store = open_store(path, writer=True)
    now = utcnow()
    with session_scope(store.engine) as s:
        regs = {
            r: RegimeConfig(name=r, version=1, sha256="0" * 64, body={}, source=None, created_at=now) for r in regimes
        }
        ags = {
            a: AgentConfig(
                name=a,
                algo=a,
                version=1,
                sha256="1" * 64,
                body={"name": a, "algo": a, "version": 1},
                source=None,
                created_at=now,
            )
            for a in algos
        }
        s.add_all([*regs.values(), *ags.values()])
        s.flush()
        for r in regimes:
            for a in algos:
                for seed in seeds:
                    for budget in budgets:
                        job = Job(
                            regime_id=regs[r].id,
                            agent_config_id=ags[a].id,
                            seed=seed,
                            episodes=budget,
                            eval_episodes=eval_eps,
                            status="done",
                            attempt=1,
                            failures=0,
                            episodes_done=budget,
                            created_at=now,
                        )
                        s.add(job)
                        s.flush()
                        for phase, n in (("train", budget), ("eval", eval_eps)):
                            for e in range(n):
                                s.add(
                                    Episode(
                                        job_id=job.id,
                                        phase=phase,
                                        episode=e,
                                        ret=float(rng.normal(-80 + e, 10)),
                                        foods=int(rng.integers(0, 12)),
                                        final_distance=float(rng.random() * 3),
                                        overshoot_ratio=float(rng.random()),
                                        final_C=1.0,
                                        final_F=1.0,
                                        final_P=1.0,
                                        first_overshoot_step=None,
                                        entropy=None,
                                    )
                                )
                        for day in range(eval_every, budget + 1, eval_every) if eval_every else ():
                            for e in range(3):
                                s.add(
                                    ValidationEpisode(
                                        job_id=job.id,
                                        train_day=day,
                                        episode=e,
                                        ret=float(rng.normal(-60 + day, 10)),
                                        foods=int(rng.integers(0, 12)),
                                        final_distance=float(rng.random() * 3),
                                        overshoot_ratio=float(rng.random()),
                                        final_C=1.0,
                                        final_F=1.0,
                                        final_P=1.0,
                                        never=-20.0,
                                        planner=-5.0 - e,
                                    )
                                )
                        if steps:
                            for e in range(eval_eps):
                                action = rng.random(H) < 0.1
                                absorbed = np.cumsum(
                                    rng.random((H, 3)) * 0.05 * action[:, None].repeat(3, 1).cumsum(0).clip(0, 1),
                                    axis=0,
                                )
                                for t in range(H):
                                    s.add(
                                        EvalStep(
                                            job_id=job.id,
                                            episode=e,
                                            step=t + 1,
                                            food=int(rng.integers(0, 10)),
                                            action=int(action[t]),
                                            C=float(absorbed[t, 0]),
                                            F=float(absorbed[t, 1]),
                                            P=float(absorbed[t, 2]),
                                            reward=-1.0,
                                        )
                                    )
    store.dispose()
    return path


@pytest.fixture(scope="module")
def full_db(tmp_path_factory) -> Path:
    return make_db(tmp_path_factory.mktemp("db") / "full.db")


def invoke(*args: str):
    return runner.invoke(app, ["report", *args])


@pytest.mark.slow
def test_report_all_writes_every_file(full_db: Path, tmp_path: Path):
    out = tmp_path / "reports"
    result = invoke("--all", "--db", str(full_db), "--out", str(out), *REF_EPISODES)
    assert result.exit_code == 0, result.output
    expected = {f"{stem}.{ext}" for stem in FIGURES.values() for ext in ("png", "pdf")}
    # the config tables of the agents it holds results of (PPO, GRU-PPO), not of MC, DDQN, SAC
    held = [stem for stem in TABLES.values() if stem not in ("table2_mc", "table3_ddqn", "table5_sac")]
    expected |= {f"{stem}.{ext}" for stem in held for ext in ("md", "tex", "csv")}
    expected |= {"index.html"}  # --all also writes the one page to look at
    expected |= {f"leaderboard.{ext}" for ext in ("md", "tex", "csv")}  # and the leaderboard, a section of it
    assert {p.name for p in out.iterdir()} == expected
    printed = {Path(line.strip()).name for line in result.stdout.splitlines() if line.strip()}
    assert printed == expected
    for p in out.iterdir():
        assert p.stat().st_size > 200, p
    assert (out / "fig1_training_return.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "fig3_eval_across_regimes.pdf").read_bytes()[:5] == b"%PDF-"
    # Tables 2-6 come from the agent config files: Table 4 is PPO's
    assert "PPO configuration" in (out / "table4_ppo.md").read_text()
    assert "clip_range" in (out / "table4_ppo.csv").read_text()


def test_results_table_equals_pandas_on_the_view(full_db: Path, tmp_path: Path):
    result = invoke("--table", "results", "--db", str(full_db), "--out", str(tmp_path))
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "table_results.csv")
    ev = pd.read_sql("select * from episode_metrics where phase = 'eval'", f"sqlite:///{full_db}")
    g = ev.groupby(["regime", "algo"])
    assert len(table) == g.ngroups == 4
    for _, row in table.iterrows():
        cell = g.get_group((row["regime"], row["algo"]))
        assert row["episodes"] == len(cell) == 10
        for m in ("return", "foods", "final_distance", "overshoot_ratio"):
            assert row[f"{m}_mean"] == pytest.approx(cell[m].mean())
            assert row[f"{m}_sem"] == pytest.approx(cell[m].std(ddof=1) / np.sqrt(len(cell)))
    md = (tmp_path / "table_results.md").read_text()
    first = table.iloc[0]
    assert f"{first['return_mean']:.2f} ± {first['return_sem']:.2f}" in md


@pytest.mark.slow
def test_figure_and_table_selection(full_db: Path, tmp_path: Path):
    result = invoke(
        "--fig", "1,3", "--fig", "2", "--table", "1", "--db", str(full_db), "--out", str(tmp_path), *REF_EPISODES
    )
    assert result.exit_code == 0, result.output
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(
        [f"{FIGURES[f]}.{e}" for f in (1, 2, 3) for e in ("png", "pdf")]
        + [f"table1_regimes.{e}" for e in ("md", "tex", "csv")]
    )


def test_table1_needs_no_database(tmp_path: Path):
    result = invoke("--table", "1", "--db", str(tmp_path / "absent.db"), "--out", str(tmp_path / "r"))
    assert result.exit_code == 0, result.output
    assert "| run6 |" in (tmp_path / "r" / "table1_regimes.md").read_text()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--fig", "7"], "--fig 7: the figures are 1, 2, 3, 4, 5, 6"),
        (["--fig", "learn"], "--fig learn: the figures are 1, 2, 3, 4, 5, 6"),
        (["--fig", "1,x"], "--fig x"),
        (["--table", "7"], "--table 7"),
        ([], "nothing to build"),
        (["--trajectory", "--algo", "ppo"], "--trajectory needs --regime, --seed"),
        (["--fig", "1", "--algo", "ppo"], "add --trajectory"),
    ],
)
def test_bad_values_one_line(full_db: Path, tmp_path: Path, args: list[str], message: str):
    line = one_error_line(invoke(*args, "--db", str(full_db), "--out", str(tmp_path)))
    assert message in line
    assert not any(tmp_path.iterdir())


def test_empty_database_one_line(tmp_path: Path):
    schema_only = tmp_path / "schema.db"
    open_store(schema_only, writer=True).dispose()
    line = one_error_line(invoke("--all", "--db", str(schema_only), "--out", str(tmp_path / "r")))
    assert "no finished episodes" in line
    empty_file = tmp_path / "empty.db"
    empty_file.touch()
    line = one_error_line(invoke("--fig", "3", "--db", str(empty_file), "--out", str(tmp_path / "r")))
    assert "empty database" in line
    assert not (tmp_path / "r").exists()


def test_missing_database_one_line(tmp_path: Path):
    line = one_error_line(invoke("--fig", "1", "--db", str(tmp_path / "nope.db"), "--out", str(tmp_path / "r")))
    assert "no results database at" in line and "nope.db" in line


@pytest.mark.slow
def test_partial_database_still_draws(tmp_path: Path):
    db = make_db(tmp_path / "partial.db", regimes=("run3",), algos=("ppo",), seeds=(7,), steps=False)
    out = tmp_path / "r"
    result = invoke("--all", "--db", str(db), "--out", str(out), *REF_EPISODES)
    assert result.exit_code == 0, result.output
    for n, stem in FIGURES.items():
        assert (out / f"{stem}.png").exists() == (n != 4), stem
    # one seed: the learner's line has no band; Figure 4 (PPO against GRU-PPO) is skipped, saying why
    assert "skipped: figure 4: no evaluation episodes for GRU-PPO in the database" in result.output
    from nutribench.report.build import ReportError, build_figure

    data = load_report_data(db)
    fig1 = build_figure(1, data)
    assert fig1.data["sem"].isna().all()
    assert not any(ax.collections for ax in fig1.figure.axes if ax.get_visible())
    with pytest.raises(ReportError, match="no evaluation episodes for GRU-PPO"):
        build_figure(4, data, reference_episodes=4)


@pytest.mark.slow
def test_all_skips_what_the_data_cannot_support(tmp_path: Path):
    db = make_db(tmp_path / "sac.db", regimes=("run0",), algos=("sac",), seeds=(0,), steps=False)
    out = tmp_path / "r"
    result = invoke("--all", "--db", str(db), "--out", str(out), *REF_EPISODES)
    assert result.exit_code == 0, result.output
    assert "skipped: figure 4: no evaluation episodes for PPO, GRU-PPO" in result.output
    assert not (out / f"{FIGURES[4]}.png").exists() and (out / f"{FIGURES[3]}.png").exists()
    line = one_error_line(invoke("--fig", "4", "--db", str(db), "--out", str(tmp_path / "r2")))
    assert "no evaluation episodes for PPO, GRU-PPO" in line


def test_largest_budget_is_used_and_noted(tmp_path: Path):
    db = make_db(
        tmp_path / "budgets.db", regimes=("run0",), algos=("ppo",), seeds=(0, 1), budgets=(10, 30), steps=False
    )
    data = load_report_data(db)
    assert set(data.metrics["budget"]) == {30}
    assert data.metrics.groupby("seed")["job_id"].nunique().tolist() == [1, 1]
    assert data.notes == ["PPO/run0: budgets 10, 30 in the database, the largest (30) shown"]
    from nutribench.report.build import build_figure

    assert (
        "note: PPO/run0: budgets 10, 30 in the database, the largest (30) shown"
        in build_figure(1, data).figure.get_suptitle()
    )
    paths = build_report(db, tmp_path / "r", figs=[1], tables=["results"], reference_episodes=4)
    assert {p.suffix for p in paths} == {".png", ".pdf", ".md", ".tex", ".csv"}
    table = pd.read_csv(tmp_path / "r" / "table_results.csv")
    assert table["episodes"].tolist() == [10]  # 2 seeds x 5 eval episodes, the budget-10 jobs left out
    assert "budgets 10, 30 in the database" in (tmp_path / "r" / "table_results.md").read_text().splitlines()[0]


def test_simple_policy_references_are_deterministic():
    a = simple_policy_references(["run0", "run6"], episodes=4)
    b = simple_policy_references(["run0", "run6"], episodes=4)
    pd.testing.assert_frame_equal(a, b)
    assert len(a) == 8 and set(a["policy"]) == {"random", "never", "always", "planner"}
    never = a[a["policy"] == "never"].iloc[0]
    assert never["foods"] == 0 and never["overshoot_ratio"] == 0
    logged: list[str] = []
    c = simple_policy_references(["run0", "no_such_regime"], episodes=4, log=logged.append)
    assert set(c["regime"]) == {"run0"} and "no_such_regime" in logged[0]


def test_trajectory_writes_png(full_db: Path, tmp_path: Path):
    out = tmp_path / "r"
    result = invoke(
        "--trajectory",
        "--algo",
        "ppo",
        "--regime",
        "run3",
        "--seed",
        "1",
        "--episode",
        "2",
        "--db",
        str(full_db),
        "--out",
        str(out),
    )
    assert result.exit_code == 0, result.output
    png = out / "trajectory_run3_ppo_seed1_ep2.png"
    assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size > 10_000
    assert str(png) in result.stdout.replace("\n", "")
    line = one_error_line(
        invoke(
            "--trajectory", "--algo", "ppo", "--regime", "run3", "--seed", "9", "--db", str(full_db), "--out", str(out)
        )
    )
    assert "no evaluation steps for ppo/run3 seed 9 episode 0" in line and "available:" in line
    # a few cells, and how to see all of them (it printed every combination in one long line)
    assert line.count("/run") <= 1 + 4 and "SELECT DISTINCT algo, regime, seed" in line and len(line) < 400, line
