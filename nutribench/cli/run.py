"""``nutribench run`` and ``nutribench status``.

Everything a user can get wrong (unknown regime or algorithm, malformed seeds, a database
path that cannot be written, a file that is not a database, a config changed without a
version bump, an unknown executor, an engine option it cannot take such as ``--device cuda``
where there is no CUDA, a models folder that is a file) is checked before the database file
is created and reported as one red line with exit status 2.

The command line's stop signals (:class:`StopSignalsAsCtrlC`): Ctrl-C (SIGINT), a batch
system's preemption (SIGTERM) and a closed terminal (SIGHUP) all end a ``nutribench run`` in
the same graceful stop (running jobs released as ``interrupted``, exit 130), however many of
them arrive. Signal handlers belong to the program, not to a library:
:func:`nutribench.scheduler.driver.run_grid` installs none (it stops on KeyboardInterrupt, or
when its ``stop`` event is set), so a notebook or a script that calls it keeps its own
handlers; ``run`` installs these around its call.
"""

from __future__ import annotations

import json
import signal
import threading
import time
from typing import Annotated, Any, Optional

import typer

from nutribench.cli.common import (
    DEVICE_HELP,
    EVAL_EVERY_HELP,
    DbOption,
    UserError,
    ValEpisodesOption,
    console,
    err_console,
    folder_option,
    old_spelling,
    option,
    path_flag,
    print_table,
    say_err,
    split_csv,
    user_errors,
)
from nutribench.engines import Engine
from nutribench.scheduler.grid import DEFAULT_PRESET, PRESETS

# the options of ``run`` whose help would not fit on the signature's one line an option
_Preset = option(
    Optional[str], f"grid preset: {', '.join(PRESETS)} (default {DEFAULT_PRESET}); options below override its fields"
)
_Seeds = option(
    Optional[str],
    "comma-separated non-negative integers, e.g. 0,21,9, or a named set: paper (0,21,9,2003,1997, "
    "the published baselines' seeds), quick (0,21), smoke (0)",
)
_RetryFailed = option(bool, "try again the jobs that failed 3 times (once their cause is fixed)", "--retry-failed")
_EngineName = option(
    str, "'sb3' (a job per worker) or 'batched' (the jobs of one agent config trained together, one batch per worker)"
)
_Tensorboard = path_flag(
    "--tensorboard",
    "also write each job's training diagnostics as TensorBoard events under this folder "
    "(one run folder per job: job<id>-<algo>-<regime>-seed<seed>)",
)


#: Signals that stop a run as Ctrl-C does: a batch system's preemption (SIGTERM) and a closed
#: terminal (SIGHUP) release the running jobs as ``interrupted`` at once.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class StopSignalsAsCtrlC:
    """Within the block (main thread only), the first stop signal raises KeyboardInterrupt;
    later ones are ignored: in the block for a second (then the first counts as lost), and
    after a stop until the process exits (the command is ending: a second Ctrl-C must not
    break its last lines). Without a stop, the handlers found are put back. SIGINT stays
    ignored where it was (a shell's background job)."""

    def __enter__(self) -> None:
        self.previous, self.raised_at = {}, None
        if threading.current_thread() is not threading.main_thread():
            return  # only the main thread may install signal handlers
        for sig in STOP_SIGNALS:
            if sig != signal.SIGINT or signal.getsignal(sig) is not signal.SIG_IGN:
                self.previous[sig] = signal.signal(sig, self._stop)

    def _stop(self, signum: int, frame: Any) -> None:
        if self.raised_at is None or time.monotonic() - self.raised_at > 1.0:
            self.raised_at = time.monotonic()
            raise KeyboardInterrupt(signal.Signals(signum).name)

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        stopped = self.raised_at is not None or (kind is not None and issubclass(kind, KeyboardInterrupt))
        for sig, handler in self.previous.items():
            signal.signal(sig, signal.SIG_IGN if stopped else handler)


@user_errors
def run_cmd(
    preset: _Preset = None,
    regimes: option(str, "'all' or comma-separated regime names (run0..run6)") = "all",
    algos: option(str, "'all' or comma-separated agent config names (mc, ddqn, ppo, sac, gru_ppo)") = "all",
    seeds: _Seeds = None,
    days: option(Optional[int], "training days per job (episodes of 50 steps)", "--days") = None,
    episodes_alias: Annotated[Optional[int], typer.Option("--episodes", hidden=True)] = None,
    eval_episodes: option(Optional[int], "evaluation episodes per job (default 5)") = None,
    workers: option(Optional[int], "jobs at once (default: core count; never more than jobs)", min=1) = None,
    executor: option(str, "'local' (a process per job) or 'dask://HOST:PORT'") = "local",
    db: DbOption = "nutribench.db",
    models_dir: path_flag("--models-dir", "where trained models go (default: models/ next to the db)") = None,
    upgrade_only: option(bool, "create or upgrade the database schema, then exit", "--upgrade-only") = False,
    retry_failed: _RetryFailed = False,
    engine: _EngineName = Engine.SB3.value,
    batch_size: option(
        int, "--engine batched: at most this many jobs in a batch (a batch's jobs are stored when it ends)", min=1
    ) = 35,
    device: option(str, f"{DEVICE_HELP}; the SB3 engine trains on the CPU (auto or cpu)") = "auto",
    tensorboard_given: _Tensorboard = None,
    eval_every: option(int, EVAL_EVERY_HELP + "; stored in validation_episodes", min=0) = 0,
    val_episodes: ValEpisodesOption = 5,
    yes: option(bool, "start a bare `nutribench run` (the paper grid) without asking", "--yes", "-y") = False,
) -> None:
    """Train and evaluate every regime x algo x seed job not done yet; store the results."""
    episodes = old_spelling(days, episodes_alias, "--days", "--episodes")
    models = folder_option(models_dir, "--models-dir")  # '' is refused, as --db '' is
    tensorboard = folder_option(tensorboard_given, "--tensorboard")
    if upgrade_only:
        from nutribench.store.schema import upgrade_schema

        console.print(upgrade_schema(db), highlight=False)
        return
    from nutribench.agents.config import list_agent_configs, where_agents_are
    from nutribench.config import list_regimes
    from nutribench.scheduler.driver import run_grid
    from nutribench.scheduler.grid import resolve_grid
    from nutribench.scheduler.settings import GridSettings

    regime_names = split_csv(regimes, list_regimes(), "regime")
    agents = split_csv(algos, list_agent_configs(), "algorithm", where_agents_are())
    grid = resolve_grid(
        preset=preset, regimes=regime_names, algos=agents, seeds=seeds, episodes=episodes, eval_episodes=eval_episodes
    )
    how = dict(workers=workers, executor=executor, models_dir=models, retry_failed=retry_failed, engine=engine)
    how |= dict(max_batch=batch_size, device=device, tensorboard=tensorboard, eval_every=eval_every)
    settings = GridSettings.of(grid, db, val_episodes=val_episodes, **how)
    settings.check()
    if preset is None and seeds is None and episodes is None and regimes == algos == "all" and not yes:
        _confirm_paper_grid(grid)  # after every check of the options, before the database exists
    say_err(settings.starting_line())
    try:
        with StopSignalsAsCtrlC():  # the program's handlers, not the library's
            summary = run_grid(settings)
    except KeyboardInterrupt:  # before any job started (opening the database, claiming)
        raise typer.Exit(130) from None
    err_console.print(summary.line(), highlight=False)
    if summary.exit_code:
        raise typer.Exit(summary.exit_code)


def _interactive() -> bool:
    """Whether a person can answer a question (standard input is a terminal)."""
    import sys

    return sys.stdin.isatty()


def _confirm_paper_grid(grid) -> None:
    """A bare ``nutribench run`` starts the paper grid (about 30 CPU-hours): say what it starts
    and ask on a terminal; elsewhere (a script) refuse in one line unless ``--yes`` or a
    ``--preset`` is given."""
    from nutribench.scheduler.settings import paper_grid_question

    what = paper_grid_question(grid)
    if not _interactive():
        raise UserError(f"a bare `nutribench run` starts {what}: pass --yes, or name a smaller --preset (smoke, quick)")
    if not typer.confirm(f"Start {what}?", default=False, err=True):
        raise typer.Exit(1)


@user_errors
def status_cmd(
    db: DbOption = "nutribench.db",
    as_json: option(bool, "print JSON instead of a table", "--json") = False,
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
    from nutribench.scheduler.progress import format_duration as took

    columns = ("regime", "algo", "budget", "done", "run", "fail", "pend", "wall", "left")
    cells = [
        [f"{r.regime} v{r.regime_version}", f"{r.algo} v{r.algo_version}", str(r.budget), str(r.done), str(r.running)]
        + [f"[red]{r.failed}[/]" if r.failed else "0", str(r.pending), took(r.wall_seconds), took(r.remaining_seconds)]
        for r in report.rows
    ]
    print_table(columns, cells, "nutribench status")
    t = report.totals
    console.print(
        f"{t['jobs']} job{'' if t['jobs'] == 1 else 's'}: {t['done']} done, {t['running']} running, {t['failed']} failed, {t['pending']} pending; "
        f"wall used {took(report.wall_seconds)}; ETA {took(report.eta_seconds)}"
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
        retried = lambda e: f"{e['failures']}" + ("" if e["retried"] else " (gave up)")  # noqa: E731
        cells = [[e["regime"], e["algo"], str(e["seed"]), retried(e), e["error"]] for e in report.errors]
        print_table(("regime", "algo", "seed", "failures", "last error"), cells, "failed jobs")
        console.print(
            "the last line of each error is shown; the whole text (its traceback) is in the jobs table's "
            "error column (docs/failures.md says how to read it)",
            highlight=False,
        )
