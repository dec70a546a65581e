"""``nutribench tune``: a tuning study on Optuna in the results database; ``tune status`` and
``tune best`` read it (docs/tuning.md).

Everything checkable is checked before the database is touched: the search space (file,
keys, parameters against the base agent, every range's ends), the regimes, the tuning seeds
(never the seeds results are reported on), the budget; each a one-line error with exit 2.
"""

from __future__ import annotations

import json
from typing import Annotated, Optional

import typer

from nutribench.cli.common import (
    DEVICE_HELP,
    command_group,
    console,
    folder_option,
    old_spelling,
    option,
    path_flag,
    progress,
    say,
    split_csv,
    user_errors,
)

tune_app = command_group(
    "Tune an agent's hyperparameters on validation days (Optuna, in the results database).", no_args_is_help=False
)

_TuneDb = option(
    str,
    "SQLite file or SQLAlchemy URL (the results database: Optuna's tables go beside nutribench's)",
    envvar="NUTRIBENCH_DB",
)


_Stack = option(
    int, "trials trained together in one batch (PPO, MC, GRU-PPO, SAC: those that agree on structure; 1: one at a time)"
)


@tune_app.callback(invoke_without_command=True)
@user_errors
def tune_cmd(
    ctx: typer.Context,
    space: option(
        Optional[str],
        "search space to tune: a name in regimes/search/ (ppo, mc, ddqn, sac, gru_ppo, ppo_v2, ...) or a .toml path",
        "--space",
    ) = None,
    algo: Annotated[Optional[str], typer.Option("--algo", hidden=True)] = None,
    study: option(Optional[str], "the study's name (new: created; existing: resumed)") = None,
    regimes: option(str, "tuning regimes, comma-separated") = "run0,run1,run2,run4",
    seeds: option(Optional[str], "tuning seeds, comma-separated (default 101,102,103; never 0,21,9,2003,1997)") = None,
    trials: option(int, "finished trials (complete or pruned) the study should hold") = 32,
    days: option(int, "training days per agent of a trial") = 1000,
    eval_every: option(
        Optional[int], "training days between validation evaluations, a divisor of --days (default: about days/10)"
    ) = None,
    val_episodes: option(int, "validation days per evaluation") = 5,
    sampler_seed: option(int, "seed of the TPE sampler") = 0,
    pruner: option(str, "'median' (after half the days) or 'none'") = "median",
    startup_trials: option(int, "random trials before TPE models the values (and before the median pruner prunes)") = 5,
    objective_rule: option(
        str,
        "a trial's objective: 'last' (its value at the last day) or 'late-mean' (the mean of its values after half its days)",
        "--objective",
    ) = "last",
    stack: _Stack = 1,
    device: option(str, DEVICE_HELP) = "cpu",
    db: _TuneDb = "nutribench.db",
) -> None:
    """Run (or resume) a tuning study until it holds --trials finished trials.

    Each trial trains one agent per (regime, tuning seed) for --days days, evaluated greedily
    every --eval-every days on validation days; its value is the IQM over those agents of the
    share of the never -> planner gap. Kill or Ctrl-C it at any time and run the same command
    again: it goes on from the trials already finished."""
    if ctx.invoked_subcommand is not None:
        return
    space = old_spelling(space, algo, "--space", "--algo")  # --algo names an agent file elsewhere
    if space is None or study is None:
        raise typer.BadParameter("give --space (a search space) and --study (a name); see nutribench tune --help")
    from nutribench.config import list_regimes
    from nutribench.tuning.driver import TuneSettings, tune

    names = tuple(split_csv(regimes, list_regimes(), "regime"))
    opts = dict(trials=trials, days=days, eval_every=eval_every, val_episodes=val_episodes, stack=stack)
    opts |= dict(sampler_seed=sampler_seed, pruner=pruner, startup_trials=startup_trials, objective=objective_rule)
    settings = TuneSettings(space, study, names, seeds, device=device, db=db, **opts)
    tune(settings, say, lambda description, text: progress(None, description, text=text))


@tune_app.command("status")
@user_errors
def tune_status_cmd(
    study: option(Optional[str], "one study (default: every study in the database)") = None,
    db: _TuneDb = "nutribench.db",
    as_json: option(bool, "print JSON instead of lines", "--json") = False,
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
        what = "settings unknown"
        if s is not None:
            seeds, days = ",".join(map(str, s.seeds)), f"{s.days} day{'' if s.days == 1 else 's'}"
            what = f"{s.space} v{s.space_version} on {','.join(s.regimes)}, seeds {seeds}, {days}"
        best = "" if c.best_value is None else f"; best {c.best_value:+.1%} (trial {c.best_number})"
        say(
            f"study {c.name}: {what}: {c.complete} complete, {c.pruned} pruned, {c.running} running, "
            f"{c.failed} failed{best}"
        )
    for c in rows:
        if c.best_params:
            shown = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in c.best_params.items())
            say(f"{c.name}: best trial {c.best_number}: {shown}")


@tune_app.command("best")
@user_errors
def tune_best_cmd(
    study: option(str, "the study"),
    write: option(bool, "write the agent file into the agents folder") = False,
    name: option(Optional[str], "the new agent's name (default <agent>_tuned)") = None,
    out_given: path_flag("--out", "the folder --write writes into (default: the agents folder)") = None,
    db: _TuneDb = "nutribench.db",
) -> None:
    """The study's best trial as a new agent file: printed, or written with --write (never over an existing file)."""
    from nutribench.agents.config import agent_config_to_toml
    from nutribench.tuning.export import tuned_config, write_tuned
    from nutribench.tuning.study import open_study

    out = folder_option(out_given, "--out")  # '' is refused, as --db '' is (not the current folder)
    handle = open_study(db, study, None)
    if write:
        path = write_tuned(handle, name, out)
        say(f"wrote {path}: `NUTRIBENCH_AGENTS={path.parent} nutribench run --algos {path.stem}` trains it")
        return
    cfg, header = tuned_config(handle, name)
    typer.echo(header + "\n" + agent_config_to_toml(cfg))


def _counts_dict(c) -> dict:
    """One study's counts and settings as plain data (``tune status --json``)."""
    counts = ("complete", "pruned", "running", "failed", "best_value", "best_number", "best_params")
    settings = None if c.settings is None else c.settings.as_attr()
    return {"study": c.name, "settings": settings} | {k: getattr(c, k) for k in counts}
