"""Tuning studies that survive a crash (issue 51): a driver killed with -9 and rerun at once
leaves no trial running and retries the killed parameters; several drivers stop at the count
exactly; a plug-in's space given by path is found again by ``tune best``; bad options are one
line and write nothing; ``db copy`` carries the studies. The slow end-to-end kill -9 test,
training for real, is in tests/test_tuning.py."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import optuna
import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.tuning.export import space_file_attr
from nutribench.tuning.space import load_search_space
from nutribench.tuning.stack import StackedTrials, claim, run_study
from nutribench.tuning.study import MAX_STUDY_NAME, StudySettings, count_trials, open_study, stored_settings
from tests.conftest import one_error_line, tiny_study_settings
from tests.test_own_agent import plugin_folder  # noqa: F401 (a fixture)

runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]
TINY = ["--regimes", "run3", "--seeds", "101", "--days", "4", "--eval-every", "2", "--val-episodes", "1"]


def settings(space: str = "ppo", **kw) -> StudySettings:
    return tiny_study_settings(space, **kw)


def quick(trial) -> float:
    """An objective that trains nothing: the study machinery alone."""
    return trial.suggest_float("x", 0.0, 1.0)


@pytest.fixture
def short_grace(monkeypatch) -> int:
    """A heartbeat every second and a 2-second grace period (120 s by default)."""
    monkeypatch.setenv("NUTRIBENCH_TUNE_HEARTBEAT", "1")
    monkeypatch.setenv("NUTRIBENCH_TUNE_GRACE", "2")
    return 2


def states(db: Path, name: str) -> dict[int, str]:
    study = optuna.load_study(study_name=name, storage=f"sqlite:///{db}")
    return {t.number: t.state.name for t in study.trials}


# -- 1. a driver killed with -9, rerun at once --------------------------------------------------

KILLED_DRIVER = textwrap.dedent(
    """
    import sys, time
    from nutribench.tuning.stack import run_study
    from nutribench.tuning.study import open_study
    from tests.test_tuning_crashes import settings

    def stuck(trial):
        trial.suggest_float("x", 0.0, 1.0)
        print("running", trial.number, flush=True)
        time.sleep(600)  # killed here, mid-trial

    run_study(open_study(sys.argv[1], "k", settings()), stuck, 3)
    """
)


def test_a_driver_killed_with_minus_9_and_rerun_at_once_retries_its_trial(tmp_path: Path, monkeypatch) -> None:
    """The documented rerun, started the moment the driver died (its trial's heartbeat still
    fresh): it runs the missing trials, waits out the grace period, fails the killed trial and
    runs its parameters; no trial is left running and the study holds exactly its count."""
    monkeypatch.setenv("NUTRIBENCH_TUNE_HEARTBEAT", "1")
    monkeypatch.setenv("NUTRIBENCH_TUNE_GRACE", "5")  # 120 s by default; the rerun meets the trial fresh
    db = tmp_path / "lab.db"
    run_study(open_study(db, "k", settings()), quick, 1)
    proc = subprocess.Popen(
        [sys.executable, "-c", KILLED_DRIVER, str(db)],
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("running"), proc.stderr.read()
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.communicate()
    study = optuna.load_study(study_name="k", storage=f"sqlite:///{db}")
    (killed,) = [t for t in study.trials if t.state.name == "RUNNING"]
    waits: list[int] = []
    started = time.monotonic()
    counts = run_study(open_study(db, "k", settings()), quick, 3, on_wait=lambda c: waits.append(c.running))
    assert time.monotonic() - started < 60
    assert (counts.complete, counts.pruned, counts.running, counts.waiting) == (3, 0, 0, 0)
    assert waits == [1]  # it said it waits for the killed trial
    study = optuna.load_study(study_name="k", storage=f"sqlite:///{db}")
    assert states(db, "k")[killed.number] == "FAIL"  # not counted
    (retry,) = [t for t in study.trials if t.system_attrs.get("failed_trial") == killed.number]
    assert retry.state.name == "COMPLETE" and retry.params == killed.params  # not lost
    again = run_study(open_study(db, "k", settings()), quick, 3)  # and a third run finds nothing to do
    assert (again.complete, again.running, len(study.trials)) == (3, 0, len(states(db, "k")))


def test_a_trial_killed_before_its_first_heartbeat_is_retried_too(tmp_path: Path, short_grace) -> None:
    """Optuna's stale-trial check skips a RUNNING trial that never beat; it would hold its place
    for good. It is failed once it started longer ago than the grace period."""
    db = tmp_path / "lab.db"
    study = open_study(db, "n", settings())
    trial = claim(study, 2)  # asked, never beat: killed at once
    x = trial.suggest_float("x", 0.0, 1.0)
    counts = run_study(open_study(db, "n", settings()), quick, 2)
    assert (counts.complete, counts.running) == (2, 0)
    retried = optuna.load_study(study_name="n", storage=f"sqlite:///{db}").trials
    assert retried[trial.number].state.name == "FAIL"
    assert [t.params["x"] for t in retried if t.system_attrs.get("failed_trial") == trial.number] == [x]


def test_the_grace_period_is_a_setting_and_a_bad_one_is_one_line(tmp_path: Path, monkeypatch) -> None:
    from nutribench.tuning.study import heartbeat_settings

    assert heartbeat_settings() == (30, 120)
    monkeypatch.setenv("NUTRIBENCH_TUNE_GRACE", "5")
    monkeypatch.setenv("NUTRIBENCH_TUNE_HEARTBEAT", "2")
    assert heartbeat_settings() == (2, 5)
    monkeypatch.setenv("NUTRIBENCH_TUNE_GRACE", "soon")
    db = tmp_path / "lab.db"
    line = one_error_line(runner.invoke(app, ["tune", "--algo", "ppo", "--study", "s", "--db", str(db), *TINY]))
    assert "NUTRIBENCH_TUNE_GRACE='soon'" in line and not db.exists()


# -- 2. several drivers stop at the count exactly ------------------------------------------------


def test_a_trial_asked_over_the_count_goes_back_to_the_queue(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    study = open_study(db, "c", settings())
    run_study(study, quick, 2)
    other = claim(open_study(db, "c", settings()), 3)  # another driver holds the last place
    assert other is not None
    assert claim(study, 3) is None  # asked, counted over: put back, never run
    assert sorted(states(db, "c").values()) == ["COMPLETE", "COMPLETE", "RUNNING", "WAITING"]
    study.tell(other, 0.5)
    assert count_trials(study).finished == 3


def drive(n: int, target) -> None:
    errors: list[BaseException] = []

    def run() -> None:
        try:
            target()
        except BaseException as e:  # noqa: BLE001 (reported below)
            errors.append(e)

    threads = [threading.Thread(target=run) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not errors, errors


@pytest.mark.parametrize("drivers", [2, 3])
def test_several_drivers_stop_at_the_count_exactly(tmp_path: Path, drivers: int) -> None:
    db = tmp_path / "lab.db"
    open_study(db, "two", settings())

    def slow(trial) -> float:
        time.sleep(0.1)
        return quick(trial)

    drive(drivers, lambda: run_study(open_study(db, "two", settings()), slow, 4))
    counts = count_trials(optuna.load_study(study_name="two", storage=f"sqlite:///{db}"))
    assert (counts.finished, counts.running, counts.failed) == (4, 0, 0)


def fake_train_group(self, study, group) -> None:
    """Train nothing: each trial of the batch told a value a moment later."""
    time.sleep(0.1)
    for trial, _ in group:
        study.tell(trial, float(trial.params["learning_rate"]))


def test_stacked_drivers_ask_only_what_remains_and_stop_at_the_count(tmp_path: Path, monkeypatch) -> None:
    from nutribench.tuning.objective import ValidationObjective

    monkeypatch.setattr(StackedTrials, "train_group", fake_train_group)
    db = tmp_path / "lab.db"
    s = settings("mc")
    objective = ValidationObjective(load_search_space("mc"), s)
    one = StackedTrials(objective, 3).run(open_study(db, "one", s), 4)  # 3, then the 1 that remains
    assert (one.finished, one.waiting, len(states(db, "one"))) == (4, 0, 4)
    open_study(db, "st", s)
    drive(2, lambda: StackedTrials(objective, 3).run(open_study(db, "st", s), 5))
    counts = count_trials(optuna.load_study(study_name="st", storage=f"sqlite:///{db}"))
    assert (counts.finished, counts.running, counts.failed) == (5, 0, 0)


# -- 3. a plug-in's search space given by path -----------------------------------------------------


def test_a_plugin_space_given_by_path_is_found_again_even_moved(plugin_folder: Path, monkeypatch) -> None:  # noqa: F811
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(plugin_folder / "agents"))
    monkeypatch.syspath_prepend(str(plugin_folder))
    spaces = plugin_folder / "spaces"
    spaces.mkdir()
    space = spaces / "a2c_mine.toml"
    space.write_text(
        'name = "a2c_mine"\nversion = 1\nagent = "a2c_mine"\ndescription = "x"\n'
        '[params.learning_rate]\nkind = "float"\nlow = 1e-4\nhigh = 1e-3\nlog = true\nwhy = "test"\n'
    )
    db = plugin_folder / "lab.db"
    res = runner.invoke(app, ["tune", "--db", str(db), "--algo", str(space), "--study", "p", "--trials", "1", *TINY])
    assert res.exit_code == 0, res.output
    out = plugin_folder / "tuned"
    best = ["tune", "best", "--study", "p", "--db", str(db)]
    res = runner.invoke(app, [*best, "--write", "--out", str(out)])
    assert res.exit_code == 0, res.output  # was: error: unknown search space 'a2c_mine'
    assert (out / "a2c_mine_tuned.toml").is_file()
    study = optuna.load_study(study_name="p", storage=f"sqlite:///{db}")
    assert study.user_attrs["nutribench_space"] == {"path": str(space.resolve()), "toml": space.read_text()}
    shutil.move(spaces, plugin_folder / "moved")  # the file moved: its kept text still works
    res = runner.invoke(app, best)
    assert res.exit_code == 0, res.output
    assert "learning_rate" in res.output and "a2c_mine_tuned" in res.output
    bad = study.user_attrs["nutribench_space"]["toml"].replace("high = 1e-3", "high = 2e-3")
    study.set_user_attr("nutribench_space", {"path": "/nowhere/a2c_mine.toml", "toml": bad})
    line = one_error_line(runner.invoke(app, best))  # a kept text that is not the study's space
    assert "changed since study 'p' was created" in line


def test_a_study_made_before_the_space_was_kept_gets_it_on_resume(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    study = open_study(db, "old", settings())
    assert "nutribench_space" not in study.user_attrs
    path = REPO / "regimes" / "search" / "ppo.toml"
    resumed = open_study(db, "old", settings(), space_file_attr(path))
    assert resumed.user_attrs["nutribench_space"]["toml"] == path.read_text()
    assert stored_settings(resumed) == settings()


# -- 4. bad options: one line, exit 2, nothing written ---------------------------------------------


@pytest.mark.parametrize(
    "args, expected",
    [
        (["--days", "1000000000000"], "--days 1000000000000: give at most 100000"),
        (["--val-episodes", "100000000"], "--val-episodes 100000000: give at most 10000"),
        (["--sampler-seed", "-1"], "--sampler-seed -1: give a seed from 0 to 4294967295"),
        (["--sampler-seed", str(2**40)], f"--sampler-seed {2**40}: give a seed from 0 to 4294967295"),
        (["--study", ""], "--study: give the study a name"),
        (["--study", "  "], "--study: give the study a name"),
        (["--study", "a\nb"], "without control characters"),
        (["--study", "s" * 600], f"(600 characters): give at most {MAX_STUDY_NAME}"),
        (["--regimes", "run3,run3"], "--regimes: run3 given twice"),
    ],
)
def test_bad_options_are_one_line_and_write_nothing(tmp_path: Path, args: list[str], expected: str) -> None:
    db = tmp_path / "lab.db"
    base = ["tune", "--algo", "ppo", "--study", "s", "--db", str(db), *TINY]
    res = runner.invoke(app, [*base, *args])
    assert expected in one_error_line(res)
    assert not db.exists()


def test_cuda_without_cuda_is_refused_before_the_study_is_opened(tmp_path: Path, monkeypatch) -> None:
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    db = tmp_path / "lab.db"
    res = runner.invoke(app, ["tune", "--algo", "ppo", "--study", "s", "--db", str(db), "--device", "cuda", *TINY])
    assert "--device cuda: CUDA is not available here" in one_error_line(res)
    assert not db.exists()


@pytest.mark.parametrize(
    "param",
    [
        '[params.net_arch]\nkind = "categorical"\nchoices = [[64, 64], [1000000, 1000000, 1000000]]\nwhy = "x"\n',
        '[params.n_steps]\nkind = "int"\nlow = 64\nhigh = 1000000000000\nwhy = "x"\n',
    ],
    ids=["net_arch", "n_steps"],
)
def test_a_space_that_needs_terabytes_is_refused_in_one_line(tmp_path: Path, param: str) -> None:
    space = tmp_path / "huge.toml"
    space.write_text('name = "huge"\nversion = 1\nagent = "ppo"\ndescription = "x"\n' + param)
    db = tmp_path / "lab.db"
    res = runner.invoke(app, ["tune", "--algo", str(space), "--study", "s", "--db", str(db), *TINY])
    line = one_error_line(res)
    # refused by the config's size bounds (nutribench.config.sizes), naming the space and the field
    bound = "TiB of memory" if "net_arch" in param else "2,147,483,647, the largest step number"
    assert "huge.toml" in line and "search space 'huge'" in line and bound in line, line
    assert not db.exists()


# -- 5. db copy carries the studies --------------------------------------------------------------


def test_db_copy_carries_the_tuning_studies(tmp_path: Path) -> None:
    src, dst = tmp_path / "src.db", tmp_path / "dst.db"
    run_study(open_study(src, "a", settings()), quick, 3)
    study = open_study(src, "b", settings(sampler_seed=7), space_file_attr(REPO / "regimes" / "search" / "ppo.toml"))
    run_study(study, quick, 2)
    res = runner.invoke(app, ["db", "copy", str(src), str(dst)])
    assert res.exit_code == 0, res.output
    status = runner.invoke(app, ["tune", "status", "--db", str(dst)])
    assert status.exit_code == 0 and "no tuning studies" not in status.output, status.output
    assert "study a: ppo v1" in status.output and "3 complete" in status.output
    assert "tuning studies (2): trials: 5 rows" in res.output
    for name in ("a", "b"):
        before, after = (optuna.load_study(study_name=name, storage=f"sqlite:///{db}") for db in (src, dst))
        assert [(t.number, t.state, t.params, t.value) for t in after.trials] == [
            (t.number, t.state, t.params, t.value) for t in before.trials
        ]
        assert after.user_attrs == before.user_attrs
    assert stored_settings(optuna.load_study(study_name="b", storage=f"sqlite:///{dst}")).sampler_seed == 7
    # the copy resumes: a driver on the destination adds to it
    assert run_study(open_study(dst, "a", settings()), quick, 4).complete == 4


def test_db_copy_refuses_a_destination_holding_a_study_of_the_same_name(tmp_path: Path) -> None:
    src, dst = tmp_path / "src.db", tmp_path / "dst.db"
    run_study(open_study(src, "a", settings()), quick, 1)
    run_study(open_study(dst, "a", settings()), quick, 2)
    line = one_error_line(runner.invoke(app, ["db", "copy", str(src), str(dst)]))
    assert "already holds the tuning studies a" in line
    assert count_trials(optuna.load_study(study_name="a", storage=f"sqlite:///{dst}")).complete == 2


def test_a_queued_trial_is_claimed_by_one_driver_only(tmp_path: Path) -> None:
    """Optuna's pop of a queued trial reads WAITING, then writes RUNNING: on SQLite two drivers
    could both take it (one trial told twice, seen with two --stack drivers). Drivers asking at
    the same moment for one queued trial: exactly one gets it."""
    db = tmp_path / "lab.db"
    studies = [open_study(db, "q", settings()) for _ in range(4)]
    for _ in range(8):
        studies[0].enqueue_trial({"x": 0.5})
        queued = max(t._trial_id for t in studies[0].trials)
        barrier = threading.Barrier(len(studies))
        got: list[int] = []

        def take(study, barrier=barrier, got=got) -> None:
            barrier.wait()
            trial = claim(study, 10**6)
            got.append(trial._trial_id)
            study.tell(trial, 0.0)

        threads = [threading.Thread(target=take, args=(s,)) for s in studies]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
        assert got.count(queued) == 1 and len(got) == len(set(got)) == len(studies)
