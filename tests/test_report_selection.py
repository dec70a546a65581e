"""``nutribench report`` for any set of agent configs: --algos, --pair, colours stable by name,
the budget and seeds on every figure, and a table for each config the database holds."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import to_hex
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.report.build import build_figure, load_report_data
from nutribench.report.figure_parts import budget_seeds_text, seed_list
from nutribench.report.palette import BUILTIN_COLORS, BUILTIN_ORDER, MIN_DISTANCE, colors, distance, label, order
from nutribench.store import AgentConfig, Episode, Job, RegimeConfig, open_store, session_scope, utcnow
from tests.conftest import one_error_line

REF = ["--reference-episodes", "2"]  # the simple-policy references of figures 3/4, kept cheap
EXTERNAL = {
    "name": "a2c_mine",
    "algo": "external",
    "version": 1,
    "entry_point": "mypkg.agents:make_agent",
    "params": {"lr": 0.0007, "hidden": [64, 64], "n_steps": 5},
}
VARIANT = {"name": "ppo_big", "algo": "ppo", "version": 2, "net_arch": [512, 256], "learning_rate": 0.0003}
runner = CliRunner()


def _config(name: str, body: dict | None = None) -> dict:
    return body or {"name": name, "algo": name, "version": 1}


def make_db(
    path: Path, configs: dict[str, tuple[dict, tuple[int, ...], int]], regimes=("run0", "run3"), eval_eps: int = 3
) -> Path:
    """A results database as tests/test_report_cli.py's make_db builds one (through the ORM),
    but each config with its own stored body, seeds and training budget; no evaluation steps."""
    rng = np.random.default_rng(0)
    store = open_store(path, writer=True)
    now = utcnow()
    with session_scope(store.engine) as s:
        regs = {
            r: RegimeConfig(name=r, version=1, sha256="0" * 64, body={}, source=None, created_at=now) for r in regimes
        }
        ags = {
            n: AgentConfig(
                name=n, algo=b["algo"], version=b["version"], sha256="1" * 64, body=b, source=None, created_at=now
            )
            for n, (b, _, _) in configs.items()
        }
        s.add_all([*regs.values(), *ags.values()])
        s.flush()
        for r in regimes:
            for n, (_, seeds, budget) in configs.items():
                for seed in seeds:
                    job = Job(
                        regime_id=regs[r].id,
                        agent_config_id=ags[n].id,
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
                    for phase, count in (("train", budget), ("eval", eval_eps)):
                        s.add_all(
                            Episode(
                                job_id=job.id,
                                phase=phase,
                                episode=e,
                                ret=float(rng.normal(-60 + e, 5)),
                                foods=int(rng.integers(0, 12)),
                                final_distance=float(rng.random() * 3),
                                overshoot_ratio=float(rng.random()),
                                final_C=1.0,
                                final_F=1.0,
                                final_P=1.0,
                                first_overshoot_step=None,
                                entropy=None,
                            )
                            for e in range(count)
                        )
    store.dispose()
    return path


@pytest.fixture(scope="module")
def db(tmp_path_factory) -> Path:
    """PPO, SAC, GRU-PPO (budget 20, seeds 0 and 1), a plug-in agent a2c_mine (budget 30,
    seeds 0-2) and a PPO variant ppo_big (budget 20, seeds 0 and 1)."""
    base = ((0, 1), 20)
    return make_db(
        tmp_path_factory.mktemp("sel") / "sel.db",
        {
            "ppo": (_config("ppo"), *base),
            "sac": (_config("sac"), *base),
            "gru_ppo": (_config("gru_ppo"), *base),
            "a2c_mine": (EXTERNAL, (0, 1, 2), 30),
            "ppo_big": (VARIANT, *base),
        },
    )


def invoke(db: Path, out: Path, *args: str):
    return runner.invoke(app, ["report", "--db", str(db), "--out", str(out), *args])


def figure_text(res) -> str:
    """Every text of the figure (title, caption, notes), whitespace made single spaces."""
    return " ".join(" ".join(t.get_text().split()) for t in res.figure.texts)


def legend_labels(res) -> list[str]:
    """The legend entries' agent names (an entry may add its budget and seeds: ``PPO (20 days, 2 seeds)``)."""
    return [_name(t.get_text()) for leg in res.figure.legends for t in leg.get_texts() if t.get_text()]


def _name(label: str) -> str:
    return re.sub(r" \(\d+ days(, \d+ seeds?)?\)$", "", label)


def line_colors(res) -> dict[str, str]:
    """Legend label -> colour of the lines drawn, over every panel."""
    return {_name(ln.get_label()): to_hex(ln.get_color()) for ax in res.figure.axes for ln in ax.get_lines()}


# --------------------------------------------------------------------------- --algos
def test_algos_selects_the_configs_of_the_tables_and_figures(db: Path, tmp_path: Path):
    result = invoke(db, tmp_path, "--fig", "1", "--table", "results", "--algos", "a2c_mine,ppo")
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "table_results.csv")
    assert list(dict.fromkeys(table["algo"])) == ["ppo", "a2c_mine"]  # built-in first, then the others by name
    fig1 = build_figure(1, load_report_data(db, algos=["a2c_mine", "ppo"]))
    agents = [lab for lab in legend_labels(fig1) if not lab.startswith("best")]
    assert agents == ["PPO", "a2c_mine"] and "SAC" not in agents
    # default: every config of the database
    every = build_figure(1, load_report_data(db))
    # every config (the legend fills its columns one after another, so its text order is by column)
    assert sorted(lab for lab in legend_labels(every) if not lab.startswith("best")) == sorted(
        ["PPO", "SAC", "GRU-PPO", "a2c_mine", "ppo_big"]
    )


def test_unknown_algos_are_one_line_naming_what_the_database_holds(db: Path, tmp_path: Path):
    line = one_error_line(invoke(db, tmp_path, "--fig", "1", "--algos", "ppo,nope"))
    assert "--algos nope: not in the database, which holds ppo, sac, gru_ppo, a2c_mine, ppo_big" in line
    assert not any(tmp_path.iterdir())


# --------------------------------------------------------------------------- --pair
@pytest.mark.slow
def test_pair_draws_figure_4_for_another_pair(db: Path, tmp_path: Path):
    result = invoke(db, tmp_path, "--fig", "4", "--pair", "a2c_mine,ppo", *REF)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig4_a2c_mine_vs_ppo.pdf", "fig4_a2c_mine_vs_ppo.png"]
    data = load_report_data(db, algos=["a2c_mine", "ppo"])
    res = build_figure(4, data, reference_episodes=2, pair=("a2c_mine", "ppo"))
    assert set(res.data["algo"]) == {"a2c_mine", "ppo"}
    assert "a2c_mine against PPO" in figure_text(res)
    # the default pair keeps the published file name
    assert invoke(db, tmp_path / "d", "--fig", "4", *REF).exit_code == 0
    assert (tmp_path / "d" / "fig4_ppo_vs_gru_ppo.png").exists()


@pytest.mark.parametrize(
    "pair, message",
    [
        ("ppo,absent", "--pair absent: not in the database, which holds ppo, sac"),
        ("ppo", "--pair ppo: give two different agent configs"),
        ("ppo,ppo", "give two different"),
    ],
)
def test_a_pair_the_database_lacks_is_one_line(db: Path, tmp_path: Path, pair: str, message: str):
    line = one_error_line(invoke(db, tmp_path, "--fig", "4", "--pair", pair, *REF))
    assert message in line
    assert not any(tmp_path.iterdir())


# --------------------------------------------------------------------------- colours and labels
OTHERS = ["a2c_mine", "ppo_big", "trpo", "rainbow"]


@pytest.mark.slow
def test_colours_are_distinct_for_many_configs_and_keep_the_five():
    c = colors([*OTHERS, "dqn_v2", "impala", "td3", "r2d2", *BUILTIN_ORDER])
    assert {n: c[n] for n in BUILTIN_ORDER} == BUILTIN_COLORS  # the published colours
    assert len(c) == 13 and len(set(c.values())) == 13
    values = list(c.values())
    assert min(distance(a, b) for i, a in enumerate(values) for b in values[i + 1 :]) >= MIN_DISTANCE
    many = colors(f"agent{k}" for k in range(40))
    assert len(set(many.values())) == 40


def test_a_colour_is_stable_by_name():
    big = colors([*OTHERS, *BUILTIN_ORDER])
    assert big == colors(reversed([*OTHERS, *BUILTIN_ORDER]))  # the order names come in does not matter
    for name in ("a2c_mine", "ppo_big", "rainbow"):  # alone, with the five, among other configs: one colour
        assert (
            colors([name])[name]
            == colors([name, *BUILTIN_ORDER])[name]
            == big[name]
            == colors([name, "sac", "zz_later"])[name]
        )
    # trpo's own colour is that of a config sorting before it: only then does it move, in
    # every set holding that config, and never to a colour taken before it
    alone = colors(["trpo"])["trpo"]
    holder = [n for n in ("a2c_mine", "ppo_big", "rainbow") if distance(alone, big[n]) < MIN_DISTANCE]
    assert len(holder) == 1 and big["trpo"] != alone
    others = [n for n in ("a2c_mine", "ppo_big", "rainbow") if n not in holder]
    assert colors(["trpo", *holder])["trpo"] != alone and colors(["trpo", *others])["trpo"] == alone
    assert colors(["ppo"])["ppo"] == BUILTIN_COLORS["ppo"]


def test_a_sixth_config_never_takes_a_built_in_colour():
    for name in [*OTHERS, *(f"cfg_{k}" for k in range(200))]:
        colour = colors([name])[name]
        assert colour not in BUILTIN_COLORS.values()
        assert min(distance(colour, b) for b in BUILTIN_COLORS.values()) >= MIN_DISTANCE, name


def test_labels_and_order():
    assert [label(n) for n in order(["zeta", "gru_ppo", "a2c_mine", "mc", "ppo", "sac", "ddqn"])] == [
        "MC",
        "DDQN",
        "PPO",
        "SAC",
        "GRU-PPO",
        "a2c_mine",
        "zeta",
    ]


def test_a_config_has_one_colour_in_every_figure_of_a_report(db: Path):
    every, some = load_report_data(db), load_report_data(db, algos=["a2c_mine"])
    fig1, fig1_alone = build_figure(1, every), build_figure(1, some)
    fig4 = build_figure(
        4, load_report_data(db, algos=["a2c_mine", "ppo"]), reference_episodes=2, pair=("a2c_mine", "ppo")
    )
    colour = line_colors(fig1)["a2c_mine"]
    assert colour == line_colors(fig1_alone)["a2c_mine"] == line_colors(fig4)["a2c_mine"]
    assert colour != BUILTIN_COLORS["mc"] and line_colors(fig4)["PPO"] == BUILTIN_COLORS["ppo"]


# --------------------------------------------------------------------------- budget and seeds
def test_every_figure_states_its_budget_and_seeds(db: Path):
    same = load_report_data(db, algos=["ppo", "sac"])
    for number in (1, 2, 3):
        assert "budget 20 days, seeds 0, 1" in figure_text(build_figure(number, same, reference_episodes=2))
    fig4 = build_figure(
        4, load_report_data(db, algos=["a2c_mine", "ppo"]), reference_episodes=2, pair=("a2c_mine", "ppo")
    )
    # budgets that differ: each agent's in its legend entry, the title says so in one line
    entries = [t.get_text() for leg in fig4.figure.legends for t in leg.get_texts()]
    assert "PPO (20 days, 2 seeds)" in entries and "a2c_mine (30 days, 3 seeds)" in entries, entries
    assert "each agent's in its legend entry" in figure_text(fig4)


def test_budget_seeds_text():
    df = pd.DataFrame({"algo": ["ppo"] * 5 + ["x"], "seed": [0, 21, 9, 1997, 2003, 4], "budget": [5000] * 5 + [100]})
    assert budget_seeds_text(df[df.algo == "ppo"]) == "budget 5000 days, seeds 0, 9, 21, 1997, 2003"
    assert budget_seeds_text(df) == "PPO: budget 5000 days, seeds 0, 9, 21, 1997, 2003; x: budget 100 days, seed 4"
    assert budget_seeds_text(df.drop(columns="budget")[df.algo == "x"]) == "seed 4"
    assert seed_list([3, 0, 1, 2, 7, 9, 8, 12, 13]) == "0-3, 7-9, 12, 13"  # runs of three or more as ranges


# --------------------------------------------------------------------------- configuration tables
def test_every_config_in_the_database_has_a_table(db: Path, tmp_path: Path):
    result = invoke(db, tmp_path, "--table", "all")
    assert result.exit_code == 0, result.output
    stems = {p.stem for p in tmp_path.iterdir()}
    assert {"table2_mc", "table6_gru_ppo", "table7_a2c_mine", "table8_ppo_big", "table_results"} <= stems
    md = (tmp_path / "table7_a2c_mine.md").read_text()
    assert md.startswith("**Table 7: a2c_mine configuration (a2c_mine v1, external agent mypkg.agents:make_agent)**")
    rows = dict(re.findall(r"^\| (\S+) \| (.*) \|$", md, flags=re.M))
    assert rows["entry_point"] == "mypkg.agents:make_agent"
    assert (rows["params.lr"], rows["params.hidden"], rows["params.n_steps"]) == ("0.0007", "64, 64", "5")
    assert "PPO variant" in (tmp_path / "table8_ppo_big.md").read_text().splitlines()[0]


def test_a_config_table_by_name_and_the_algos_filter(db: Path, tmp_path: Path):
    result = invoke(db, tmp_path, "--table", "a2c_mine")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"table7_a2c_mine.{e}" for e in ("csv", "md", "tex")]
    assert "params.hidden" in (tmp_path / "table7_a2c_mine.csv").read_text()
    out = tmp_path / "sel"
    assert invoke(db, out, "--table", "all", "--algos", "a2c_mine,sac").exit_code == 0
    config_tables = sorted(p.stem for p in out.glob("table[0-9]*.md"))
    assert config_tables == ["table1_regimes", "table5_sac", "table7_a2c_mine"]
    line = one_error_line(invoke(db, tmp_path / "x", "--table", "9"))
    assert "--table 9" in line and "7 (a2c_mine), 8 (ppo_big)" in line
