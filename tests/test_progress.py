"""Issue 54, "nothing silent, no wrong estimate": the long commands (db import, leaderboard,
report --all, tune until its first evaluation) say on stderr what they are doing, on a
terminal only (stdout and a pipe's stderr stay as they were); ``nutribench run``'s first ETA
is an estimate from the agents' costs, said to be one, until a job has finished."""

from __future__ import annotations

import io
from pathlib import Path
from types import SimpleNamespace

import pytest
from rich.console import Console

from nutribench.cli.common import progress


def _terminal() -> tuple[Console, io.StringIO]:
    out = io.StringIO()
    return Console(force_terminal=True, file=out, width=160), out


# ------------------------------------------------------------------ the one helper
def test_the_progress_line_shows_each_step_on_a_terminal_and_goes_at_the_end() -> None:
    console, out = _terminal()
    with progress(None, "db import a.npz", text="checking the archive", console=console) as advance:
        advance("writing job 1 of 3", 0, 3)
        advance("writing job 2 of 3")
    shown = out.getvalue()
    for step in ("db import a.npz: checking the archive", "writing job 1 of 3", "db import a.npz: writing job 2 of 3"):
        assert step in shown
    assert "0:00:0" in shown  # the time elapsed
    assert shown.endswith("\x1b[2K")  # transient: the line is erased when the block ends


def test_no_terminal_no_progress_line_or_one_plain_line_per_step() -> None:
    out = io.StringIO()
    with progress(3, "leaderboard", text="ranking", console=Console(file=out)) as advance:
        advance("importing archive 1 of 2", 0)
    assert out.getvalue() == ""
    with progress(None, "report", text="reading the database", lines=True, console=Console(file=out)) as advance:
        advance("[1/2] figure 1", 0, 2)
        advance("[2/2] table 1", 1, 2)
    assert out.getvalue().splitlines() == ["[1/2] figure 1 (0 s)", "[2/2] table 1 (0 s)"]


def test_an_error_inside_ends_the_line_and_is_raised() -> None:
    console, out = _terminal()
    with pytest.raises(KeyError), progress(None, "tune s", console=console):
        raise KeyError("x")
    assert out.getvalue().endswith("\x1b[2K")


# ------------------------------------------------------------------ the commands' steps
def test_db_import_shows_checking_then_each_job_on_a_terminal(tmp_path, monkeypatch) -> None:
    from typer.testing import CliRunner

    import nutribench.cli.common as common
    from nutribench.cli import app
    from nutribench.scheduler.driver import GridSettings, run_grid
    from nutribench.scheduler.synthetic import synthetic_job

    monkeypatch.chdir(tmp_path)
    assert run_grid(
        GridSettings(tmp_path / "a.db", ["run0", "run3"], ["mc"], [0], 4, 1, job_fn=synthetic_job, display=False)
    ).done
    runner = CliRunner()
    res = runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(tmp_path / "a.db")])
    assert res.exit_code == 0, res.output
    quiet = runner.invoke(app, ["db", "import", str(tmp_path / "a.npz"), "--db", str(tmp_path / "b.db")])
    console, out = _terminal()
    monkeypatch.setattr(common, "err_console", console)
    res = runner.invoke(app, ["db", "import", str(tmp_path / "a.npz"), "--db", str(tmp_path / "c.db")])
    assert res.exit_code == 0, res.output
    shown = out.getvalue()
    assert "db import a.npz: checking, replaying the evaluation days" in shown
    assert "db import a.npz: writing job 1 of 2" in shown and "writing job 2 of 2" in shown
    # stdout is what it was without a terminal: the one result line, no progress
    assert res.stdout.replace("c.db", "b.db") == quiet.stdout and "writing job" not in res.output


def test_the_leaderboard_steps_follow_its_archives_then_the_ranking(tmp_path) -> None:
    from nutribench.cli.leaderboard import _steps

    for name in ("b.npz", "a.npz", "c.npz"):
        (tmp_path / name).write_bytes(b"")
    said: list[tuple[str, int, int]] = []
    seen = _steps(tmp_path, "ranking", lambda text, done, total: said.append((text, done, total)))
    seen("imported a.npz")
    seen("imported b.npz")  # c.npz is refused: said once every archive is read
    seen("refused: c.npz is damaged")
    seen("no reference lines for run9: ...")  # any other log line: no step
    assert said == [
        ("importing 1 of 3: a.npz", 0, 4),
        ("importing 2 of 3: b.npz", 1, 4),
        ("importing 3 of 3: c.npz", 2, 4),
        ("ranking", 3, 4),
    ]
    said.clear()
    _steps(None, "ranking", lambda *a: said.append(a))("anything")  # --db: the ranking alone
    assert said == []


def test_report_items_are_counted_from_build_report_s_lines() -> None:
    from nutribench.report.request import counted as _counted

    assert _counted("[3/14] figure 3") == (2, 14) and _counted("[1/2] table results") == (0, 2)
    assert _counted("reading") == (None, None)


def test_tune_says_which_trials_train_and_their_day_until_the_first_evaluation() -> None:
    from nutribench.tuning.driver import show_training as _show_training

    recorded, said = [], []
    objective = SimpleNamespace(
        record_engine=lambda trial, cfg: recorded.append(trial.number),
        on_day=None,
        settings=SimpleNamespace(days=1000, eval_every=100),
        jobs=[("run0", 101), ("run0", 102)],
    )
    _show_training(objective, lambda text, done=None, total=None: said.append((text, done, total)))
    objective.record_engine(SimpleNamespace(number=4), None)
    objective.record_engine(SimpleNamespace(number=5), None)  # stacked with trial 4
    for day in range(1, 21):
        objective.on_day(day, None)  # a batch: its agents in step
    objective.on_day(30, 1)  # one agent after another (the SB3 engine): the second agent's day 30
    assert recorded == [4, 5]  # the engine is still recorded
    assert said == [
        ("training trial 4: 2 agents each, 1,000 days, first evaluation at day 100", 0, 1000),
        ("training trials 4..5: 2 agents each, 1,000 days, first evaluation at day 100", 0, 1000),
        # every 10th day of 1000 (about 100 updates a trial), the bar at that day
        ("training trials 4..5: 2 agents each: day 10 of 1,000, first evaluation at day 100", 10, 1000),
        ("training trials 4..5: 2 agents each: day 20 of 1,000, first evaluation at day 100", 20, 1000),
        ("training trials 4..5: 2 agents each: agent 2 of 2, day 30 of 1,000, first evaluation at day 100", 30, 1000),
    ]


@pytest.mark.parametrize("stack", [1, 2])
def test_a_trial_reports_each_training_day_batched_stacked_or_alone(tmp_path, stack) -> None:
    """The objective's ``on_day`` hears every day of a real trial: the batched engine (one
    trial, or two stacked) once per day of the batch, in order."""
    from nutribench.tuning.objective import ValidationObjective
    from nutribench.tuning.space import load_search_space
    from nutribench.tuning.stack import StackedTrials, run_study
    from nutribench.tuning.study import open_study
    from tests.conftest import tiny_study_settings

    space = load_search_space("mc")
    settings = tiny_study_settings("mc")  # run0, seed 101, 4 days, evaluated every 2, no pruning
    handle = open_study(f"sqlite:///{tmp_path / 't.db'}", "s", settings)
    objective = ValidationObjective(space, settings)
    heard: list[tuple[int, int | None]] = []
    objective.on_day = lambda day, job: heard.append((day, job))
    if stack > 1:
        StackedTrials(objective, stack).run(handle, stack)
    else:
        run_study(handle, objective, 1)
    assert heard == [(1, None), (2, None), (3, None), (4, None)]


# ------------------------------------------------------------------ nutribench run's ETA
def _run(done: int = 0, k: int = 0, planned: int = 1) -> SimpleNamespace:
    """One PPO job of 1000 days on 2 workers (``k`` days trained), ``planned`` jobs in all."""
    spec = SimpleNamespace(job_id=1, algo="ppo", episodes=1000, regime="run0", seed=0)
    live = {} if done else {1: {"spec": spec, "k": k, "t0": 0.0}}
    return SimpleNamespace(
        grid=SimpleNamespace(episodes=1000, algos=("ppo",)),
        planned=planned,
        attempted={1},
        summary=SimpleNamespace(done=done, failed=0, total=planned),
        live=live,
        resumed={},
        handle=SimpleNamespace(slots=2),
    )


def test_the_first_eta_is_an_estimate_from_the_agents_cost_then_measured() -> None:
    """The issue's run: one PPO job of about a minute, whose first day came 40 s in (the
    worker's start): the days so far priced the rest at 12m49s."""
    from nutribench.scheduler.grid import SB3_SECONDS_PER_COST_DAY
    from nutribench.scheduler.progress import estimate_seconds, eta_seconds, eta_text

    costs = {"ppo": 1.0}
    before = _run()
    assert estimate_seconds(before, costs, 2) == pytest.approx(1000 * SB3_SECONDS_PER_COST_DAY)  # one job: one worker
    assert eta_text(before, 0.0, costs, 2) == "~1m (estimate)"
    first_day = _run(k=1)
    assert eta_seconds(first_day, 40.0) == pytest.approx(39960.0)  # what the measured ETA would say
    assert eta_text(first_day, 40.0, costs, 2) == "~1m (estimate)"
    # a job has finished: measured progress replaces the estimate (one job of two left)
    after = _run(done=1, planned=2)
    after.attempted = {1}
    assert eta_text(after, 60.0, costs, 2) == "1m00s"


def test_a_minute_after_the_first_trained_day_the_eta_is_measured_from_then(monkeypatch) -> None:
    """A batch of long jobs (the re-tuning study's 5000-day GRU-PPO batches): no job finishes for
    20 minutes, and the SB3 engine's cost estimate priced the batched engine's rest at ~18h.
    From a minute after the first trained day the ETA is the rate since then, which leaves the
    workers' start-up out."""
    import nutribench.scheduler.progress as progress

    assert progress.eta_since(_run(k=800, planned=3), (30.0, 100), 89.0) is None  # under a minute
    assert progress.eta_since(_run(k=100, planned=3), (30.0, 100), 100.0) is None  # no day since
    # 700 days in 70 s; 3 jobs x 1000 days planned, 800 done: 2200 left at 10 a second
    assert progress.eta_since(_run(k=800, planned=3), (30.0, 100), 100.0) == pytest.approx(220.0)

    clock = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock[0])
    view = progress.LiveView(3, "1 worker", None, console=Console(file=io.StringIO(), width=80), costs={"ppo": 1.0})
    view.head(_run(k=0, planned=3))  # the workers start: no day yet, no mark
    clock[0] = 30.0
    assert "(estimate)" in view.head(_run(k=100, planned=3))  # the first days: the mark, still the estimate
    clock[0] = 100.0
    assert view.head(_run(k=800, planned=3)).endswith("ETA 3m40s")


def test_the_estimate_prices_each_agent_by_its_cost_and_shares_the_workers() -> None:
    from nutribench.scheduler.grid import SB3_SECONDS_PER_COST_DAY
    from nutribench.scheduler.progress import estimate_seconds

    run = _run(k=500, planned=3)  # PPO half done; two jobs not started, of the grid's mean cost
    run.grid.algos = ("ppo", "sac")
    costs = {"ppo": 1.0, "sac": 5.0}
    cost_days = 500 * 1.0 + 2 * 1000 * 3.0
    assert estimate_seconds(run, costs, 2) == pytest.approx(cost_days * SB3_SECONDS_PER_COST_DAY / 2)
    assert estimate_seconds(run, costs, 8) == pytest.approx(cost_days * SB3_SECONDS_PER_COST_DAY / 3)


def test_the_live_panel_says_its_eta_is_an_estimate(tmp_path: Path) -> None:
    from nutribench.scheduler.progress import LiveView, make_view

    agents = [SimpleNamespace(name="ppo", algo="ppo"), SimpleNamespace(name="sac_fast", algo="sac")]
    view = make_view(True, None, 1, "2 workers", None, agents)
    assert isinstance(view, LiveView) and view.costs == {"ppo": 1.0, "sac_fast": 5.0}
    out = io.StringIO()
    view = LiveView(1, "2 workers", None, console=Console(file=out, width=80), costs={"ppo": 1.0})
    run = _run()
    view.start(run)
    view.stop(run)
    assert "ETA ~1m (estimate)" in out.getvalue()


# ------------------------------------------------------------------ through the commands
def _forced_terminal(monkeypatch) -> io.StringIO:
    import nutribench.cli.common as common

    console, out = _terminal()
    monkeypatch.setattr(common, "err_console", console)
    return out


def test_leaderboard_and_report_all_show_their_steps_on_a_terminal(tmp_path, monkeypatch) -> None:
    """The commands themselves draw the line (not only their helpers): ``leaderboard
    --archives`` its imports then the ranking, ``report --all`` its items; stdout as without."""
    from typer.testing import CliRunner

    from nutribench.cli import app
    from tests.test_archive_poison import _export, _record

    runner = CliRunner()
    folder = tmp_path / "lb"
    folder.mkdir()
    _record(tmp_path / "g.db", "eat_early", seeds=(0, 21))
    _export(tmp_path / "g.db", folder / "eat_early.npz")
    args = ["leaderboard", "--archives", str(folder), "--reps", "200"]
    quiet = runner.invoke(app, [*args, "--out", str(tmp_path / "o1")])
    out = _forced_terminal(monkeypatch)
    res = runner.invoke(app, [*args, "--out", str(tmp_path / "o2")])
    assert res.exit_code == 0 == quiet.exit_code, res.output
    shown = out.getvalue()
    assert "importing 1 of 1: eat_early.npz" in shown and "ranking" in shown, shown
    assert res.stdout.replace("o2", "o1") == quiet.stdout and "importing 1 of 1" not in res.stdout
    out.truncate(0)
    res = runner.invoke(app, ["report", "--all", "--db", str(tmp_path / "g.db"), "--out", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    assert "[1/" in out.getvalue(), out.getvalue()


def test_tune_shows_the_trials_and_their_day_on_a_terminal_until_the_first_evaluation(tmp_path, monkeypatch) -> None:
    from typer.testing import CliRunner

    from nutribench.cli import app

    out = _forced_terminal(monkeypatch)
    args = ["--regimes", "run3", "--seeds", "101", "--days", "4", "--eval-every", "2", "--val-episodes", "1"]
    res = CliRunner().invoke(
        app, ["tune", "--space", "mc", "--study", "s", "--trials", "1", *args, "--db", str(tmp_path / "t.db")]
    )
    assert res.exit_code == 0, res.output
    shown = out.getvalue()
    assert "tune s: training trial 0: 1 agent each, 4 days, first evaluation at day 2" in shown, shown
    assert "day 1 of 4" in shown and "day 2 of 4" in shown
    assert "day 3 of 4" not in shown  # the line ended with the first evaluation's line on stdout
    assert "trial 0: day 2: IQM share of the gap" in res.stdout and "training trial" not in res.stdout


def test_without_a_terminal_run_writes_a_progress_line_now_and_then(monkeypatch) -> None:
    """A long run logged to a file says how far it is every few minutes, not only at the end."""
    import nutribench.scheduler.progress as progress_mod
    from nutribench.scheduler.progress import LiveView

    clock = [1000.0]
    monkeypatch.setattr(progress_mod.time, "monotonic", lambda: clock[0])
    out = io.StringIO()
    view = LiveView(1, "1 local worker process", None, console=Console(file=out, width=80), costs={"ppo": 1.0})
    run = _run(k=10)
    view.start(run)
    run.live[1]["k"] = 400
    clock[0] += progress_mod.NO_TERMINAL_EVERY_S - 1
    view.update(run)
    assert "running: day" not in out.getvalue()  # not yet: one line per period
    clock[0] += 2
    view.update(run)
    lines = [ln for ln in out.getvalue().splitlines() if "running: day" in ln]
    assert len(lines) == 1 and lines[0].startswith("jobs: 0 done") and lines[0].endswith("running: day 400 of 1000")
    view.update(run)
    assert sum("running: day" in ln for ln in out.getvalue().splitlines()) == 1


@pytest.mark.slow  # two commands in fresh interpreters (torch imported in each: about a minute each, loaded)
def test_run_and_tune_logged_to_a_file_say_what_they_start_then_a_line_per_job_or_trial(tmp_path: Path) -> None:
    """``nutribench run ... > out.txt 2>&1`` (no terminal): its first line says what it starts,
    before the database is opened and the workers start; then one line per finished job.
    ``tune`` likewise: what the study trains, then a line per finished trial."""
    import os
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUTRIBENCH_")}
    env["PYTHONPATH"] = str(repo)
    cli = f"{sys.executable} -m nutribench.cli"
    run = f"{cli} run --regimes run0 --algos mc --seeds 0,21 --days 2 --eval-episodes 1 --workers 1 --db r.db"
    tune = f"{cli} tune --space mc --study s --trials 2 --days 2 --eval-every 2 --val-episodes 1 --regimes run3 --seeds 101 --db t.db"
    for cmd, log in ((run, "run.txt"), (tune, "tune.txt")):
        res = subprocess.run(f"{cmd} > {log} 2>&1", shell=True, cwd=tmp_path, env=env, timeout=600)
        assert res.returncode == 0, (tmp_path / log).read_text()
    lines = (tmp_path / "run.txt").read_text().splitlines()
    assert lines[0] == (
        "nutribench run: 2 jobs (1 regime x 1 agent mc x seeds 0, 21; 2 training days and 1 evaluation day "
        "each; sb3 engine, 1 at a time) into r.db: opening it, then the jobs not done yet"
    ), lines
    assert lines[1] == "2 of 2 jobs to run on 1 local worker process", lines
    done = [ln for ln in lines if ln.startswith("done run0 mc seed ")]
    assert len(done) == 2, lines
    lines = (tmp_path / "tune.txt").read_text().splitlines()
    assert lines[0] == (
        "tune s: search space mc, until 2 trials are finished; each trains 1 agent (run3 x seeds 101) for 2 days; "
        "study in t.db: opening it"
    ), lines
    assert [ln.split(" (")[0] for ln in lines if ln.startswith("study s: ")] == [
        "study s: 1 of 2 finished",
        "study s: 2 of 2 finished",
    ], lines
