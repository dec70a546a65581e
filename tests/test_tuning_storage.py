"""``nutribench tune``'s ground: Optuna's tables beside nutribench's in one database (SQLite
here, PostgreSQL in the slow tests), the search-space files, the study's fixed settings and
its trial count; the training objective is tested in tests/test_tuning.py."""

from __future__ import annotations

from pathlib import Path

import optuna
import pytest
from sqlalchemy import create_engine, inspect, text
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.store import head_revision, open_store
from nutribench.store.schema import LEGACY_VERSION_TABLE, VERSION_TABLE
from nutribench.tuning.space import load_search_space
from nutribench.tuning.stack import run_study
from nutribench.tuning.study import StudySettings, TuneError, count_trials, open_study, optuna_storage
from tests.conftest import one_error_line, tiny_study_settings

runner = CliRunner()
SPACES = ("mc", "ddqn", "ppo", "sac", "gru_ppo")


def settings(**kw) -> StudySettings:
    return tiny_study_settings(**{"pruner": "median", **kw})


def tables(url: str) -> set[str]:
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            return set(inspect(conn).get_table_names())
    finally:
        engine.dispose()


def quick(trial) -> float:
    """An objective that trains nothing: the study machinery alone."""
    return trial.suggest_float("x", 0.0, 1.0)


def check_coexistence(url: str) -> None:
    """Optuna's storage and nutribench's schema in one database, opened in either order."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    optuna.create_study(study_name="first", storage=url)  # Optuna on an empty database first
    store = open_store(url, writer=True)  # nutribench still creates its schema there
    assert store.created and store.revision == head_revision()
    store.dispose()
    study = open_study(url, "second", settings())
    run_study(study, quick, 3)
    names = tables(url)
    assert {VERSION_TABLE, LEGACY_VERSION_TABLE, "jobs", "episodes", "studies", "trials"} <= names
    engine = create_engine(url)
    with engine.connect() as conn:
        ours = conn.execute(text(f"SELECT version_num FROM {VERSION_TABLE}")).scalar()
        theirs = conn.execute(text(f"SELECT version_num FROM {LEGACY_VERSION_TABLE}")).scalar()
    engine.dispose()
    assert ours == head_revision() and theirs != ours  # each chain its own table
    open_store(url).dispose()  # a reader opens it
    open_store(url, writer=True).dispose()  # a writer finds nothing to do
    optuna_storage(url)  # Optuna's schema check passes
    assert count_trials(optuna.load_study(study_name="second", storage=url)).complete == 3


def test_optuna_and_nutribench_share_a_sqlite_database(tmp_path: Path) -> None:
    check_coexistence(f"sqlite:///{tmp_path / 'lab.db'}")


@pytest.mark.slow
def test_optuna_and_nutribench_share_a_postgres_database(pg_url: str) -> None:
    check_coexistence(pg_url)


@pytest.mark.slow
def test_two_drivers_share_one_study_on_postgres(pg_url: str) -> None:
    """Two drivers on one study stop together at the asked count: no trial run twice or missing."""
    import threading

    study_a = open_study(pg_url, "shared", settings())
    study_b = open_study(pg_url, "shared", settings())
    seen: list[int] = []

    def slow(trial) -> float:
        seen.append(trial.number)
        threading.Event().wait(0.05)
        return quick(trial)

    threads = [threading.Thread(target=run_study, args=(s, slow, 12)) for s in (study_a, study_b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    counts = count_trials(optuna.load_study(study_name="shared", storage=pg_url))
    assert len(seen) == len(set(seen))  # no trial number twice
    assert (counts.complete, counts.running) == (12, 0)  # the count exactly: no trial claimed past it


def test_a_database_from_before_the_move_opens_and_moves(tmp_path: Path) -> None:
    """nutribench's revision used to live in alembic_version, the table Optuna needs."""
    db = tmp_path / "old.db"
    open_store(db, writer=True).dispose()
    engine = create_engine(f"sqlite:///{db}")
    with engine.begin() as conn:  # as an older nutribench left it
        conn.execute(text(f"ALTER TABLE {VERSION_TABLE} RENAME TO {LEGACY_VERSION_TABLE}"))
    engine.dispose()
    store = open_store(db)  # a reader reads it where it is
    assert store.revision == head_revision()
    store.dispose()
    assert runner.invoke(app, ["status", "--db", str(db)]).exit_code == 0
    open_store(db, writer=True).dispose()  # the first writer moves it
    assert VERSION_TABLE in tables(f"sqlite:///{db}") and LEGACY_VERSION_TABLE not in tables(f"sqlite:///{db}")
    run_study(open_study(db, "after", settings()), quick, 2)  # and Optuna can then move in
    assert open_store(db).revision == head_revision()


@pytest.mark.parametrize("name", SPACES)
def test_the_shipped_search_spaces_load(name: str) -> None:
    space = load_search_space(name)
    assert space.name == name and space.base().algo == name
    assert all(p.why for p in space.params.values())
    cfg = space.config({k: p.ends()[-1] for k, p in space.params.items()})  # every upper end at once
    assert cfg.algo == name


BAD_SPACES = {
    "unknown key": ('name = "bad"\nversion = 1\nagent = "ppo"\ndescription = "x"\ncolour = 1\n', "colour"),
    "unknown parameter": ("learnin_rate", "not a hyperparameter of agent 'ppo'"),
    "low above high": ("inverted", "must be below high"),
    "log of zero": ("logzero", "log = true needs low > 0"),
    "an end that is no valid config": ("lambda_high", "gives no valid agent config"),
    "another file name": ("other_name", "differs from the file name"),
    "unknown agent": ("no_agent", "unknown agent config 'nope'"),
}


def bad_space(tmp_path: Path, case: str) -> Path:
    head = 'name = "bad"\nversion = 1\nagent = "ppo"\ndescription = "x"\n'
    param = '[params.learning_rate]\nkind = "float"\nlow = 1e-5\nhigh = 1e-3\nlog = true\nwhy = "x"\n'
    text_ = {
        "unknown key": BAD_SPACES["unknown key"][0] + param,
        "unknown parameter": head + param.replace("learning_rate", "learnin_rate"),
        "low above high": head + param.replace("low = 1e-5", "low = 1e-2"),
        "log of zero": head + param.replace("low = 1e-5", "low = 0.0"),
        "an end that is no valid config": head
        + '[params.gae_lambda]\nkind = "float"\nlow = 0.9\nhigh = 1.5\nwhy = "x"\n',
        "another file name": head.replace('"bad"', '"other"') + param,
        "unknown agent": head.replace('agent = "ppo"', 'agent = "nope"') + param,
    }[case]
    path = tmp_path / "bad.toml"
    path.write_text(text_)
    return path


@pytest.mark.parametrize("case", list(BAD_SPACES))
def test_bad_search_spaces_are_one_line_and_write_nothing(tmp_path: Path, case: str) -> None:
    db = tmp_path / "lab.db"
    path = bad_space(tmp_path, case)
    res = runner.invoke(app, ["tune", "--algo", str(path), "--study", "s", "--db", str(db), "--days", "4"])
    line = one_error_line(res)
    assert BAD_SPACES[case][1] in line and "bad.toml" in line, line
    assert not db.exists()


@pytest.mark.parametrize(
    "args, expected",
    [
        (["--seeds", "101,21"], "21 are seeds results are reported on"),
        (["--seeds", "x"], "--seeds 'x': 'x' is not a non-negative integer"),
        (["--seeds", "101,101"], "seed 101 is given twice"),
        (["--seeds", "paper"], "are seeds results are reported on"),
        (["--regimes", "run0,run9"], "unknown regime run9"),
        (["--days", "0"], "must be >= 1"),
        (["--eval-every", "3"], "must be a multiple of --eval-every (3)"),
        (["--pruner", "hyperband"], "--pruner: 'hyperband'"),
        (["--trials", "0"], "--trials and --stack must be >= 1"),
        (["--stack", "0"], "--trials and --stack must be >= 1"),
        (["--startup-trials", "0"], "--startup-trials must be >= 1"),
    ],
)
def test_bad_study_options_are_one_line_and_write_nothing(tmp_path: Path, args: list[str], expected: str) -> None:
    db = tmp_path / "lab.db"
    res = runner.invoke(app, ["tune", "--algo", "ppo", "--study", "s", "--db", str(db), "--days", "4", *args])
    assert expected in one_error_line(res)
    assert not db.exists()


def test_a_study_resumes_only_with_its_own_settings(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    run_study(open_study(db, "s", settings()), quick, 2)
    with pytest.raises(TuneError, match=r"study 's' was created with other settings: days 4 \(asked 8\)"):
        open_study(db, "s", settings(days=8))
    again = run_study(open_study(db, "s", settings()), quick, 5)  # resumed: three more, not five
    assert (again.complete, again.running) == (5, 0)
    assert run_study(open_study(db, "s", settings()), quick, 5).complete == 5  # done: nothing runs
    with pytest.raises(TuneError, match="no tuning study 'other'"):
        open_study(db, "other", None)


def test_the_library_leaves_optuna_verbosity_as_the_caller_set_it(tmp_path: Path) -> None:
    """Opening, running, counting and copying studies, and drawing bench trials, quiet Optuna
    while they run and give the caller's verbosity back (a library does not change its
    caller's process): INFO stays INFO."""
    from nutribench.bench.tune import draw_trials
    from nutribench.store.copy import copy_database
    from nutribench.tuning.study import study_counts

    db = tmp_path / "lab.db"
    calls = {
        "open_study": lambda: open_study(db, "s", settings()),
        "run_study": lambda: run_study(open_study(db, "s", settings()), quick, 2),
        "study_counts": lambda: study_counts(db),
        "copy_database": lambda: copy_database(str(db), str(tmp_path / "copy.db")),
        "draw_trials": lambda: draw_trials("ppo", 2),
    }
    caller = optuna.logging.get_verbosity()
    try:
        for name, call in calls.items():
            optuna.logging.set_verbosity(optuna.logging.INFO)
            call()
            assert optuna.logging.get_verbosity() == optuna.logging.INFO, name
    finally:
        optuna.logging.set_verbosity(caller)


def test_status_lists_the_studies(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    absent = runner.invoke(app, ["tune", "status", "--db", str(db)])
    assert "no results database" in one_error_line(absent) and not db.exists()
    open_store(db, writer=True).dispose()
    empty = runner.invoke(app, ["tune", "status", "--db", str(db)])
    assert empty.exit_code == 0 and "no tuning studies" in empty.output
    run_study(open_study(db, "lr", settings()), quick, 3)
    res = runner.invoke(app, ["tune", "status", "--db", str(db)])
    assert res.exit_code == 0, res.output
    assert "lr" in res.output and "ppo v1" in res.output and "best trial" in res.output


def test_startup_trials_reach_the_sampler_and_the_pruner_and_belong_to_the_study(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    study = open_study(db, "s", settings(startup_trials=12))
    assert study.sampler._n_startup_trials == 12 and study.pruner._n_startup_trials == 12
    run_study(study, quick, 2)
    with pytest.raises(TuneError, match="created with other settings"):
        open_study(db, "s", settings())  # 5, the default: another study's settings
