"""``nutribench run`` and ``nutribench status``.

Everything a user can get wrong (unknown regime or algorithm, malformed seeds, a database
path that cannot be written, a file that is not a database, a config changed without a
version bump, an unknown executor, an engine option it cannot take such as ``--device cuda``
where there is no CUDA, a models folder that is a file) is checked before the database file
is created and reported as one red line with exit status 2.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer

from nutribench.cli.common import (
    DEVICE_HELP,
    EVAL_EVERY_HELP,
    VAL_EPISODES_HELP,
    UserError,
    check_tensorboard,
    console,
    err_console,
    folder_option,
    old_spelling,
    split_csv,
    user_errors,
)
from nutribench.cli.signals import StopSignalsAsCtrlC
from nutribench.engines import Engine
from nutribench.scheduler.executors import ExecutorError
from nutribench.scheduler.grid import DEFAULT_PRESET, PRESETS


def _check_executor(value: str) -> None:
    v = value.strip()
    if v == "local" or any(v.startswith(p) and len(v) > len(p) for p in ("dask://", "tcp://", "tls://")):
        return
    raise ExecutorError(f"unknown --executor '{value}': use 'local' or 'dask://HOST:PORT'")


def _check_db(db: str) -> None:
    """Refuse a database path that cannot be created or is not SQLite, and an in-memory database
    (every result would be lost), before anything runs."""
    from nutribench.store.engine import (
        StoreError,
        check_sqlite_file,
        database_url,
        hide_secrets,
        in_memory,
        sqlite_path,
    )

    url = database_url(db)
    if in_memory(url):
        raise StoreError(
            f"--db {hide_secrets(db)}: an in-memory SQLite database is lost when `run` ends, with every result: "
            "give a file path (e.g. --db nutribench.db)"
        )
    path = sqlite_path(url)
    if path is not None:
        check_sqlite_file(path, create=True)


def _check_eval_every(eval_every: int, agent_cfgs) -> None:
    """Evaluation during training runs in the built-in algorithms' loops: a plug-in agent
    (an entry point) is refused, in one line, before anything is written."""
    plugins = [a.name for a in agent_cfgs if getattr(a.obj, "entry_point", None)]
    if eval_every and plugins:
        raise UserError(
            f"--eval-every: {', '.join(plugins)} trains in its own loop (a plug-in agent), which evaluation "
            "during training cannot enter; leave them out of this run or drop --eval-every"
        )


def _check_models_dir(models_dir: Path | None, db: str) -> None:
    """Refuse a models folder that cannot be one (a file, or a path through a file, or not
    writable) before anything runs: each job would train and then fail to save."""
    from nutribench.safe_write import check_folder_target
    from nutribench.scheduler.registration import RunError
    from nutribench.store.engine import database_url, sqlite_path

    if models_dir is None:
        path = sqlite_path(database_url(db))
        folder, what = (path.parent if path is not None else Path.cwd()) / "models", "the models folder"
    else:
        folder, what = Path(models_dir), "--models-dir"
    hint = "give a folder for the trained models" + (" (--models-dir)" if models_dir is None else "")
    check_folder_target(folder, what, RunError, hint)


def _check_checkpoint_seconds() -> None:
    """A bad ``$NUTRIBENCH_CHECKPOINT_SECONDS`` is one line before any job starts."""
    from nutribench.engine.checkpoint import every_seconds_from_env
    from nutribench.scheduler.registration import RunError

    try:
        every_seconds_from_env()
    except ValueError as exc:
        raise RunError(str(exc)) from None


@user_errors
def run_cmd(
    preset: Annotated[
        Optional[str],
        typer.Option(
            help=f"grid preset: {', '.join(PRESETS)} (default {DEFAULT_PRESET}); options below override its fields"
        ),
    ] = None,
    regimes: Annotated[str, typer.Option(help="'all' or comma-separated regime names (run0..run6)")] = "all",
    algos: Annotated[
        str, typer.Option(help="'all' or comma-separated agent config names (mc, ddqn, ppo, sac, gru_ppo)")
    ] = "all",
    seeds: Annotated[
        Optional[str],
        typer.Option(
            help="comma-separated non-negative integers, e.g. 0,21,9, or a named set: paper (0,21,9,2003,1997, "
            "the published baselines' seeds), quick (0,21), smoke (0)"
        ),
    ] = None,
    days: Annotated[Optional[int], typer.Option("--days", help="training days per job (episodes of 50 steps)")] = None,
    episodes_alias: Annotated[Optional[int], typer.Option("--episodes", hidden=True)] = None,
    eval_episodes: Annotated[Optional[int], typer.Option(help="evaluation episodes per job (default 5)")] = None,
    workers: Annotated[
        Optional[int], typer.Option(min=1, help="jobs at once (default: core count; never more than jobs)")
    ] = None,
    executor: Annotated[str, typer.Option(help="'local' (a process per job) or 'dask://HOST:PORT'")] = "local",
    db: Annotated[str, typer.Option(envvar="NUTRIBENCH_DB", help="SQLite file or SQLAlchemy URL")] = "nutribench.db",
    models_dir_given: Annotated[
        Optional[str],
        typer.Option("--models-dir", metavar="PATH", help="where trained models go (default: models/ next to the db)"),
    ] = None,
    upgrade_only: Annotated[
        bool, typer.Option("--upgrade-only", help="create or upgrade the database schema, then exit")
    ] = False,
    retry_failed: Annotated[
        bool, typer.Option("--retry-failed", help="try again the jobs that failed 3 times (once their cause is fixed)")
    ] = False,
    engine: Annotated[
        str,
        typer.Option(
            help="'sb3' (a job per worker) or 'batched' (the jobs of one agent config trained together, one batch per worker)"
        ),
    ] = Engine.SB3.value,
    batch_size: Annotated[
        int,
        typer.Option(
            min=1, help="--engine batched: at most this many jobs in a batch (a batch's jobs are stored when it ends)"
        ),
    ] = 35,
    device: Annotated[
        str, typer.Option(help=f"{DEVICE_HELP}; the SB3 engine trains on the CPU (auto or cpu)")
    ] = "auto",
    tensorboard_given: Annotated[
        Optional[str],
        typer.Option(
            "--tensorboard",
            metavar="PATH",
            help="also write each job's training diagnostics as TensorBoard events under this folder "
            "(one run folder per job: job<id>-<algo>-<regime>-seed<seed>)",
        ),
    ] = None,
    eval_every: Annotated[int, typer.Option(min=0, help=EVAL_EVERY_HELP + "; stored in validation_episodes")] = 0,
    val_episodes: Annotated[int, typer.Option(min=1, help=VAL_EPISODES_HELP)] = 5,
    yes: Annotated[
        bool, typer.Option("--yes", "-y", help="start a bare `nutribench run` (the paper grid) without asking")
    ] = False,
) -> None:
    """Train and evaluate every regime x algo x seed job not done yet; store the results."""
    episodes = old_spelling(days, episodes_alias, "--days", "--episodes")
    models_dir = folder_option(models_dir_given, "--models-dir")  # '' is refused, as --db '' is
    tensorboard = folder_option(tensorboard_given, "--tensorboard")
    from nutribench.store import open_store

    if upgrade_only:
        store = open_store(db, writer=True)
        store.dispose()
        what = (
            "created"
            if store.created
            else (f"upgraded from {store.upgraded_from}" if store.upgraded_from else "already")
        )
        console.print(f"{store.display}: schema {what} at revision {store.revision}", highlight=False)
        return
    from nutribench.agents.config import list_agent_configs, where_agents_are
    from nutribench.config import list_regimes
    from nutribench.scheduler.driver import default_job_fn, run_grid
    from nutribench.scheduler.grid import resolve_grid
    from nutribench.scheduler.lifecycle import MAX_FAILURES
    from nutribench.scheduler.pools import check_engine
    from nutribench.scheduler.registration import load_grid_configs

    grid = resolve_grid(
        preset=preset,
        regimes=split_csv(regimes, list_regimes(), "regime"),
        algos=split_csv(algos, list_agent_configs(), "algorithm", where_agents_are()),
        seeds=seeds,
        episodes=episodes,
        eval_episodes=eval_episodes,
    )
    _check_executor(executor)
    check_engine(engine, batch_size, device)
    _check_models_dir(models_dir, db)
    if tensorboard is not None:
        check_tensorboard(tensorboard)
    _check_db(db)
    _check_checkpoint_seconds()
    _, agent_cfgs = load_grid_configs(grid)  # a broken config file fails here, before the database exists
    _check_eval_every(eval_every, agent_cfgs)
    if preset is None and seeds is None and episodes is None and regimes == algos == "all" and not yes:
        _confirm_paper_grid(grid)  # after every check of the options, before the database exists
    job_fn = default_job_fn()
    err_console.print(_starting_line(grid, engine, db, workers), highlight=False, soft_wrap=True)
    try:
        with StopSignalsAsCtrlC():  # the program's handlers, not the library's
            summary = run_grid(
                db,
                grid.regimes,
                grid.algos,
                grid.seeds,
                grid.episodes,
                grid.eval_episodes,
                workers=workers,
                executor=executor,
                job_fn=job_fn,
                models_dir=models_dir,
                display=True,
                retry_failed=retry_failed,
                engine=engine,
                max_batch=batch_size,
                device=device,
                tensorboard=tensorboard,
                eval_every=eval_every,
                val_episodes=val_episodes,
            )
    except KeyboardInterrupt:  # before any job started (opening the database, claiming)
        raise typer.Exit(130) from None
    parts = [f"{summary.done} done", f"{summary.failed} failed", f"{summary.skipped} already done"]
    if summary.busy:
        parts.append(f"{summary.busy} running in another driver")
    if summary.given_up:
        parts.append(
            f"{summary.given_up} failed {MAX_FAILURES} times (not retried: see `nutribench status`; `--retry-failed` tries them again)"
        )
    if summary.interrupted:
        parts.append(f"{summary.interrupted} interrupted (the next run resumes them)")
    err_console.print(f"{summary.total} jobs: " + ", ".join(parts), highlight=False)
    if summary.exit_code:
        raise typer.Exit(summary.exit_code)


def _starting_line(grid, engine: str, db: str, workers: int | None) -> str:
    """What ``run`` starts, printed as soon as its options are checked (every bad one is still
    one line), before the database is opened and the workers start: a line in a log file at
    once, the first of those the run writes there (one per finished job follows)."""
    where = db if "://" not in db else f"a {db.split('://', 1)[0]} database"  # a URL's password stays out
    seeds = ", ".join(map(str, grid.seeds))
    at = "" if workers is None else f", {workers} at a time"

    def n(count: int, word: str) -> str:
        return f"{count:,} {word}{'' if count == 1 else 's'}"

    return (
        f"nutribench run: {n(len(grid), 'job')} ({n(len(grid.regimes), 'regime')} x {n(len(grid.algos), 'agent')} "
        f"{', '.join(grid.algos)} x seeds {seeds}; {n(grid.episodes, 'training day')} and "
        f"{n(grid.eval_episodes, 'evaluation day')} each; {engine} engine{at}) into {where}: opening it, "
        "then the jobs not done yet"
    )


def _interactive() -> bool:
    """Whether a person can answer a question (standard input is a terminal)."""
    import sys

    return sys.stdin.isatty()


def _confirm_paper_grid(grid) -> None:
    """A bare ``nutribench run`` starts the paper grid (about 30 CPU-hours): say what it starts
    and ask on a terminal; elsewhere (a script) refuse in one line unless ``--yes`` or a
    ``--preset`` is given."""
    import nutribench.agents.registry as registry
    from nutribench.agents.config import load_agent_config

    hours = grid.cpu_hours(lambda name: registry.algorithm(load_agent_config(name)).cost)
    what = (
        f"the paper grid: {len(grid.cells())} jobs ({len(grid.regimes)} regimes x {len(grid.algos)} agents x "
        f"{len(grid.seeds)} seeds) x {grid.episodes} days, about {hours:.0f} CPU-hours with the SB3 engine "
        "(an estimate from the agents' relative costs)"
    )
    if not _interactive():
        raise UserError(f"a bare `nutribench run` starts {what}: pass --yes, or name a smaller --preset (smoke, quick)")
    if not typer.confirm(f"Start {what}?", default=False, err=True):
        raise typer.Exit(1)


@user_errors
def status_cmd(
    db: Annotated[str, typer.Option(envvar="NUTRIBENCH_DB", help="SQLite file or SQLAlchemy URL")] = "nutribench.db",
    as_json: Annotated[bool, typer.Option("--json", help="print JSON instead of a table")] = False,
) -> None:
    """Jobs done, running, failed and pending per regime x algo, wall time, ETA, last errors."""
    from nutribench.scheduler.status import status_table

    report = status_table(db)
    if as_json:
        typer.echo(json.dumps(report.to_dict(), indent=2, default=str))
        return
    render_status(report)


def render_status(report) -> None:
    """The status report as rich tables on stdout."""
    from rich.table import Table

    from nutribench.scheduler.progress import format_duration

    table = Table("regime", "algo", "budget", "done", "run", "fail", "pend", "wall", "left", title="nutribench status")
    for r in report.rows:
        table.add_row(
            f"{r.regime} v{r.regime_version}",
            f"{r.algo} v{r.algo_version}",
            str(r.budget),
            str(r.done),
            str(r.running),
            f"[red]{r.failed}[/]" if r.failed else "0",
            str(r.pending),
            format_duration(r.wall_seconds),
            format_duration(r.remaining_seconds),
        )
    console.print(table)
    t = report.totals
    console.print(
        f"{t['jobs']} jobs: {t['done']} done, {t['running']} running, {t['failed']} failed, {t['pending']} pending; "
        f"wall used {format_duration(report.wall_seconds)}; ETA {format_duration(report.eta_seconds)}"
        f" with {max(report.workers, 1)} worker{'s' if report.workers > 1 else ''}",
        highlight=False,
    )
    if t.get("orphaned"):
        console.print(
            f"[yellow]{t['orphaned']} of the pending jobs were running in a driver whose heartbeat stopped "
            f"(crashed or killed): the next `nutribench run` takes them over (the ETA prices them as whole jobs; "
            f"a batch that resumes from its checkpoint has less left)[/]",
            highlight=False,
        )
    if report.errors:
        errs = Table("regime", "algo", "seed", "failures", "last error", title="failed jobs")
        for e in report.errors:
            errs.add_row(
                e["regime"],
                e["algo"],
                str(e["seed"]),
                f"{e['failures']}" + ("" if e["retried"] else " (gave up)"),
                e["error"],
            )
        console.print(errs)
        console.print(
            "the last line of each error is shown; the whole text (its traceback) is in the jobs table's "
            "error column (docs/failures.md says how to read it)",
            highlight=False,
        )
