"""Training diagnostics in the results database: a row for every update of a short job of each
of the five agents through ``nutribench run`` (the SB3 engine; the batched engine in the slow
tests), stored with the job's rows in one transaction, written as TensorBoard events that
tensorboard's own reader reads, carried by archives, drawn by the report, and the migration
that adds the table to a revision-0004 database."""

from __future__ import annotations

import re
import shutil
import sqlite3
from pathlib import Path

import pytest
from sqlalchemy import event, text
from typer.testing import CliRunner

from nutribench import diagnostics as d
from nutribench.cli import app
from nutribench.scheduler.grid import Grid
from nutribench.scheduler.lifecycle import claim_jobs, store_result
from nutribench.scheduler.registration import load_grid_configs, register_grid
from nutribench.scheduler.worker import JobResult
from nutribench.store import head_revision, make_engine, open_store
from nutribench.store.engine import database_url
from nutribench.store.models import TRAINING_DIAGNOSTICS_COLUMNS
from nutribench.store.schema import upgrade_connection

REPO = Path(__file__).resolve().parents[1]
ALGOS = ("mc", "ppo", "gru_ppo", "ddqn", "sac")
#: the order the fixtures' runs take them in (jobs start in registration order): the longest
#: first, so that the two workers end together instead of SAC running alone at the end
RUN_ORDER = ("sac", "gru_ppo", "ppo", "ddqn", "mc")
DAYS = 20  # PPO and GRU-PPO update every 10 days (n_steps 500): two updates
HORIZON = 50

#: the quantities each agent fills on every update once it learns (the SB3 engine)
FILLED = {
    "mc": {"policy_loss", "value_loss", "entropy_loss", "explained_variance", "grad_norm", "learning_rate"},
    "ppo": {
        "policy_loss",
        "value_loss",
        "entropy_loss",
        "approx_kl",
        "clip_fraction",
        "explained_variance",
        "grad_norm",
        "learning_rate",
    },
    "ddqn": {"value_loss", "grad_norm", "learning_rate", "epsilon", "q_mean"},
    "sac": {"value_loss", "learning_rate", "q_mean", "actor_loss", "ent_coef"},
}
FILLED["gru_ppo"] = FILLED["ppo"]
REWARD_NORMALISED = {"mc", "ppo", "gru_ppo"}  # normalize_reward = true in regimes/agents


def sql(db: Path, query: str) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return con.execute(query).fetchall()
    finally:
        con.close()


def test_the_table_has_the_vocabulary() -> None:
    assert TRAINING_DIAGNOSTICS_COLUMNS[-len(d.COLUMNS) - 1 : -1] == d.COLUMNS


def _run(tmp: Path, engine: str, days: int) -> dict:
    """One short job of each agent on run3 through ``nutribench run --tensorboard`` (DDQN
    learning from day 2 instead of day 200, so that its losses show)."""
    agents = tmp / "agents"
    shutil.copytree(REPO / "regimes" / "agents", agents)
    ddqn = agents / "ddqn.toml"
    # a changed config is a new version (a shipped name and version holds the shipped content:
    # `db export` and `db import` refuse another)
    text = ddqn.read_text().replace("learning_starts = 10000", "learning_starts = 100")
    ddqn.write_text(re.sub(r"(?m)^version = \d+", "version = 900", text, count=1))
    mp = pytest.MonkeyPatch()
    mp.setenv("NUTRIBENCH_AGENTS", str(agents))
    mp.delenv("NUTRIBENCH_DB", raising=False)
    db, tb = tmp / "r.db", tmp / "tb"
    try:
        res = CliRunner().invoke(
            app,
            ["run", "--regimes", "run3", "--algos", ",".join(RUN_ORDER), "--seeds", "0", "--episodes", str(days)]
            + ["--eval-episodes", "1", "--workers", "2", "--db", str(db), "--tensorboard", str(tb)]
            + ["--engine", engine, "--device", "cpu"],
        )
    finally:
        mp.undo()
    assert res.exit_code == 0, res.output
    return {"db": db, "tb": tb, "engine": engine, "days": days}


@pytest.fixture(scope="module")
def ran(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return _run(tmp_path_factory.mktemp("diag"), "sb3", DAYS)


@pytest.fixture(scope="module")
def ran_batched(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return _run(tmp_path_factory.mktemp("diag_batched"), "batched", 10)


def _rows(db: Path, algo: str) -> list[dict]:
    con = sqlite3.connect(db)
    con.row_factory = sqlite3.Row
    try:
        rows = con.execute('SELECT * FROM training_diagnostics WHERE algo = ? ORDER BY "update"', (algo,)).fetchall()
    finally:
        con.close()
    return [dict(r) for r in rows]


def check_every_update(run: dict, algo: str) -> None:
    """A row for each update of ``algo``'s job in ``run``: on-policy one per rollout (MC a day,
    PPO and GRU-PPO ten days), off-policy one per day with gradient steps (from day 2 on)."""
    rows, days = _rows(run["db"], algo), run["days"]
    if algo in ("ddqn", "sac"):  # DDQN learns after step 100, SAC after step 128: from day 2
        timesteps = [HORIZON * (day + 1) for day in range(2, days)]
    else:
        per_update = 500 if algo in ("ppo", "gru_ppo") else HORIZON
        timesteps = [per_update * (u + 1) for u in range(days * HORIZON // per_update)]
    assert [r["update"] for r in rows] == list(range(len(timesteps)))
    assert [r["timestep"] for r in rows] == timesteps
    assert {r["engine"] for r in rows} == {run["engine"]}
    for r in rows:
        filled = {q for q in d.QUANTITIES if r[q] is not None}
        expected = FILLED[algo] | ({"return_scale"} if algo in REWARD_NORMALISED else set())
        assert filled == expected, (algo, r["update"], filled ^ expected)
        if r["learning_rate"] is not None:
            assert 0 < r["learning_rate"] <= 0.005
        if r["grad_norm"] is not None:
            assert r["grad_norm"] > 0
        if r["clip_fraction"] is not None:
            assert 0 <= r["clip_fraction"] <= 1
    if algo == "ddqn":
        eps = [r["epsilon"] for r in rows]  # down to exploration_final_eps after 10 % of the budget
        assert all(0.1 - 1e-9 <= e <= 1 for e in eps) and eps[-1] == pytest.approx(0.1)


@pytest.mark.parametrize("algo", ALGOS)
def test_a_row_for_every_update_of_each_agent(ran, algo) -> None:
    check_every_update(ran, algo)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ALGOS)
def test_a_row_for_every_update_of_each_agent_batched(ran_batched, algo) -> None:
    check_every_update(ran_batched, algo)


def test_tensorboard_events_are_read_by_tensorboard(ran) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    runs = sorted(p.name for p in ran["tb"].iterdir())
    assert len(runs) == 5 and all(r.startswith("job") and "-run3-seed0" in r for r in runs), runs
    for algo in ALGOS:
        (folder,) = [p for p in ran["tb"].iterdir() if p.name.split("-")[1] == algo]
        acc = EventAccumulator(str(folder))
        acc.Reload()
        tags = set(acc.Tags()["scalars"])
        rows = _rows(ran["db"], algo)
        want = {f"diagnostics/{q}" for q in d.QUANTITIES if any(r[q] is not None for r in rows)}
        assert want and want <= tags, (algo, want - tags)
        # the same numbers as the database, at the same env steps
        for q in ("value_loss", "learning_rate"):
            stored = [(r["timestep"], r[q]) for r in rows if r[q] is not None]
            events = [(e.step, e.value) for e in acc.Scalars(f"diagnostics/{q}")]
            assert [s for s, _ in events] == [s for s, _ in stored]
            assert [v for _, v in events] == pytest.approx([v for _, v in stored], rel=1e-6)
        if algo == "ppo":  # SB3's own keys too (its logger's TensorBoard output)
            assert {"train/approx_kl", "train/clip_fraction"} <= tags


@pytest.mark.slow
def test_tensorboard_events_of_the_batched_engine(ran_batched) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    for algo in ALGOS:
        (folder,) = [p for p in ran_batched["tb"].iterdir() if p.name.split("-")[1] == algo]
        acc = EventAccumulator(str(folder))
        acc.Reload()
        rows = _rows(ran_batched["db"], algo)
        for q in [q for q in d.QUANTITIES if any(r[q] is not None for r in rows)]:
            events = [(e.step, e.value) for e in acc.Scalars(f"diagnostics/{q}")]
            stored = [(r["timestep"], r[q]) for r in rows if r[q] is not None]
            assert [s for s, _ in events] == [s for s, _ in stored]
            assert [v for _, v in events] == pytest.approx([v for _, v in stored], rel=1e-6)


# --------------------------------------------------------------------------- one transaction
def _running_job(db: Path) -> tuple[object, int, str]:
    """A database with one registered job, claimed (running) by owner ``me``."""
    grid = Grid(("run0",), ("ppo",), (0,), 2, 0)
    regimes, agents = load_grid_configs(grid)
    store = open_store(db, writer=True)
    (job_id,) = register_grid(store, grid, regimes, agents)
    claim_jobs(store, [job_id], set(), 1, "me")
    return store, job_id, "me"


def _result(job_id: int, n: int) -> JobResult:
    train = [
        {
            "episode": k,
            "return": -1.0,
            "foods": 3,
            "final_distance": 0.5,
            "overshoot_ratio": 0.1,
            "final_C": 1.0,
            "final_F": 1.0,
            "final_P": 1.0,
            "first_overshoot_step": None,
            "entropy": 0.6,
        }
        for k in range(2)
    ]
    diags = [{"update": u, "timestep": 50 * (u + 1), "value_loss": 1.0 / (u + 1), "grad_norm": 2.0} for u in range(n)]
    return JobResult(job_id, train, [], [], {}, diagnostics=diags)


def test_a_jobs_rows_are_stored_all_at_once(tmp_path) -> None:
    db = tmp_path / "t.db"
    store, job_id, owner = _running_job(db)

    def fail_after_diagnostics(conn, clauseelement, multiparams, params, execution_options, result) -> None:
        if "INSERT INTO diagnostics" in str(clauseelement):
            raise RuntimeError("injected after the diagnostics insert")

    event.listen(store.engine, "after_execute", fail_after_diagnostics)
    with pytest.raises(RuntimeError, match="injected"):
        store_result(store, _result(job_id, 7), owner, None)
    # nothing of the job was written: no diagnostics, no episodes, still running
    assert sql(db, "SELECT count(*) FROM diagnostics") == [(0,)]
    assert sql(db, "SELECT count(*) FROM episodes") == [(0,)]
    assert sql(db, f"SELECT status FROM jobs WHERE id = {job_id}") == [("running",)]
    event.remove(store.engine, "after_execute", fail_after_diagnostics)
    assert store_result(store, _result(job_id, 7), owner, None)
    query = 'SELECT "update", timestep, value_loss, grad_norm, epsilon FROM training_diagnostics ORDER BY 1'
    assert sql(db, query)[:2] == [(0, 50, 1.0, 2.0, None), (1, 100, 0.5, 2.0, None)]
    assert sql(db, "SELECT count(*) FROM training_diagnostics") == [(7,)]
    assert sql(db, "SELECT count(*) FROM diagnostics") == [(7 * 3,)]  # timestep, value_loss, grad_norm
    assert sql(db, f"SELECT status FROM jobs WHERE id = {job_id}") == [("done",)]
    # deleting the job takes its diagnostics with it (ON DELETE CASCADE)
    with store.engine.begin() as conn:
        conn.exec_driver_sql("PRAGMA foreign_keys = ON")
        conn.execute(text(f"DELETE FROM jobs WHERE id = {job_id}"))
    assert sql(db, "SELECT count(*) FROM diagnostics") == [(0,)]
    store.dispose()


def test_a_bad_diagnostics_row_fails_the_store_and_writes_nothing(tmp_path) -> None:
    db = tmp_path / "t.db"
    store, job_id, owner = _running_job(db)
    bad = _result(job_id, 3)
    bad.diagnostics.append(dict(bad.diagnostics[0]))  # update 0 twice: the primary key refuses it
    with pytest.raises(Exception, match="UNIQUE"):
        store_result(store, bad, owner, None)
    assert sql(db, "SELECT count(*) FROM diagnostics") == sql(db, "SELECT count(*) FROM episodes") == [(0,)]
    store.dispose()


# --------------------------------------------------------------------------- migration
def test_the_migration_upgrades_a_0004_database(tmp_path) -> None:
    db = tmp_path / "old.db"
    engine = make_engine(database_url(db), writer=True)
    with engine.begin() as conn:
        upgrade_connection(conn, "0004")
        conn.execute(text("INSERT INTO regimes VALUES (1, 'run0', 1, 'aa', '{}', NULL, '2026-01-01')"))
        conn.execute(text("INSERT INTO agent_configs VALUES (1, 'ppo', 'ppo', 1, 'bb', '{}', NULL, '2026-01-01')"))
        conn.execute(
            text(
                "INSERT INTO jobs (id, regime_id, agent_config_id, seed, episodes, eval_episodes, status, attempt, "
                "failures, episodes_done, created_at, fake) VALUES (1, 1, 1, 0, 2, 0, 'done', 1, 0, 2, '2026-01-01', 0)"
            )
        )
    engine.dispose()
    assert "diagnostics" not in {r[0] for r in sql(db, "SELECT name FROM sqlite_master")}
    res = CliRunner().invoke(app, ["run", "--upgrade-only", "--db", str(db)])
    assert res.exit_code == 0 and "upgraded from 0004" in res.output, res.output
    assert sql(db, "SELECT version_num FROM nutribench_alembic_version") == [(head_revision(),)]
    assert sql(db, "SELECT count(*) FROM jobs") == [(1,)]
    con = sqlite3.connect(db)
    con.execute("INSERT INTO diagnostics VALUES (1, 0, 'timestep', 500), (1, 0, 'value_loss', 0.25)")
    con.commit()
    con.close()
    rows = sql(db, 'SELECT regime, algo, seed, "update", timestep, value_loss, policy_loss FROM training_diagnostics')
    assert rows == [("run0", "ppo", 0, 0, 500, 0.25, None)]
    cols = [c[1] for c in sql(db, "PRAGMA table_info(training_diagnostics)")]
    assert tuple(cols) == TRAINING_DIAGNOSTICS_COLUMNS


# --------------------------------------------------------------------------- the report
def test_report_draws_the_diagnostics(ran, tmp_path) -> None:
    from matplotlib.image import imread

    from nutribench.report.diagnostics import TITLES

    assert set(TITLES) == set(d.QUANTITIES)
    out = tmp_path / "figs"
    args = ["report", "--diagnostics", "--algo", "ppo", "--regime", "run3", "--db", str(ran["db"]), "--out", str(out)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    png = out / "diagnostics_run3_ppo.png"
    assert png.is_file() and (out / "diagnostics_run3_ppo.pdf").is_file()
    assert imread(png).shape[0] > 500
    # no diagnostics for that selection: one line, exit 2, naming what the database has
    res = CliRunner().invoke(app, [*args[:4], "--regime", "run0", *args[6:]])
    assert res.exit_code == 2, res.output
    assert "no training diagnostics for ppo/run0" in res.output and "gru_ppo/run3" in res.output, res.output
    res = CliRunner().invoke(app, ["report", "--diagnostics", "--algo", "ppo", "--db", str(ran["db"])])
    assert res.exit_code == 2 and "--diagnostics needs --regime" in res.output, res.output


def test_the_figure_has_a_panel_per_quantity_and_a_line_per_seed() -> None:
    import pandas as pd

    from nutribench.report.diagnostics import diagnostics_figure

    rows = pd.DataFrame(
        [
            {"seed": s, "timestep": 500 * (u + 1), "value_loss": 1.0 / (u + 1), "approx_kl": 0.01 * s, "epsilon": None}
            for s in (0, 21, 9)
            for u in range(4)
        ]
    )
    fig = diagnostics_figure(rows, 50, title="t")
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title(loc="left") for ax in shown] == ["value loss (SAC: critic, DDQN: TD)", "approximate KL"]
    assert all(len(ax.lines) == 3 for ax in shown)
    assert list(shown[0].lines[0].get_xdata()) == [10.0, 20.0, 30.0, 40.0]  # training days


# --------------------------------------------------------------------------- archives
def test_diagnostics_travel_in_an_archive(ran, tmp_path) -> None:
    import json

    import numpy as np

    archive, dst = tmp_path / "a.npz", tmp_path / "copy.db"
    res = CliRunner().invoke(app, ["db", "export", "--db", str(ran["db"]), str(archive)])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["db", "import", str(archive), "--db", str(dst)])
    assert res.exit_code == 0, res.output
    cols = ", ".join(f'"{c}"' for c in ("regime", "algo", "seed", *d.COLUMNS))
    query = f'SELECT {cols} FROM training_diagnostics ORDER BY algo, "update"'
    assert sql(dst, query) == sql(ran["db"], query) and len(sql(dst, query)) > 50
    # an update there twice: refused in one line, nothing imported
    with np.load(archive, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(arrays.pop("meta").tobytes().decode())
    arrays["diagnostics.update"][1] = arrays["diagnostics.update"][0]
    bad = tmp_path / "bad.npz"
    np.savez(bad, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    res = CliRunner().invoke(app, ["db", "import", str(bad), "--db", str(tmp_path / "other.db")])
    assert res.exit_code == 2 and "update 0 is there twice" in res.output, res.output
    assert not (tmp_path / "other.db").exists()
    # an archive written before the table (no diagnostics arrays, not counted) imports without them
    for k in [k for k in arrays if k.startswith("diagnostics.")]:
        del arrays[k]
    del meta["counts"]["diagnostics"]
    old = tmp_path / "old.npz"
    np.savez(old, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    res = CliRunner().invoke(app, ["db", "import", str(old), "--db", str(tmp_path / "old.db")])
    assert res.exit_code == 0, res.output
    assert sql(tmp_path / "old.db", "SELECT count(*) FROM diagnostics") == [(0,)]
    assert sql(tmp_path / "old.db", "SELECT count(*) FROM jobs") == [(5,)]


def _copy_s_grad_norm(norms) -> float:
    """What ``agents/sb3_train.py`` (SB3's ``train()`` copied to keep the norm, removed in issue
    72) logged as ``train/grad_norm``: the float32 mean of the finite norms ``clip_grad_norm_``
    returned over the update's gradient steps."""
    import torch as th

    kept = th.stack(norms)
    return float(kept[th.isfinite(kept)].mean())


def test_grad_norm_probe_reads_the_norm_before_clipping():
    """The probe's norm (one per gradient step) is the one clip_grad_norm_ returns, bit for bit,
    not the clipped gradient's; a row gets their mean; a step whose backward missed a parameter
    keeps nothing."""
    import torch as th

    from nutribench.agents.training_log import DiagnosticsLogger, GradNormProbe

    th.manual_seed(0)
    net = th.nn.Sequential(th.nn.Linear(4, 8), th.nn.Tanh(), th.nn.Linear(8, 2))
    opt = th.optim.SGD(net.parameters(), lr=0.1)
    logger = DiagnosticsLogger({})
    probe = GradNormProbe(list(net.parameters()), opt, logger)
    norms = []
    for _ in range(3):
        opt.zero_grad()
        net(th.randn(16, 4)).pow(2).sum().backward()
        norms.append(th.nn.utils.clip_grad_norm_(net.parameters(), 0.01))  # clips hard
        opt.step()
    assert min(norms) > 0.01  # every step was clipped
    assert [float(n) for n in probe.norms] == [float(n) for n in norms]
    assert logger.take() == {d.GRAD_NORM: _copy_s_grad_norm(norms)}
    opt.zero_grad(set_to_none=True)
    net[2](th.randn(16, 8)).sum().backward()  # the first layer gets no gradient
    opt.step()
    assert probe.norms == [] and logger.take() == {}
    probe.remove()
    assert logger.before_take == []


@pytest.mark.parametrize("algo", ["ppo", "mc"])
def test_ppo_and_mc_are_sb3_s_own_classes_and_the_probe_logs_the_norm_the_copy_did(algo, monkeypatch):
    """The SB3 engine's PPO and MC train with SB3's own ``train()`` (no copy): one update equals
    that of SB3's ``PPO`` / ``A2C`` built the same way, every weight bit for bit and every value
    SB3 logs; the diagnostics' ``grad_norm`` (read by the probe) equals what the removed copy of
    ``train()`` logged, computed here from the norms ``clip_grad_norm_`` returned."""
    import numpy as np
    import torch as th
    from stable_baselines3 import A2C, PPO

    from nutribench.agents.algos import build_model
    from nutribench.agents.api import make_train_env
    from nutribench.agents.config import load_agent_config
    from nutribench.agents.training_log import SB3_KEYS, DiagnosticsLogger, GradNormProbe
    from nutribench.config import load_env_config

    th.set_num_threads(1)
    sb3 = PPO if algo == "ppo" else A2C
    torch_clip = th.nn.utils.clip_grad_norm_
    cfg = load_agent_config(algo)

    def after_one_rollout(cls=None):
        _, env = make_train_env(load_env_config("run3"), cfg)
        model = build_model(cfg, env, seed=5, horizon=50, cls=cls)
        _, callback = model._setup_learn(model.n_steps, callback=None)
        callback.on_training_start(locals(), globals())
        assert model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=model.n_steps)
        return model

    ours, theirs = after_one_rollout(), after_one_rollout(sb3)
    assert type(theirs) is sb3 and isinstance(ours, sb3) and type(ours).train is sb3.train
    np.testing.assert_array_equal(ours.rollout_buffer.observations, theirs.rollout_buffer.observations)
    diagnostics = DiagnosticsLogger(SB3_KEYS)
    ours.set_logger(diagnostics)
    probe = GradNormProbe(list(ours.policy.parameters()), ours.policy.optimizer, diagnostics)
    norms: list[th.Tensor] = []

    def keeping(*args, **kwargs):
        norm = torch_clip(*args, **kwargs)
        norms.append(norm)
        return norm

    monkeypatch.setattr(th.nn.utils, "clip_grad_norm_", keeping)  # spied on here only
    np.random.seed(11)
    ours.train()
    monkeypatch.undo()
    row = diagnostics.take()
    probe.remove()
    np.random.seed(11)
    theirs.train()
    assert len(norms) == (cfg.n_epochs * -(-cfg.n_steps // cfg.batch_size) if algo == "ppo" else 1)
    mine, reference = ours.policy.state_dict(), theirs.policy.state_dict()
    assert all(th.equal(mine[k], reference[k]) for k in reference)
    assert ours.logger.name_to_value == theirs.logger.name_to_value
    assert row[d.GRAD_NORM] == _copy_s_grad_norm(norms)


def test_an_on_policy_job_s_diagnostics_probe_its_model_unless_its_update_logs_the_norm():
    """PPO's and MC's jobs (SB3's own update) get the probe; GRU-PPO's, whose update logs the
    norm itself, does not; a whole PPO update's row carries the norm."""
    import torch as th

    from nutribench.agents.algos import build_model
    from nutribench.agents.api import make_train_env
    from nutribench.agents.config import load_agent_config
    from nutribench.agents.training_log import TrainingDiagnostics
    from nutribench.config import load_env_config

    th.set_num_threads(1)
    for algo, probed in (("ppo", True), ("mc", True), ("gru_ppo", False)):
        cfg = load_agent_config(algo)
        _, env = make_train_env(load_env_config("run0"), cfg)
        model = build_model(cfg, env, seed=0, horizon=50)
        assert (TrainingDiagnostics(model).probe is not None) is probed, algo
    cfg = load_agent_config("ppo")
    _, env = make_train_env(load_env_config("run0"), cfg)
    model = build_model(cfg, env, seed=0, horizon=50)
    diagnostics = TrainingDiagnostics(model)
    model.learn(total_timesteps=500, callback=diagnostics)  # one rollout, one update of 10 epochs x 8 minibatches
    (row,) = diagnostics.rows
    assert row[d.GRAD_NORM] > 0 and diagnostics.probe.handles == []


@pytest.mark.parametrize("algo", ["ppo", "ddqn"])
def test_diagnostics_off_trains_the_same_job_without_rows(algo):
    """``train(..., diagnostics=False)`` (what reports/diagnostics_cost's benches time against)
    records no rows and changes nothing else: the same seed gives the same training days."""
    from nutribench.agents import load_agent_config, train

    cfg = load_agent_config(algo)
    cfg = cfg.model_copy(update={"learning_starts": 50} if algo == "ddqn" else {"n_steps": 50})
    on = train("run0", cfg, seed=3, episodes=3)
    off = train("run0", cfg, seed=3, episodes=3, diagnostics=False)
    assert len(on.diagnostics) >= 2 and off.diagnostics == []
    assert [e["return"] for e in on.train_episodes] == [e["return"] for e in off.train_episodes]


def test_paired_cost_is_one_minus_the_median_ratio_with_its_interval():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "cost_stats.py"  # developer code
    spec = importlib.util.spec_from_file_location("cost_stats", path)
    cost_stats = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cost_stats)
    paired_cost = cost_stats.paired_cost

    # every pair 2 % faster without: the cost is 2 %, and so is every resample
    assert paired_cost([1.0, 2.0, 4.0], [0.98, 1.96, 3.92]) == pytest.approx((0.02, 0.02, 0.02))
    with_, without = [10.0] * 5, [9.0, 9.5, 10.0, 10.5, 11.0]  # ratios 0.9 ... 1.1
    cost, lo, hi = paired_cost(with_, without)
    assert cost == pytest.approx(0.0)  # the median ratio is 1
    # a resample's median is the largest ratio when 3 or more of its 5 draws are: p = 5.8 % > 2.5 %,
    # so the interval reaches the extreme ratios
    assert lo == pytest.approx(-0.1) and hi == pytest.approx(0.1)
