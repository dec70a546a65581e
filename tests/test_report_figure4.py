"""Figure 4's memory ablation: beside its pair (PPO, GRU-PPO) it draws the database's copies of
the pair's configs with ``memory = false`` and nothing else changed; without one it is the
pair's figure as before."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from sqlalchemy import select

import nutribench.report.build as build
from nutribench.agents.config import agent_config_content, load_agent_config
from nutribench.report.build import build_report, read_metrics, stored_agent_configs
from nutribench.store import AgentConfig, open_store, session_scope
from tests.test_report_cli import make_db

ROOT = Path(__file__).resolve().parents[1]
NOMEM = ROOT / "reports" / "ladder" / "agents" / "gru_ppo_nomem.toml"


def _bodies() -> dict[str, dict]:
    """The stored content of each config of the test databases: the shipped files, the ladder's
    file without memory, and a memoryless GRU-PPO that differs in more (not an ablation)."""
    nomem = load_agent_config(NOMEM)
    wide = nomem.model_copy(update={"name": "gru_ppo_wide", "hidden_size": 64})
    configs = [load_agent_config("ppo"), load_agent_config("gru_ppo"), nomem, wide]
    return {c.name: agent_config_content(c) for c in configs}


def _db(path: Path, algos: tuple[str, ...]) -> Path:
    make_db(path, regimes=("run0", "run3"), algos=algos, seeds=(0, 1), steps=False, eval_every=0)
    bodies = _bodies()
    store = open_store(path, writer=True)
    with session_scope(store.engine) as s:
        for row in s.scalars(select(AgentConfig)):
            row.body, row.algo = bodies[row.name], bodies[row.name]["algo"]
    store.dispose()
    return path


def _drawn(db: Path, out: Path, monkeypatch, **kw) -> tuple[list[str], str, list[str]]:
    """Figure 4 built by ``build_report``: the configs drawn, the title's first line, the
    legend's agents."""
    made = []
    write = build.write_figure
    monkeypatch.setattr(build, "write_figure", lambda res, *a: made.append(res) or write(res, *a))
    build_report(db, out, figs=[4], reference_episodes=2, **kw)
    (res,) = made
    algos = list(dict.fromkeys(res.data["algo"]))
    legend = [t.get_text() for g in res.figure.legends for t in g.get_texts()]
    legend = [t for t in legend if t and not t.endswith("(reference)")]
    return algos, res.figure.get_suptitle().splitlines()[0], legend


def test_figure_4_draws_gru_ppo_without_memory_beside_the_pair(tmp_path: Path, monkeypatch) -> None:
    db = _db(tmp_path / "ablation.db", ("ppo", "gru_ppo", "gru_ppo_nomem", "gru_ppo_wide"))
    assert build.without_memory(build.DEFAULT_PAIR, stored_agent_configs(db), read_metrics(db)) == {
        "gru_ppo_nomem": "gru_ppo"
    }
    algos, title, legend = _drawn(db, tmp_path / "out", monkeypatch)
    assert algos == ["ppo", "gru_ppo", "gru_ppo_nomem"]  # not gru_ppo_wide: more than memory differs
    assert title == "PPO against GRU-PPO with and without memory: fixed-policy inference across regimes"
    assert legend == ["PPO", "GRU-PPO", "GRU-PPO without memory (gru_ppo_nomem)"]
    assert (tmp_path / "out" / "fig4_ppo_vs_gru_ppo.png").is_file()
    # asked as a pair, the two are the figure (nothing drawn twice)
    algos, title, _ = _drawn(db, tmp_path / "pair", monkeypatch, pair=("gru_ppo", "gru_ppo_nomem"))
    assert algos == ["gru_ppo", "gru_ppo_nomem"] and title.startswith("GRU-PPO against gru_ppo_nomem:")


def test_without_memoryless_runs_figure_4_is_the_pair_as_before(tmp_path: Path, monkeypatch) -> None:
    db = _db(tmp_path / "pair.db", ("ppo", "gru_ppo", "gru_ppo_wide"))
    algos, title, legend = _drawn(db, tmp_path / "out", monkeypatch)
    assert algos == ["ppo", "gru_ppo"]
    assert title == "PPO against GRU-PPO: fixed-policy inference across regimes"
    assert legend == ["PPO", "GRU-PPO"]


def test_a_memoryless_config_without_evaluation_episodes_is_not_drawn() -> None:
    bodies = _bodies()

    class Stored:
        def __init__(self, body):
            self.body = body

        def model_dump(self, mode: str = "json") -> dict:
            return self.body

    stored = {n: Stored(b) for n, b in bodies.items()}
    evaluated = pd.DataFrame({"phase": ["eval", "eval", "train"], "algo": ["ppo", "gru_ppo", "gru_ppo_nomem"]})
    assert build.without_memory(("ppo", "gru_ppo"), stored, evaluated) == {}
    assert build.without_memory(("ppo", "gru_ppo"), stored) == {"gru_ppo_nomem": "gru_ppo"}
    assert build.without_memory(("ppo", "gru_ppo"), None) == {}


@pytest.mark.parametrize("pair", [("ppo",), ("ppo", "ppo")])
def test_a_bad_pair_is_one_line(pair) -> None:
    with pytest.raises(build.ReportError, match="two different agent configs"):
        build.check_pair(pair, build.DEFAULT_PAIR)


@pytest.mark.slow  # about 40 s: three jobs through the scheduler, then the report
def test_nutribench_run_of_the_ladder_s_agents_then_figure_4_draws_the_three(tmp_path: Path, monkeypatch) -> None:
    """The ladder's agent folder through ``nutribench run`` (batched engine, 2 days): the
    database stores gru_ppo_nomem's content with ``memory = false`` and gru_ppo's without the
    key (its hash as shipped), and ``nutribench report --fig 4`` draws PPO, GRU-PPO and
    GRU-PPO without memory."""
    from typer.testing import CliRunner

    from nutribench.agents.config import agent_config_sha256
    from nutribench.cli import app
    from tests.conftest import run_cli_args

    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(ROOT / "reports" / "ladder" / "agents"))
    db = tmp_path / "ladder.db"
    args = run_cli_args(db, "--engine", "batched", "--workers", "1", algos="ppo,gru_ppo,gru_ppo_nomem", episodes=2)
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    store = open_store(db)
    with session_scope(store.engine) as s:
        rows = {r.name: r for r in s.scalars(select(AgentConfig))}
        assert rows["gru_ppo_nomem"].body["memory"] is False and "memory" not in rows["gru_ppo"].body
        assert rows["gru_ppo"].sha256 == agent_config_sha256(load_agent_config("gru_ppo"))
    store.dispose()
    algos, title, legend = _drawn(db, tmp_path / "out", monkeypatch)
    assert algos == ["ppo", "gru_ppo", "gru_ppo_nomem"] and "with and without memory" in title
    report = ["report", "--fig", "4", "--db", str(db), "--out", str(tmp_path / "cli"), "--reference-episodes", "2"]
    result = CliRunner().invoke(app, report)
    assert result.exit_code == 0 and (tmp_path / "cli" / "fig4_ppo_vs_gru_ppo.png").is_file(), result.output
