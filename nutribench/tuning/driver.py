"""The driver of ``nutribench tune``: one settings object (:class:`TuneSettings`), checked whole
before the database is touched (the search space: file, keys, parameters against the base
agent, every range's ends, its memory; the regimes, the tuning seeds, never the seeds results are
reported on; the budget; the device), then the study opened (created or resumed) and run until
it holds ``trials`` finished trials (:func:`tune`).

What it says goes through ``say`` (one line each: the plan, every evaluation, every finished
trial, every wait for another driver's trials) and ``progress`` (a context manager yielding
``advance(text, done, total)``: which trials train and the day they have reached); nothing is
printed by this module itself.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, ExitStack, nullcontext
from dataclasses import dataclass
from typing import Any

from nutribench.tuning.study import StudyCounts, TuneError


@dataclass(frozen=True)
class TuneSettings:
    """One ``tune`` call: the search space (a name in ``regimes/search/`` or a .toml path), the
    study's name, the tuning regimes and seeds (a comma list; None: the defaults), the trials the
    study should hold, and the study's own settings (:class:`~nutribench.tuning.study.StudySettings`:
    fixed when it is created, checked on every resume); ``stack`` trials train together in one
    batch, on ``device``, into the database ``db``."""

    space: str
    study: str
    regimes: tuple[str, ...] = ("run0", "run1", "run2", "run4")
    seeds: str | None = None
    trials: int = 32
    days: int = 1000
    eval_every: int | None = None
    val_episodes: int = 5
    sampler_seed: int = 0
    pruner: str = "median"
    startup_trials: int = 5
    objective: str = "last"
    stack: int = 1
    device: str = "cpu"
    db: str = "nutribench.db"


def plan(t: TuneSettings) -> tuple[Any, Any, bool]:
    """Check ``t`` whole (see the module docstring), before the database is touched, one line each;
    the search space, the study's settings, and whether a plug-in's trials are scored once
    (after their last day, never pruned)."""
    from nutribench.agents.registry import by_entry_point
    from nutribench.engine.device import check_device
    from nutribench.tuning.space import check_space_memory, load_search_space
    from nutribench.tuning.study import StudySettings, check_study_name, default_eval_every, scored_once, tuning_seeds

    check_study_name(t.study)
    space = load_search_space(t.space)
    study = StudySettings(
        space=space.name,
        space_version=space.version,
        space_sha256=space.sha256,
        regimes=tuple(t.regimes),
        seeds=tuning_seeds(t.seeds),
        eval_every=t.eval_every or default_eval_every(t.days),
        constant_liar=True,  # a new study's; one made before keeps its sampler (open_study)
        **{k: getattr(t, k) for k in ("days", "val_episodes", "sampler_seed", "pruner", "startup_trials", "objective")},
    )
    # a plug-in's trials are scored once, after their last day, and never pruned: recorded so
    once = bool(by_entry_point(space.base().algo))
    if once:
        study = scored_once(study)
    study.check()
    if t.trials < 1 or t.stack < 1:
        raise TuneError("--trials and --stack must be >= 1")
    # what would only fail inside a trial, refused before the database is opened
    check_space_memory(space, len(study.regimes) * len(study.seeds) * min(t.stack, t.trials))
    check_device(t.device)
    return space, study, once


def starting_line(t: TuneSettings, space: str, study: Any) -> str:
    """What ``tune`` starts, said before anything is opened: the space, the trials, the agents
    each trial trains and their days."""
    n, at_a_time = len(study.regimes) * len(study.seeds), f", {t.stack} trials at a time" if t.stack > 1 else ""
    return (
        f"tune {t.study}: search space {space}, until {t.trials} trial{' is' if t.trials == 1 else 's are'} "
        "finished; each trains "
        f"{n} agent{'' if n == 1 else 's'} ({', '.join(study.regimes)} x seeds {', '.join(map(str, study.seeds))}) "
        f"for {study.days:,} day{'' if study.days == 1 else 's'}{at_a_time}"
    )


def tune(
    t: TuneSettings,
    say: Callable[[str], None] = print,
    progress: Callable[[str, str], AbstractContextManager] | None = None,
) -> StudyCounts:
    """Run (or resume) the study of ``t`` until it holds ``t.trials`` finished trials; its counts.
    ``say`` hears each line; ``progress(description, text)`` (None: none), a context manager that
    yields ``advance(text, done, total)``, shows the training until the next line."""
    from nutribench.store.engine import shown_db
    from nutribench.tuning.export import space_file_attr
    from nutribench.tuning.objective import ValidationObjective
    from nutribench.tuning.space import resolve_space_path
    from nutribench.tuning.stack import StackedTrials, run_study
    from nutribench.tuning.study import heartbeat_settings, open_study

    space, study, once = plan(t)
    _, grace = heartbeat_settings()
    say(f"{starting_line(t, space.name, study)}; study in {shown_db(t.db)}: opening it")
    handle = open_study(t.db, t.study, study, space_file_attr(resolve_space_path(t.space)), once=once)
    with ExitStack() as shown:  # the progress line, until the next line said

        def line(text: str) -> None:
            shown.close()
            say(text)

        def evaluation(number: int, day: int, value: float) -> None:
            line(f"trial {number}: day {day}: IQM share of the gap {value:+.1%}")

        def finished(c: StudyCounts) -> None:
            best = "" if c.best_value is None else f"; best {c.best_value:+.1%} (trial {c.best_number})"
            line(
                f"study {c.name}: {c.finished} of {t.trials} finished ({c.complete} complete, "
                f"{c.pruned} pruned, {c.failed} failed){best}"
            )

        def waiting(c: StudyCounts) -> None:
            line(
                f"study {c.name}: {c.finished} of {t.trials} finished, {c.running} running: waiting for "
                f"them (another driver's finish; a killed driver's is failed {grace} s after its last heartbeat and "
                "its parameters run again)"
            )

        objective = ValidationObjective(space, study, device=t.device, on_evaluation=evaluation)
        bar = progress(f"tune {t.study}", "asking for a trial") if progress else nullcontext(lambda *_: None)
        show_training(objective, shown.enter_context(bar))
        if t.stack > 1:
            counts = StackedTrials(objective, t.stack).run(handle, t.trials, on_trial=finished, on_wait=waiting)
        else:
            counts = run_study(handle, objective, t.trials, on_trial=finished, on_wait=waiting)
    say(
        f"study {t.study} holds {counts.finished} finished trial{'' if counts.finished == 1 else 's'}: "
        f"`nutribench tune best --study {t.study} --write` "
        "writes the best as a new agent file"
    )
    return counts


def show_training(objective: Any, advance: Callable[..., None]) -> None:
    """The progress line says which trials train (each trial's engine is recorded as its
    training starts, stacked trials one after the other), the day their training has reached
    and when their first evaluation comes."""
    record, numbers, shown = objective.record_engine, [], {"which": ""}
    s = objective.settings
    n_jobs = len(objective.jobs)
    first = f"first evaluation at day {min(s.eval_every, s.days):,}"

    def record_engine(trial: Any, cfg: Any) -> None:
        record(trial, cfg)
        numbers.append(trial.number)
        which = f"trial {numbers[0]}" if len(numbers) == 1 else f"trials {min(numbers)}..{max(numbers)}"
        shown["which"] = f"training {which}: {n_jobs} agent{'s' if n_jobs != 1 else ''} each"
        advance(f"{shown['which']}, {s.days:,} day{'' if s.days == 1 else 's'}, {first}", 0, s.days)

    def on_day(day: int, job: int | None) -> None:
        step = max(1, s.days // 100)  # at most about 100 updates of the line per trial
        if day % step and day != s.days:
            return
        agent = "" if job is None else f"agent {job + 1} of {n_jobs}, "
        advance(f"{shown['which']}: {agent}day {day:,} of {s.days:,}, {first}", day, s.days)

    objective.record_engine, objective.on_day = record_engine, on_day
