"""``nutribench tune``: a tuning study on Optuna in the results database; ``tune status`` and
``tune best`` read it (docs/tuning.md).

Everything checkable is checked before the database is touched: the search space (file,
keys, parameters against the base agent, every range's ends), the regimes, the tuning seeds
(never the seeds results are reported on), the budget; each a one-line error with exit 2.
"""

from __future__ import annotations

import json
from contextlib import ExitStack
from typing import Annotated, Optional

import typer

from nutribench.cli.common import DEVICE_HELP, console, folder_option, old_spelling, progress, split_csv, user_errors

tune_app = typer.Typer(
    no_args_is_help=False,
    add_completion=False,
    rich_markup_mode=None,
    invoke_without_command=True,
    help="Tune an agent's hyperparameters on validation days (Optuna, in the results database).",
)

DB_HELP = "SQLite file or SQLAlchemy URL (the results database: Optuna's tables go beside nutribench's)"


@tune_app.callback(invoke_without_command=True)
@user_errors
def tune_cmd(
    ctx: typer.Context,
    space: Annotated[
        Optional[str],
        typer.Option(
            "--space",
            help="search space to tune: a name in regimes/search/ (ppo, mc, ddqn, sac, gru_ppo, ppo_v2, ...) or a .toml path",
        ),
    ] = None,
    algo: Annotated[Optional[str], typer.Option("--algo", hidden=True)] = None,
    study: Annotated[Optional[str], typer.Option(help="the study's name (new: created; existing: resumed)")] = None,
    regimes: Annotated[str, typer.Option(help="tuning regimes, comma-separated")] = "run0,run1,run2,run4",
    seeds: Annotated[
        Optional[str], typer.Option(help="tuning seeds, comma-separated (default 101,102,103; never 0,21,9,2003,1997)")
    ] = None,
    trials: Annotated[int, typer.Option(help="finished trials (complete or pruned) the study should hold")] = 32,
    days: Annotated[int, typer.Option(help="training days per agent of a trial")] = 1000,
    eval_every: Annotated[
        Optional[int],
        typer.Option(help="training days between validation evaluations, a divisor of --days (default: about days/10)"),
    ] = None,
    val_episodes: Annotated[int, typer.Option(help="validation days per evaluation")] = 5,
    sampler_seed: Annotated[int, typer.Option(help="seed of the TPE sampler")] = 0,
    pruner: Annotated[str, typer.Option(help="'median' (after half the days) or 'none'")] = "median",
    startup_trials: Annotated[
        int,
        typer.Option(help="random trials before TPE models the values (and before the median pruner prunes)"),
    ] = 5,
    objective_rule: Annotated[
        str,
        typer.Option(
            "--objective",
            help="a trial's objective: 'last' (its value at the last day) or 'late-mean' (the mean of its values after half its days)",
        ),
    ] = "last",
    stack: Annotated[
        int,
        typer.Option(
            help="trials trained together in one batch (PPO, MC, GRU-PPO, SAC: those that agree on structure; 1: one at a time)"
        ),
    ] = 1,
    device: Annotated[str, typer.Option(help=DEVICE_HELP)] = "cpu",
    db: Annotated[str, typer.Option(envvar="NUTRIBENCH_DB", help=DB_HELP)] = "nutribench.db",
) -> None:
    """Run (or resume) a tuning study until it holds --trials finished trials.

    Each trial trains one agent per (regime, tuning seed) for --days days, evaluated greedily
    every --eval-every days on validation days; its value is the IQM over those agents of the
    share of the never -> planner gap. Kill or Ctrl-C it at any time and run the same command
    again: it goes on from the trials already finished."""
    if ctx.invoked_subcommand is not None:
        return
    algo = old_spelling(space, algo, "--space", "--algo")  # --algo names an agent file elsewhere
    if algo is None or study is None:
        raise typer.BadParameter("give --space (a search space) and --study (a name); see nutribench tune --help")
    from nutribench.agents.registry import by_entry_point
    from nutribench.config import list_regimes
    from nutribench.tuning.export import space_file_attr
    from nutribench.tuning.objective import ValidationObjective
    from nutribench.tuning.space import check_space_memory, load_search_space, resolve_space_path
    from nutribench.tuning.study import (
        StudySettings,
        TuneError,
        check_study_name,
        default_eval_every,
        heartbeat_settings,
        open_study,
        parse_seeds,
        scored_once,
    )

    check_study_name(study)
    space = load_search_space(algo)
    names = split_csv(regimes, list_regimes(), "regime")
    settings = StudySettings(
        space=space.name,
        space_version=space.version,
        space_sha256=space.sha256,
        regimes=tuple(names),
        seeds=parse_seeds(seeds),
        days=days,
        eval_every=eval_every or default_eval_every(days),
        val_episodes=val_episodes,
        sampler_seed=sampler_seed,
        pruner=pruner,
        startup_trials=startup_trials,
        objective=objective_rule,
        constant_liar=True,  # a new study's; one made before keeps its sampler (open_study)
    )
    # a plug-in's trials are scored once, after their last day, and never pruned: recorded so
    once = by_entry_point(space.base().algo)
    if once:
        settings = scored_once(settings)
    settings.check()
    if trials < 1 or stack < 1:
        raise TuneError("--trials and --stack must be >= 1")
    # what would only fail inside a trial, refused before the database is opened
    check_space_memory(space, len(settings.regimes) * len(settings.seeds) * min(stack, trials))
    from nutribench.engine.device import check_device

    check_device(device)
    _, grace = heartbeat_settings()
    where = db if "://" not in db else f"a {db.split('://', 1)[0]} database"  # a URL's password stays out
    console.print(
        f"tune {study}: search space {space.name}, until {trials} trials are finished; each trains "
        f"{len(settings.regimes) * len(settings.seeds)} agent{'' if len(settings.regimes) * len(settings.seeds) == 1 else 's'} ({', '.join(settings.regimes)} x seeds "
        f"{', '.join(map(str, settings.seeds))}) for {settings.days:,} days{f', {stack} trials at a time' if stack > 1 else ''}; "
        f"study in {where}: opening it",
        highlight=False,
        soft_wrap=True,
    )
    handle = open_study(db, study, settings, space_file_attr(resolve_space_path(algo)), once=once)

    def evaluation(number: int, day: int, value: float) -> None:
        shown.close()
        console.print(f"trial {number}: day {day}: IQM share of the gap {value:+.1%}", highlight=False, soft_wrap=True)

    def finished(counts) -> None:
        shown.close()
        best = "" if counts.best_value is None else f"; best {counts.best_value:+.1%} (trial {counts.best_number})"
        console.print(
            f"study {counts.name}: {counts.finished} of {trials} finished ({counts.complete} complete, "
            f"{counts.pruned} pruned, {counts.failed} failed){best}",
            highlight=False,
            soft_wrap=True,
        )

    def waiting(counts) -> None:
        shown.close()
        console.print(
            f"study {counts.name}: {counts.finished} of {trials} finished, {counts.running} running: waiting for "
            f"them (another driver's finish; a killed driver's is failed {grace} s after its last heartbeat and "
            "its parameters run again)",
            highlight=False,
            soft_wrap=True,
        )

    objective = ValidationObjective(space, settings, device=device, on_evaluation=evaluation)
    from nutribench.tuning.stack import StackedTrials, run_study

    with ExitStack() as shown:  # the progress line on stderr, until the first line on stdout
        _show_training(objective, shown.enter_context(progress(None, f"tune {study}", text="asking for a trial")))
        if stack > 1:
            counts = StackedTrials(objective, stack).run(handle, trials, on_trial=finished, on_wait=waiting)
        else:
            counts = run_study(handle, objective, trials, on_trial=finished, on_wait=waiting)
    console.print(
        f"study {study} holds {counts.finished} finished trials: `nutribench tune best --study {study} --write` "
        "writes the best as a new agent file",
        highlight=False,
        soft_wrap=True,
    )


def _show_training(objective, advance) -> None:
    """The progress line says which trials train (each trial's engine is recorded as its
    training starts, stacked trials one after the other), the day their training has reached
    and when their first evaluation comes."""
    record, numbers, shown = objective.record_engine, [], {"which": ""}
    s = objective.settings
    n_jobs = len(objective.jobs)
    first = f"first evaluation at day {min(s.eval_every, s.days):,}"

    def record_engine(trial, cfg) -> None:
        record(trial, cfg)
        numbers.append(trial.number)
        which = f"trial {numbers[0]}" if len(numbers) == 1 else f"trials {min(numbers)}..{max(numbers)}"
        shown["which"] = f"training {which}: {n_jobs} agent{'s' if n_jobs != 1 else ''} each"
        advance(f"{shown['which']}, {s.days:,} days, {first}", 0, s.days)

    def on_day(day: int, job: int | None) -> None:
        step = max(1, s.days // 100)  # at most about 100 updates of the line per trial
        if day % step and day != s.days:
            return
        agent = "" if job is None else f"agent {job + 1} of {n_jobs}, "
        advance(f"{shown['which']}: {agent}day {day:,} of {s.days:,}, {first}", day, s.days)

    objective.record_engine, objective.on_day = record_engine, on_day


@tune_app.command("status")
@user_errors
def status_cmd(
    study: Annotated[Optional[str], typer.Option(help="one study (default: every study in the database)")] = None,
    db: Annotated[str, typer.Option(envvar="NUTRIBENCH_DB", help=DB_HELP)] = "nutribench.db",
    as_json: Annotated[bool, typer.Option("--json", help="print JSON instead of lines")] = False,
) -> None:
    """Each tuning study: trials complete, pruned, running, failed, and the best so far
    (values: the IQM share of the never -> planner gap, in percent; a fraction in --json)."""
    from nutribench.tuning.study import study_counts

    rows = study_counts(db, study)
    if as_json:
        typer.echo(json.dumps([_counts_dict(c) for c in rows], indent=2, default=str))
        return
    if not rows:
        console.print("no tuning studies in this database: `nutribench tune --space ppo --study NAME` starts one")
        return
    for c in rows:
        s = c.settings
        what = (
            "settings unknown"
            if s is None
            else (
                f"{s.space} v{s.space_version} on {','.join(s.regimes)}, seeds {','.join(map(str, s.seeds))}, {s.days} days"
            )
        )
        best = "" if c.best_value is None else f"; best {c.best_value:+.1%} (trial {c.best_number})"
        console.print(
            f"study {c.name}: {what}: {c.complete} complete, {c.pruned} pruned, {c.running} running, "
            f"{c.failed} failed{best}",
            highlight=False,
            soft_wrap=True,
        )
    for c in rows:
        if c.best_params:
            shown = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in c.best_params.items())
            console.print(f"{c.name}: best trial {c.best_number}: {shown}", highlight=False, soft_wrap=True)


@tune_app.command("best")
@user_errors
def best_cmd(
    study: Annotated[str, typer.Option(help="the study")],
    write: Annotated[bool, typer.Option(help="write the agent file into the agents folder")] = False,
    name: Annotated[Optional[str], typer.Option(help="the new agent's name (default <agent>_tuned)")] = None,
    out_given: Annotated[
        Optional[str],
        typer.Option("--out", metavar="PATH", help="the folder --write writes into (default: the agents folder)"),
    ] = None,
    db: Annotated[str, typer.Option(envvar="NUTRIBENCH_DB", help=DB_HELP)] = "nutribench.db",
) -> None:
    """The study's best trial as a new agent file: printed, or written with --write (never over an existing file)."""
    from nutribench.agents.config import agent_config_to_toml
    from nutribench.tuning.export import tuned_config, write_tuned
    from nutribench.tuning.study import open_study

    out = folder_option(out_given, "--out")  # '' is refused, as --db '' is (not the current folder)
    handle = open_study(db, study, None)
    if write:
        path = write_tuned(handle, name, out)
        console.print(
            f"wrote {path}: `NUTRIBENCH_AGENTS={path.parent} nutribench run --algos {path.stem}` trains it",
            highlight=False,
            soft_wrap=True,
        )
        return
    cfg, header = tuned_config(handle, name)
    typer.echo(header + "\n" + agent_config_to_toml(cfg))


def _counts_dict(c) -> dict:
    """One study's counts and settings as plain data (``tune status --json``)."""
    settings = None if c.settings is None else c.settings.as_attr()
    return {
        "study": c.name,
        "settings": settings,
        **{
            k: getattr(c, k)
            for k in ("complete", "pruned", "running", "failed", "best_value", "best_number", "best_params")
        },
    }
