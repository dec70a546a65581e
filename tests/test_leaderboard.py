"""``nutribench leaderboard``: every agent ranked by the IQM of its share of the never ->
planner gap over the regimes it covers, budgets, seeds and coverage flagged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import nutribench
from nutribench.cli import app
from tests.conftest import one_error_line
from tests.test_report_builders import _day_refs, synthetic

PAPER_SEEDS = (0, 21, 9, 2003, 1997)


def _board_data():
    """PPO on the reference grid; a plug-in at 50 days on every regime; a recorded agent on
    two regimes with one seed."""
    regs = ("run0", "run3", "run6")
    ppo = synthetic(regimes=regs, algos=("ppo",), seeds=PAPER_SEEDS, train_eps=1).assign(budget=5000)
    plug = synthetic(regimes=regs, algos=("qrdqn_mine",), seeds=PAPER_SEEDS, train_eps=1, seed=1).assign(budget=50)
    rec = synthetic(regimes=("run0", "run6"), algos=("loop",), seeds=(0,), train_eps=1, seed=2).assign(budget=50)
    df = pd.concat([ppo, plug, rec], ignore_index=True)
    df.loc[df.algo == "qrdqn_mine", "return"] += 30  # the plug-in does best, the recorded loop worst
    df.loc[df.algo == "loop", "return"] -= 30
    df["job_id"] = df.groupby(["regime", "algo", "seed"]).ngroup()
    jobs = pd.DataFrame(
        {
            "id": sorted(df["job_id"].unique()),
            "engine": "sb3",
            "nutribench_version": "0.1.0",
            "git_commit": "abcdef0123",
            "git_dirty": False,
        }
    )
    df["algo_version"] = 1
    return df[df.phase == "eval"], _day_refs(df, never=-150.0, planner=-50.0), jobs


def test_rows_are_ranked_by_the_iqm_over_the_regimes_each_covers_and_flag_what_departs():
    from nutribench.report.aggregate import interval_estimates, run_scores, score_set
    from nutribench.report.leaderboard import leaderboard_rows, leaderboard_table

    ev, refs, jobs = _board_data()
    protocol = {"ppo": "paper config", "qrdqn_mine": "plug-in", "loop": "recorded"}
    rows = leaderboard_rows(ev, refs, jobs, protocol, reps=300)
    assert list(rows["algo"]) == ["qrdqn_mine", "ppo", "loop"]
    assert list(rows["rank"]) == [1, 2, 3]
    assert list(rows["iqm"]) == sorted(rows["iqm"], reverse=True)
    # the IQM and its interval are the aggregate statistics' own, over the agent's regimes
    scores = run_scores(ev, refs)
    iv = interval_estimates(score_set(scores, ["run0", "run3", "run6"], ["ppo"]), reps=300)
    ppo = rows.set_index("algo").loc["ppo"]
    assert (ppo["iqm"], ppo["iqm_lo"], ppo["iqm_hi"]) == pytest.approx(
        tuple(iv.loc[iv["aggregate"] == "iqm", ["point", "lo", "hi"]].iloc[0])
    )
    assert ppo["share_run3"] == pytest.approx(
        scores[(scores.algo == "ppo") & (scores.regime == "run3")]["score"].mean()
    )
    flags = rows.set_index("algo")["flags"]
    assert flags["ppo"] == ""  # the reference grid
    assert "budget 50 days (reference 5000)" in flags["qrdqn_mine"] and "seeds" not in flags["qrdqn_mine"]
    assert "seeds 0 (reference 0, 21, 9, 2003, 1997)" in flags["loop"]
    assert "ranked on run0, run6 only: no run3" in flags["loop"]
    loop = rows.set_index("algo").loc["loop"]
    assert loop["regimes"] == 2 and np.isnan(loop["share_run3"]) and np.isnan(loop["iqm_lo"])
    table = leaderboard_table(rows)
    md = table.to_markdown()
    assert "| 1 | qrdqn_mine |" in md and "[single seed]" in md and "2/3" in md and "abcdef0" in md
    assert "budget (days)" in md and "plug-in" in md and "recorded" in md
    assert table.to_csv().splitlines()[0].startswith("rank,algo,protocol,iqm,iqm_lo,iqm_hi")
    assert "\\caption" in table.to_latex()
    # the caption names the reference grid's budget, not a placeholder
    assert "Reference grid: 5000 training days" in table.title and "{" not in table.title


def test_a_row_whose_seeds_scored_alike_prints_no_spread_not_single_seed():
    """Five seeds that score alike on each regime give an interval of zero width: the row
    says ``[no spread]`` (it has several seeds); ``[single seed]`` stays for one seed."""
    from nutribench.report.leaderboard import leaderboard_rows, leaderboard_table

    ev, refs, jobs = _board_data()
    flat = ev.algo == "ppo"
    ev = ev.copy()
    ev.loc[flat, "return"] = ev.loc[flat, "regime"].map({"run0": -60.0, "run3": -100.0, "run6": -120.0})
    rows = leaderboard_rows(ev, refs, jobs, {"ppo": "paper config", "qrdqn_mine": "plug-in", "loop": "recorded"})
    ppo = rows.set_index("algo").loc["ppo"]
    assert ppo["iqm_lo"] == ppo["iqm_hi"] == pytest.approx(ppo["iqm"])
    printed = leaderboard_table(rows).formatted.set_index("agent")["IQM share of gap (%) [95% CI]"]
    assert printed["PPO"] == f"{round(100 * ppo['iqm'])} [no spread]"
    assert printed["loop"].endswith("[single seed]")  # one seed per regime
    assert printed["qrdqn_mine"].endswith("]") and "spread" not in printed["qrdqn_mine"]


def _recorded_db(db: Path, agents: dict[str, tuple[int, ...]], regimes=("run0",)) -> None:
    for name, seeds in agents.items():
        for regime in regimes:
            for seed in seeds:
                with nutribench.Recorder(db=db, name=name, regime=regime, seed=seed, eval_episodes=1) as rec:
                    rec.env.reset()
                    for t in range(50):
                        rec.env.step(int(name == "eat_early" and t < 3))
                    rec.evaluate(lambda obs, n=name: int(n == "eat_early" and obs[:3].sum() < 1.0))


def test_cli_prints_writes_and_reads_a_folder_of_archives(tmp_path: Path):
    db = tmp_path / "lab.db"
    _recorded_db(db, {"eat_early": (0, 21), "never_eat": (0,)})
    res = CliRunner().invoke(app, ["leaderboard", "--db", str(db), "--out", str(tmp_path / "out"), "--reps", "200"])
    assert res.exit_code == 0, res.output
    assert "| 1 | eat_early |" in res.output and "| 2 | never_eat |" in res.output
    assert "budget 1 day (reference 5000)" in res.output and "recorded" in res.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "leaderboard.csv",
        "leaderboard.md",
        "leaderboard.tex",
    ]
    csv = CliRunner().invoke(app, ["leaderboard", "--db", str(db), "--format", "csv", "--reps", "200"])
    assert csv.exit_code == 0 and csv.output.startswith("rank,algo,protocol")
    # the same from archives: each agent exported to its own file, the folder read back
    folder = tmp_path / "shared"
    folder.mkdir()
    for name in ("eat_early", "never_eat"):
        r = CliRunner().invoke(app, ["db", "export", str(folder / f"{name}.npz"), "--db", str(db), "--algos", name])
        assert r.exit_code == 0, r.output
    again = CliRunner().invoke(app, ["leaderboard", "--archives", str(folder), "--reps", "200"])
    assert again.exit_code == 0, again.output
    table = lambda out: [ln for ln in out.splitlines() if ln.startswith("| ")]  # noqa: E731
    assert table(again.output) == table(res.output)


def test_cli_refuses_in_one_line(tmp_path: Path):
    (tmp_path / "empty").mkdir()
    line = one_error_line(CliRunner().invoke(app, ["leaderboard", "--archives", str(tmp_path / "empty")]))
    assert "no archives" in line
    line = one_error_line(CliRunner().invoke(app, ["leaderboard", "--db", str(tmp_path / "none.db")]))
    assert "none.db" in line
    line = one_error_line(CliRunner().invoke(app, ["leaderboard", "--db", str(tmp_path / "x.db"), "--format", "html"]))
    assert "--format html" in line


@pytest.mark.slow  # every figure and table of a report: about 20 s
def test_the_report_page_has_a_leaderboard_section(tmp_path: Path):
    from nutribench.report.build import build_report

    db = tmp_path / "lab.db"
    _recorded_db(db, {"eat_early": (0, 21), "never_eat": (0,)})
    paths = build_report(db, tmp_path / "out", all=True, reference_episodes=2)
    assert {"leaderboard.md", "leaderboard.csv", "leaderboard.tex", "index.html"} <= {p.name for p in paths}
    page = (tmp_path / "out" / "index.html").read_text()
    assert '<section id="leaderboard">' in page and "Leaderboard: every agent ranked" in page
    assert "<td>eat_early</td>" in page and "budget 1 day (reference 5000)" in page


def test_the_protocol_tells_paper_tuned_and_variant_configs_apart() -> None:
    import pandas as pd

    from nutribench.agents.config import agent_config_content, agent_config_sha256, load_agent_config
    from nutribench.report.leaderboard import protocols

    paper = load_agent_config("ppo")
    tuned = paper.model_copy(
        update={
            "name": "ppo_tuned",
            "learning_rate": 3e-4,
            "description": "tuned by nutribench tune: study 's', trial 3",
        }
    )
    variant = paper.model_copy(update={"name": "ppo_lr", "learning_rate": 3e-4})
    rows = [
        {"name": c.name, "version": c.version, "sha256": agent_config_sha256(c), "body": agent_config_content(c)}
        for c in (paper, tuned, variant)
    ]
    assert protocols(pd.DataFrame(rows)) == {"ppo": "paper config", "ppo_tuned": "tuned", "ppo_lr": "variant"}


def test_an_older_version_that_differs_only_in_its_description_is_the_paper_config() -> None:
    """A shipped file whose new version rewrote only its description leaves the results of the
    older version (an archive of reports/paper/) paper configs; a changed setting does not."""
    import pandas as pd

    from nutribench.agents.config import agent_config_content, agent_config_sha256, load_agent_config
    from nutribench.report.leaderboard import protocols

    shipped = load_agent_config("mc")
    older = shipped.model_copy(update={"version": shipped.version - 1, "description": "an older text"})
    changed = older.model_copy(update={"learning_rate": 1e-3})
    for cfg, protocol in ((older, "paper config"), (changed, "variant")):
        body = agent_config_content(cfg) | {"max_grad_norm": "inf"}  # as JSON stores it
        row = {"name": "mc", "version": cfg.version, "sha256": agent_config_sha256(cfg), "body": body}
        assert protocols(pd.DataFrame([row])) == {"mc": protocol}


def test_a_share_just_below_zero_reads_0_not_minus_0() -> None:
    from nutribench.report.leaderboard import _pct

    assert [_pct(v) for v in (-0.004, 0.0, 0.004, -0.006, 0.555, float("nan"))] == ["0", "0", "0", "-1", "56", "n/a"]
